"""Where compensated samples go and how they look: the output formats (`same`, `fogd`, `csv`, `jsonl`), the
sinks (stdout, a file, a serial or pty device, a pty fogd creates and links like socat), and the writer thread
that drains a bounded queue into the sink with a write timeout.

The compensation loop hands the writer one encoded chunk per batch and never waits: when the queue is full
the chunk's frames are dropped and counted, and a consumer that does not take bytes within the write timeout
costs the frames not yet written, counted too. Memory is bounded by the queue length, whatever the consumer
does. When the writer thread is idle (nothing queued or being written) and the sink is non-blocking, the
loop writes the chunk itself with one non-blocking write, and queues only what the consumer did not take at
once: output order is kept, nothing waits, and a frame reaches the consumer without a wake-up of the writer
thread (most of the daemon's latency at real rates).

An output that goes away (a serial port unplugged, a consumer's pty re-created behind its link, a FIFO's
reader gone) is closed and opened again by path with a back-off, as the input port is; meanwhile its frames
are dropped and counted. A pty fogd makes (`pty:PATH`) is written only while a reader holds it open: frames
for nobody are dropped and counted, never queued in the kernel for a reader that comes later, who gets the
CSV header (if any) and then live frames.
"""

from __future__ import annotations

import bisect
import errno
import logging
import math
import operator
import os
import queue
import select
import stat
import threading
import time
import termios
import tty
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import serial

from fogd.core.channels import output_columns
from fogd.core.columns import CHANNELS, OUTPUT_FORMATS
from fogd.core.compensator import Compensated
from fogd.errors import DeviceError, describe_os_error
from fogd.protocols import Protocol
from fogd.protocols.base import NAN, Frame
from fogd.protocols.fogdbin import SEQ_MODULUS, CompImu, FogdProtocol, encode_comp_imu
from fogd.serving.channels import ChannelPlan, source
from fogd.serving.ring import RATE_KINDS
from fogd.serving.serialio import describe_open_error

log = logging.getLogger("fogd.writer")

OUT_FORMATS = ("same", "fogd", "csv", "jsonl")
CSV_COLUMNS = tuple(OUTPUT_FORMATS)  # t_s,rate_dph,temp_c,temp_rate_cps,comp_dph,rate_comp_dph,flags
CSV_ROW = ",".join(OUTPUT_FORMATS[name] for name in CSV_COLUMNS) + "\n"
WRITE_TIMEOUT_S = 1.0
QUEUE_CHUNKS = 64  # batches waiting for the sink; a batch is at most a ring's pop, so memory stays bounded
PTY_PREFIX = "pty:"
_RAW = operator.attrgetter("raw")
REOPEN_FIRST_S = 0.05  # an output that went away is tried again after this, doubling up to REOPEN_MAX_S
REOPEN_MAX_S = 2.0


@dataclass
class OutputBatch:
    """One batch from the ring, compensated: `comp` and `t_s` have one row per entry of `rate_rows`."""

    frames: list[Frame]  # as the lexer decoded them, in arrival order
    rate_rows: list[int]  # indices of the frames that carry a rate
    t_s: np.ndarray | list[float]  # output time of each rate row
    comp: Compensated  # the compensated axis (a multi-channel model: its first channel), per rate row
    channels: dict[str, Compensated] | None = None  # a multi-channel model: every compensated channel


@dataclass
class Chunk:
    """Encoded output: the bytes and the end offset of each frame in them."""

    data: bytes
    frame_ends: list[int]
    begun: bool = False  # the first frame's start is already on the wire: it must be finished, never dropped


class Formatter:
    """Encodes compensated batches in one output format; `axis` is the compensated gyro axis (0..2) of a
    single-channel model, `channels` the plan of a multi-channel one (every covered channel in each frame)."""

    def __init__(self, out_format: str, protocol: Protocol, axis: int, channels: ChannelPlan | None = None) -> None:
        if out_format not in OUT_FORMATS:
            raise ValueError(f"unknown output format {out_format!r}")
        self.out_format = out_format
        self.protocol = protocol
        self.axis = axis
        self.plan = channels if channels is not None and not channels.single else None
        self._fogd_protocol = FogdProtocol()
        self._seq = 0
        self._pieces = getattr(self, f"_{out_format}" if self.plan is None else f"_{out_format}_channels")
        self._same_one = out_format == "same" and self.plan is None
        if self.plan is not None:
            self._columns, self._row_format = _channel_columns(self.plan)
            self._accel = bool(self.plan.accel_axes)

    def header(self) -> bytes:
        """What goes to the sink before any frame (the CSV header line)."""
        if self.out_format != "csv":
            return b""
        return (",".join(CSV_COLUMNS if self.plan is None else self._columns) + "\n").encode()

    def encode(self, batch: OutputBatch) -> Chunk:
        pieces = self._pieces(batch)
        if len(pieces) == 1:
            return Chunk(pieces[0], [len(pieces[0])])
        ends, total = [], 0
        for piece in pieces:
            total += len(piece)
            ends.append(total)
        return Chunk(b"".join(pieces), ends)

    def encode_one(self, frame: Frame, t_s: float, comp: Compensated) -> Chunk:
        """`encode` of a batch of one rate frame and one channel (`comp` one row long), the same bytes."""
        if self._same_one:  # the usual output: the input frame with its rate replaced, a fresh CRC
            rates = list(frame.rate_dph)
            rates[self.axis] = comp.rate_comp_dph[0]
            data = self.protocol.reencode(frame, rates)
            return Chunk(data, [len(data)])
        return self.encode(OutputBatch([frame], [0], [t_s], comp))

    def _same(self, batch: OutputBatch) -> list[bytes]:
        """Every input frame, rate frames re-encoded with the compensated rate and a fresh CRC."""
        axis, reencode, frames = self.axis, self.protocol.reencode, batch.frames
        pieces = list(map(_RAW, frames))  # (a list comprehension is a call of its own in Python 3.11)
        for row, rate_comp in zip(batch.rate_rows, _values(batch.comp.rate_comp_dph)):
            frame = frames[row]
            rates = list(frame.rate_dph)
            rates[axis] = rate_comp
            pieces[row] = reencode(frame, rates)
        return pieces

    def _fogd(self, batch: OutputBatch) -> list[bytes]:
        """One fogd compensated-output frame per rate sample."""
        comp = batch.comp
        axis = self.axis
        pieces = []
        columns = zip(
            _values(batch.t_s), [batch.frames[row] for row in batch.rate_rows], _values(comp.temp_c),
            _values(comp.temp_rate_cps), _values(comp.comp_dph), _values(comp.rate_comp_dph), _values(comp.flags),
        )  # fmt: skip
        for t_s, rated, temp_c, temp_rate_cps, comp_dph, rate_comp_dph, flags in columns:
            comps = [0.0, 0.0, 0.0]
            comps[axis] = comp_dph
            rates_comp = list(rated.rate_dph)
            rates_comp[axis] = rate_comp_dph
            frame = Frame(
                "fogd", "comp", "comp", self._seq, max(t_s, 0.0), tuple(rated.rate_dph), rated.axis_valid,
                rated.axis_present, temp_c, b"", temp_rate_cps, tuple(comps), tuple(rates_comp), flags,
            )  # fmt: skip
            pieces.append(self._fogd_protocol.encode(frame))
            self._seq = (self._seq + 1) % SEQ_MODULUS
        return pieces

    def _rows(self, batch: OutputBatch):
        comp = batch.comp
        axis, frames = self.axis, batch.frames
        return zip(
            _values(batch.t_s), [frames[row].rate_dph[axis] for row in batch.rate_rows], _values(comp.temp_c),
            _values(comp.temp_rate_cps), _values(comp.comp_dph), _values(comp.rate_comp_dph), _values(comp.flags),
        )  # fmt: skip

    def _csv(self, batch: OutputBatch) -> list[bytes]:
        """fogd-replay's columns and number formats, one row per rate sample."""
        return [(CSV_ROW % row).encode() for row in self._rows(batch)]

    def _jsonl(self, batch: OutputBatch) -> list[bytes]:
        """One JSON object per rate sample (null for NaN/Inf)."""
        return [
            (
                f'{{"t_s":{_json(t_s)},"rate_dph":{_json(rate)},"temp_c":{_json(temp)},'
                f'"temp_rate_cps":{_json(temp_rate)},"comp_dph":{_json(comp)},"rate_comp_dph":{_json(rate_comp)},'
                f'"flags":{flags}}}\n'
            ).encode()
            for t_s, rate, temp, temp_rate, comp, rate_comp, flags in self._rows(batch)
        ]


    def _channel_columns(self, batch: OutputBatch) -> list[tuple[bool, int, str | None, list, list, list]]:
        """Per carried channel: (accelerometer?, axis, name if compensated, comp, compensated, flags)."""
        channels = batch.channels or {}
        columns = []
        for name in self.plan.carried:
            accel, axis = source(name)
            comp = channels.get(name)
            if comp is None:
                columns.append((accel, axis, None, [], [], []))
            else:
                columns.append((accel, axis, name, _values(comp.comp_dph), _values(comp.rate_comp_dph), _values(comp.flags)))
        return columns

    def _channel_rows(self, batch: OutputBatch) -> list[tuple]:
        """One tuple per rate sample: t_s, temp_c, temp_rate_cps, then per carried channel its reading and,
        if compensated, its compensation, compensated reading and flags."""
        columns = self._channel_columns(batch)
        comp, frames = batch.comp, batch.frames
        rows = []
        for j, (row, t_s, temp_c, temp_rate_cps) in enumerate(
            zip(batch.rate_rows, _values(batch.t_s), _values(comp.temp_c), _values(comp.temp_rate_cps))
        ):
            frame = frames[row]
            values: list = [t_s, temp_c, temp_rate_cps]
            for accel, axis, name, comps, compensated, flags in columns:
                values.append(_reading(frame, accel, axis))
                if name is not None:
                    values += (comps[j], compensated[j], flags[j])
            rows.append(tuple(values))
        return rows

    def _same_channels(self, batch: OutputBatch) -> list[bytes]:
        """Every input frame, rate frames re-encoded with every compensated channel and a fresh CRC."""
        channels = batch.channels or {}
        gyros: dict[int, list] = {}
        accels: dict[int, list] = {}
        for name, (accel, axis) in zip(self.plan.covered, self.plan.sources):
            (accels if accel else gyros)[axis] = _values(channels[name].rate_comp_dph)
        # per rate frame, its values by axis: zipped at once where a kind's three axes are all compensated
        gyro_rows = list(zip(gyros[0], gyros[1], gyros[2])) if len(gyros) == 3 else None
        accel_rows = list(zip(accels[0], accels[1], accels[2])) if len(accels) == 3 else None
        reencode, with_accel = self.protocol.reencode, self._accel
        rate_rows = batch.rate_rows
        pieces = [frame.raw for frame in batch.frames]
        for j, index in enumerate(rate_rows):
            frame = batch.frames[index]
            rates = gyro_rows[j] if gyro_rows is not None else _merged(frame.rate_dph, gyros, j)
            if not with_accel:
                pieces[index] = reencode(frame, rates)
                continue
            accel_g = (None if frame.accel_g is None else accel_rows[j] if accel_rows is not None
                       else _merged(frame.accel_g, accels, j))  # fmt: skip
            pieces[index] = reencode(frame, rates, accel_g)
        return pieces

    def _csv_channels(self, batch: OutputBatch) -> list[bytes]:
        """fogd-replay's multi-channel columns and number formats, one row per rate sample."""
        fmt = self._row_format
        return [(fmt % (row[:2] + row[3:])).encode() for row in self._channel_rows(batch)]

    def _jsonl_channels(self, batch: OutputBatch) -> list[bytes]:
        """One JSON object per rate sample: the CSV's names (and temp_rate_cps), null for NaN/Inf."""
        names = ("t_s", "temp_c", "temp_rate_cps", *self._columns[2:])
        flag_names = {name for name in names if name.startswith("flags_")}
        return [
            ("{" + ",".join(f'"{name}":{value if name in flag_names else _json(value)}' for name, value in zip(names, row))
             + "}\n").encode()
            for row in self._channel_rows(batch)
        ]  # fmt: skip

    def _fogd_channels(self, batch: OutputBatch) -> list[bytes]:
        """One fogd compensated-IMU frame (type 05) per rate sample: six channels, each with its flags."""
        channels = batch.channels or {}
        comp = batch.comp
        covered = [(*source(name), name in channels) for name in CHANNELS]
        per_channel = {name: (_values(one.comp_dph), _values(one.rate_comp_dph), _values(one.flags))
                       for name, one in channels.items()}  # fmt: skip
        pieces = []
        for j, (row, t_s, temp_c, temp_rate_cps) in enumerate(
            zip(batch.rate_rows, _values(batch.t_s), _values(comp.temp_c), _values(comp.temp_rate_cps))
        ):
            frame = batch.frames[row]
            comps, compensated, flags = [0.0] * 6, [], [0] * 6
            for i, name in enumerate(CHANNELS):
                accel, axis, done = covered[i]
                reading = _reading(frame, accel, axis)
                if done:
                    values = per_channel[name]
                    comps[i], flags[i] = values[0][j], values[2][j]
                    compensated.append(values[1][j])
                else:
                    compensated.append(reading)
            record = CompImu(
                seq=self._seq, t_s=max(t_s, 0.0),
                rate_dph=tuple(frame.rate_dph), accel_g=frame.accel_g if frame.accel_g is not None else (NAN, NAN, NAN),
                axis_valid=frame.axis_valid, axis_present=frame.axis_present,
                accel_valid=frame.accel_valid, accel_present=frame.accel_present,
                comp=tuple(comps), compensated=tuple(compensated), covered=tuple(done for _, _, done in covered),
                temp_c=temp_c, temp_rate_cps=temp_rate_cps, flags=tuple(flags),
            )  # fmt: skip
            pieces.append(encode_comp_imu(record))
            self._seq = (self._seq + 1) % SEQ_MODULUS
        return pieces


def _reading(frame: Frame, accel: bool, axis: int) -> float:
    """A channel's value in a frame as decoded (NaN for an accelerometer the frame does not carry)."""
    if not accel:
        return frame.rate_dph[axis]
    return frame.accel_g[axis] if frame.accel_g is not None else NAN


def _channel_columns(plan: ChannelPlan) -> tuple[list[str], str]:
    """fogd-replay's multi-channel CSV columns (t_s, temp_c, each carried channel, then for a compensated
    one output_columns(channel)) and the row's printf format."""
    names, formats = ["t_s", "temp_c"], [OUTPUT_FORMATS["t_s"], OUTPUT_FORMATS["temp_c"]]
    for channel in plan.carried:
        names.append(channel)
        formats.append("%.9g")
        if channel in plan.covered:
            names += output_columns(channel)
            formats += ["%.9g", "%.9g", OUTPUT_FORMATS["flags"]]
    return names, ",".join(formats) + "\n"


def _merged(readings: Sequence[float], columns: dict[int, list], row: int) -> list[float]:
    """A frame's readings with the compensated axes' values of `row` in place of theirs."""
    merged = list(readings)
    for axis, values in columns.items():
        merged[axis] = values[row]
    return merged


def _values(column: np.ndarray | list) -> list:
    """A column as Python numbers (the daemon's few-frame batches are lists already)."""
    return column if isinstance(column, list) else column.tolist()


def _json(value: float) -> str:
    return repr(value) if math.isfinite(value) else "null"


def split_batch(batch: OutputBatch) -> list[OutputBatch]:
    """The batch as one batch per frame (the slow path that isolates a frame no format can encode)."""
    position = {row: j for j, row in enumerate(batch.rate_rows)}
    batches = []
    for i, frame in enumerate(batch.frames):
        j = position.get(i)
        rows = slice(j, j + 1) if j is not None else slice(0, 0)
        channels = None if batch.channels is None else {name: _rows(one, rows) for name, one in batch.channels.items()}
        batches.append(OutputBatch([frame], [0] if j is not None else [], batch.t_s[rows], _rows(batch.comp, rows), channels))
    return batches


def _rows(comp: Compensated, rows: slice) -> Compensated:
    return Compensated(comp.temp_c[rows], comp.temp_rate_cps[rows], comp.comp_dph[rows], comp.rate_comp_dph[rows],
                       comp.flags[rows])  # fmt: skip


def rate_rows(frames: list[Frame]) -> list[int]:
    """Indices of the frames that carry a gyro rate."""
    return [index for index, frame in enumerate(frames) if frame.kind in RATE_KINDS]


class SinkError(Exception):
    """A write that failed after `written` bytes of the data had gone (a full disk, a vanished consumer)."""

    def __init__(self, written: int, error: OSError) -> None:
        super().__init__(describe_os_error(error))
        self.written = written
        self.error = error


class Sink:
    """A byte destination with a file descriptor; `write` gives up after a timeout and says how far it got.

    `opener` (devices and FIFOs) opens the same path again, as a new Sink, after the destination went away
    (a USB-serial output replugged, a consumer's pty re-created behind the same link, a FIFO's reader back);
    `ends_on_epipe` (stdout): a reader that closed the pipe ends fogd, as it ends any Unix filter."""

    ends_on_epipe = False

    def __init__(self, name: str, fd: int, *, blocking: bool, on_close=None, opener=None) -> None:
        self.name = name
        self.fd = fd
        self.blocking = blocking  # regular files: the disk, not a consumer, sets the pace
        self._on_close = on_close
        self.opener = opener
        try:
            self.regular = stat.S_ISREG(os.fstat(fd).st_mode)  # a cut frame can be cut off again (truncate)
        except OSError:
            self.regular = False

    def write(self, data: bytes, timeout_s: float) -> int:
        """Bytes of `data` written before `timeout_s` ran out (all of them unless the consumer is stuck);
        SinkError (with the bytes written before it) when the sink fails."""
        view = memoryview(data)
        done = 0
        deadline = time.monotonic() + timeout_s
        while done < len(data):
            if not self.blocking:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    break
                _, ready, _ = select.select([], [self.fd], [], remaining)
                if not ready:
                    break
            try:
                done += os.write(self.fd, view[done:])
            except BlockingIOError:
                continue
            except OSError as error:
                raise SinkError(done, error) from None
        return done

    def cut_back(self, length: int) -> bool:
        """Remove the last `length` bytes written (a frame the disk took only part of); regular files only."""
        if not self.regular:
            return False
        try:
            end = os.lseek(self.fd, 0, os.SEEK_CUR)
            os.ftruncate(self.fd, end - length)
            os.lseek(self.fd, end - length, os.SEEK_SET)
        except OSError:
            return False
        return True

    def reader_present(self) -> bool:
        """Whether frames written now reach a reader (a pty fogd made may have none)."""
        return True

    def close(self) -> None:
        if self._on_close is not None:
            self._on_close()
            self._on_close = None
        self.fd = -1

    def reopen(self) -> bool:
        """Close the descriptor and open the path again (False, still closed, while it cannot be opened)."""
        self.close()
        try:
            new = self.opener()
        except DeviceError:
            return False
        self.fd, self._on_close, self.blocking = new.fd, new._on_close, new.blocking
        return True


def open_sink(spec: str, baud: int) -> Sink:
    """The sink `--out` names: '-' (stdout), 'pty:PATH' (a new pty linked at PATH), or a file or device path.
    Raises DeviceError with one line when it cannot be opened."""
    if spec == "-":
        return _stdout_sink()
    if spec.startswith(PTY_PREFIX):
        return _pty_sink(spec[len(PTY_PREFIX) :])
    try:
        mode = os.stat(spec).st_mode
    except FileNotFoundError:
        mode = 0
    except OSError as error:
        raise DeviceError(f"cannot open output {describe_os_error(error)}") from None
    if stat.S_ISCHR(mode):
        return _device_sink(spec, baud)
    try:
        if stat.S_ISFIFO(mode):
            return _fifo_sink(spec)
        fd = os.open(spec, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    except OSError as error:
        raise DeviceError(f"cannot open output {describe_os_error(error)}") from None
    return Sink(spec, fd, blocking=True, on_close=lambda: os.close(fd))


def _stdout_sink() -> Sink:
    if stat.S_ISREG(os.fstat(1).st_mode):
        sink = Sink("stdout", 1, blocking=True)
    else:
        # A pipe or terminal: a fresh open file description, so non-blocking mode does not leak to the shell.
        try:
            fd = os.open("/proc/self/fd/1", os.O_WRONLY | os.O_NONBLOCK | os.O_NOCTTY)
        except OSError:
            sink = Sink("stdout", 1, blocking=True)
        else:
            sink = Sink("stdout", fd, blocking=False, on_close=lambda: os.close(fd))
    sink.ends_on_epipe = True
    return sink


def _fifo_sink(path: str) -> Sink:
    """A FIFO, written without blocking; reopened when its reader comes back (ENXIO until one does)."""
    try:
        fd = os.open(path, os.O_WRONLY | os.O_NONBLOCK)
    except OSError as error:
        raise DeviceError(f"cannot open output {describe_os_error(error)}") from None
    return Sink(path, fd, blocking=False, on_close=lambda: os.close(fd), opener=lambda: _fifo_sink(path))


def _device_sink(path: str, baud: int) -> Sink:
    """A serial port or someone else's pty (opened like the input port), or another character device such
    as /dev/null; written without blocking, and opened again (the same path) when it goes away and returns."""
    try:
        fd = os.open(path, os.O_WRONLY | os.O_NOCTTY | os.O_NONBLOCK)
    except OSError as error:
        raise DeviceError(f"cannot open output {describe_os_error(error)}") from None
    opener = lambda: _device_sink(path, baud)  # noqa: E731
    if not os.isatty(fd):
        return Sink(path, fd, blocking=False, on_close=lambda: os.close(fd), opener=opener)
    os.close(fd)
    try:
        port = serial.Serial(path, baud, write_timeout=0, exclusive=True)
    except serial.SerialException as error:
        raise DeviceError(f"cannot open output {describe_open_error(path, error)}") from None
    except (OSError, ValueError) as error:
        raise DeviceError(f"cannot open output {path}: {error}") from None
    return Sink(path, port.fd, blocking=False, on_close=port.close, opener=opener)


def _pty_sink(link: str) -> Sink:
    """A new pty in raw mode with `link` pointing at its slave; fogd writes to the master."""
    link_path = Path(link)
    if link_path.exists() and not link_path.is_symlink():
        raise DeviceError(f"cannot make pty link {link}: it exists and is not a symlink; remove it or choose another path")
    master, slave = os.openpty()
    try:
        tty.setraw(slave)
        os.set_blocking(master, False)
        slave_name = os.ttyname(slave)
        link_path.parent.mkdir(parents=True, exist_ok=True)
        temporary = link_path.with_name(f".{link_path.name}.{os.getpid()}")
        os.symlink(slave_name, temporary)
        os.replace(temporary, link_path)
    except OSError as error:
        os.close(master)
        os.close(slave)
        raise DeviceError(f"cannot make pty link {link}: {describe_os_error(error)}") from None
    log.info("output pty %s -> %s", link, slave_name)
    # fogd does not keep the slave open (the master's writes succeed all the same, and its raw mode stays):
    # the master's poll then says whether a reader holds it (PtySink)
    os.close(slave)

    def close() -> None:
        try:
            if os.readlink(link_path) == slave_name:
                link_path.unlink()
        except OSError:
            pass
        os.close(master)

    return PtySink(f"pty {link}", master, blocking=False, on_close=close)


class PtySink(Sink):
    """A pty fogd made: frames go to it only while a reader holds its slave open. While none does they are
    dropped (counted `frames_dropped_no_reader`), and what a reader that left had not read is flushed, so a
    consumer that (re)opens the link gets the CSV header (if any) and then live frames, never seconds-old ones
    queued in the kernel (KVH frames carry no time to tell them by)."""

    def __init__(self, name: str, fd: int, **kwargs) -> None:
        super().__init__(name, fd, **kwargs)
        self._poll = select.poll()
        self._poll.register(fd, 0)  # no events asked: poll reports the hang-up alone (no slave open)
        self._reader = False
        self.arrived = False  # a reader opened it since the writer last looked: the header goes first

    def reader_present(self) -> bool:
        if any(events & select.POLLHUP for _, events in self._poll.poll(0)):
            if self._reader:
                self._reader = False
                try:
                    termios.tcflush(self.fd, termios.TCOFLUSH)  # what the reader left unread
                except termios.error:
                    pass
                log.info("%s: reader gone; frames dropped until one opens it", self.name)
            return False
        if not self._reader:
            self._reader = self.arrived = True
            log.info("%s: a reader opened it", self.name)
        return True


@dataclass
class WriterCounters:
    """Every frame handed to `submit` ends in exactly one of these, or is `frames_pending` (the writer is still
    finishing a frame the consumer took part of): submitted = written + dropped_* + cut + pending."""

    frames_submitted: int = 0
    frames_written: int = 0
    frames_dropped_full: int = 0  # queue full: the consumer is behind
    frames_dropped_timeout: int = 0  # the consumer did not take bytes within the write timeout
    frames_dropped_error: int = 0  # the sink reported an error
    frames_dropped_exit: int = 0  # still queued when the flush at exit ran out of time
    frames_dropped_no_reader: int = 0  # a pty fogd made with no reader holding it (not queued for a later one)
    frames_cut: int = 0  # begun on the wire but never finished: the consumer stalled through the exit flush
    frames_pending: int = 0  # begun on the wire; its rest goes before anything else
    reopens: int = 0  # times the output came back after it went away (not a frame count)


class Writer:
    """The writer thread: a bounded queue of encoded chunks drained into a sink with a write timeout.

    A frame goes on the wire whole or not at all: when the consumer takes part of a frame and then stalls,
    the rest of that frame is kept (`frames_pending`) and written before any later byte, and the frames behind
    it are dropped (counted); on a regular file a frame the disk took only part of is cut off again."""

    def __init__(self, sink: Sink, *, queue_chunks: int = QUEUE_CHUNKS, write_timeout_s: float = WRITE_TIMEOUT_S) -> None:
        self.sink = sink
        self.write_timeout_s = write_timeout_s
        self.counters = WriterCounters()
        self._queue: queue.Queue[Chunk | None] = queue.Queue(maxsize=queue_chunks)
        self._thread = threading.Thread(target=self._run, name="fogd-writer", daemon=True)
        self._error_logged = False
        self.error: BaseException | None = None  # what killed the thread, if anything did
        # chunks queued (counted by `submit`'s thread) and written (by the writer thread): each counter has one
        # writer, so no lock; equal means the writer thread is idle in `get` with nothing queued.
        self._queued = 0
        self._done = 0
        self._tail = b""  # the unwritten rest of a frame begun on the wire (writer thread's, set before _done)
        self._give_up_s = math.inf  # monotonic time after which queued chunks are counted, not written (exit)
        self._running = False  # the thread is in `_run` (a flag: `Thread.is_alive` is three Python calls a submit)
        self._header = b""
        self._gated = isinstance(sink, PtySink)  # frames only while a reader holds it
        self.consumer_gone = False  # stdout's reader closed the pipe (EPIPE): the daemon stops
        self._failing_since_s: float | None = None  # the first failed write since the last one that worked
        self._down_since_s: float | None = None  # the sink went away and is being reopened (writer thread's)
        self._retry_s = 0.0
        self._backoff_s = REOPEN_FIRST_S

    def start(self, header: bytes = b"") -> None:
        self._header = header
        if self._gated and not self.sink.reader_present():
            header = b""  # written when a reader opens it
        if self._gated:
            self.sink.arrived = False
        if header:
            try:
                self.sink.write(header, self.write_timeout_s)
            except SinkError:
                pass  # the frames' own writes report the error
        self._running = True
        self._thread.start()

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def failing_s(self, now_s: float) -> float:
        """How long every write has failed (the sink gone, being reopened); 0 while writes work."""
        since_s = self._failing_since_s
        return 0.0 if since_s is None else now_s - since_s

    def submit(self, chunk: Chunk) -> None:
        """Queue a chunk without waiting; a full queue drops it (counted), and so does a pty of fogd's own
        with no reader (a reader that opens it later gets the header first, then frames from then on)."""
        if not chunk.frame_ends:
            return
        self.counters.frames_submitted += len(chunk.frame_ends)
        if self._gated:
            sink = self.sink
            if not sink.reader_present():
                self.counters.frames_dropped_no_reader += len(chunk.frame_ends)
                return
            if sink.arrived:
                sink.arrived = False
                if self._header:
                    size = len(self._header)
                    chunk = Chunk(self._header + chunk.data, [end + size for end in chunk.frame_ends], chunk.begun)
        if not self.sink.blocking and self._queued == self._done and not self._tail and self._running:
            # one non-blocking write on the caller's thread while the writer thread is idle (so the counters
            # have one writer at a time); what the consumer did not take goes to the queue
            try:
                written = os.write(self.sink.fd, chunk.data)
            except OSError:  # would block, or an error the writer thread logs and counts by its own policy
                written = -1
            if written >= 0:
                self._failing_since_s = None
                if written == len(chunk.data):  # (inline: the daemon's every frame when the consumer keeps up)
                    self.counters.frames_written += len(chunk.frame_ends)
                    return
                chunk = self._rest(chunk, written)
        try:
            self._queue.put_nowait(chunk)
            self._queued += 1
        except queue.Full:  # (never the rest of a direct write: the writer was idle, the queue empty)
            self.counters.frames_dropped_full += len(chunk.frame_ends)

    def _rest(self, chunk: Chunk, written: int) -> Chunk:
        """What is left of `chunk` after a write took its first `written` bytes (its whole frames counted)."""
        complete = bisect.bisect_right(chunk.frame_ends, written)
        self.counters.frames_written += complete
        begun = written > (chunk.frame_ends[complete - 1] if complete else 0)
        return Chunk(chunk.data[written:], [end - written for end in chunk.frame_ends[complete:]], begun)

    def close(self, timeout_s: float) -> bool:
        """Write what is queued (within `timeout_s`), stop the thread and close the sink; False if it timed out.
        What the flush could not write is counted (dropped at exit, or cut)."""
        deadline = time.monotonic() + timeout_s
        flushed = True
        if self._thread.is_alive():
            self._give_up_s = deadline
            try:
                self._queue.put(None, timeout=max(0.0, deadline - time.monotonic()))
            except queue.Full:
                flushed = False
                # past the deadline the thread counts chunks instead of writing them: room comes within a write
                try:
                    self._queue.put(None, timeout=self.write_timeout_s + 1.0)
                except queue.Full:
                    pass
            self._thread.join(max(0.0, deadline - time.monotonic()) + (0.0 if flushed else self.write_timeout_s + 1.0))
            flushed = flushed and not self._thread.is_alive()
        if not self._thread.is_alive():
            self.sink.close()
        return flushed

    def _run(self) -> None:
        try:
            while True:
                chunk = self._queue.get()
                if chunk is None:
                    self._finish_tail()
                    return
                if time.monotonic() > self._give_up_s:
                    self.counters.frames_dropped_exit += len(chunk.frame_ends)
                else:
                    self._write(chunk)
                self._done += 1
        except BaseException as error:  # the daemon notices a dead writer through `alive` and `error`
            self.error = error
            raise
        finally:
            self._running = False

    def _finish_tail(self) -> None:
        """At exit: finish a frame begun on the wire, or count it cut."""
        if not self._tail:
            return
        try:
            written = self.sink.write(self._tail, max(0.0, min(self.write_timeout_s, self._give_up_s - time.monotonic())))
        except SinkError as error:
            written = error.written
        counters = self.counters
        counters.frames_pending = 0
        if written == len(self._tail):
            counters.frames_written += 1
        else:
            counters.frames_cut += 1
        self._tail = b""

    def _reopened(self) -> bool:
        """Whether the sink that went away is back (tried again after a back-off doubling up to REOPEN_MAX_S)."""
        now_s = time.monotonic()
        if now_s < self._retry_s:
            return False
        if not self.sink.reopen():
            self._retry_s = now_s + self._backoff_s
            self._backoff_s = min(2.0 * self._backoff_s, REOPEN_MAX_S)
            return False
        log.warning("%s: reopened after %.1f s; writing again", self.sink.name, now_s - (self._down_since_s or now_s))
        self.counters.reopens += 1
        self._down_since_s = None
        self._backoff_s = REOPEN_FIRST_S
        self._error_logged = False
        return True

    def _went_away(self, failure: SinkError) -> None:
        """The sink failed: stdout's reader gone ends fogd; a device or FIFO is closed and reopened."""
        if self._failing_since_s is None:
            self._failing_since_s = time.monotonic()
        if failure.error.errno == errno.EPIPE and self.sink.ends_on_epipe:
            self.consumer_gone = self._error_logged = True  # the daemon says so, and stops
            return
        if self.sink.opener is not None and self._down_since_s is None:
            self._down_since_s = self._retry_s = time.monotonic()
            self._backoff_s = REOPEN_FIRST_S
            self.sink.close()
            if not self._error_logged:
                log.warning("%s: write failed: %s; reopening it as it comes back", self.sink.name, failure)
                self._error_logged = True

    def _write(self, chunk: Chunk) -> None:
        counters = self.counters
        if self._down_since_s is not None and not self._reopened():
            counters.frames_dropped_error += len(chunk.frame_ends)
            return
        if self.consumer_gone:
            counters.frames_dropped_error += len(chunk.frame_ends)
            return
        data, ends, begun = chunk.data, chunk.frame_ends, chunk.begun
        if self._tail:  # finish the frame begun on the wire before anything else
            tail = self._tail
            data, ends, begun = tail + data, [len(tail), *(end + len(tail) for end in ends)], True
            counters.frames_pending = 0
            self._tail = b""
        failure: SinkError | None = None
        try:
            written = self.sink.write(data, self.write_timeout_s)
        except SinkError as error:
            written, failure = error.written, error
        complete = bisect.bisect_right(ends, written)
        frame_start = ends[complete - 1] if complete else 0
        partial = complete < len(ends) and (written > frame_start or (complete == 0 and begun))
        if partial and failure is not None and written > frame_start and self.sink.cut_back(written - frame_start):
            partial = False  # a file: the frame the disk took part of is gone again, whole
        cut = 0
        if partial and failure is not None and self.sink.opener is not None:
            counters.frames_cut += 1  # begun on a device that went away: the one reopened gets whole frames only
            partial, cut = False, 1
        if partial:
            self._tail = data[written : ends[complete]]
            counters.frames_pending = 1
        lost = len(ends) - complete - (1 if partial else 0) - cut
        counters.frames_written += complete
        if failure is None:
            self._error_logged = False
            self._failing_since_s = None
            counters.frames_dropped_timeout += lost
            return
        self._went_away(failure)
        if not self._error_logged:
            log.warning("%s: write failed: %s; dropping output until it recovers", self.sink.name, failure)
            self._error_logged = True
        counters.frames_dropped_error += lost
