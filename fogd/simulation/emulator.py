"""The FOG emulator behind `fogd-emu` (after gpsd's gpsfake): it plays a simulated or recorded run onto a
pseudo-terminal as a gyro would, in any of fogd's wire protocols, so the real daemon can be tested end to end.
This module owns the sample sources (`SimSource`, `RunSource`), turning samples into wire frames, seeded fault
injection and its JSON-lines ledger, real-time pacing with backpressure, and the pty itself (`open_pty`: raw
mode, an atomically re-pointed symlink, unplug and replug). An IMU source (a simulated IMU, a multi-channel
recorded run) streams all three gyros and, in KVH frames, the three accelerometers, in whatever output the
protocol's options set (rate or delta, radians or degrees, g or delta velocity); fogd IMU frames (type 04)
carry the same six channels. `Emulator(...).start()` streams on a thread and
returns the slave's path; `stop()` and `join()` end it, draining what the reader has not yet taken.
"""

from __future__ import annotations

import fcntl
import json
import logging
import math
import os
import random
import secrets
import select
import struct
import termios
import threading
import time
import tty
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import IO, TYPE_CHECKING
from typing import Protocol as TypingProtocol

import numpy as np

from fogd import protocols
from fogd.core.atomic import output_kind
from fogd.core.columns import ACCEL_CHANNELS, GYRO_CHANNELS, SINGLE_CHANNEL
from fogd.core.runio import Run
from fogd.errors import (
    ConfigError,
    DeviceError,
    FogdError,
    InputError,
    OutputError,
    describe_os_error,
)
from fogd.protocols.base import ALL_AXES, NAN, NO_AXES, Z_ONLY, Frame, FrameError
from fogd.protocols.kvh import KvhProtocol, settings_reply
from fogd.simulation.profiles import Profile

if TYPE_CHECKING:
    from fogd.simulation.simulator import SimParams

log = logging.getLogger("fogd-emu")

TICK_S = 0.001  # real-time pacing writes every frame that is due, at most once per tick
FAST_BATCH_SAMPLES = 64
BLOCK_ROWS = 1024
SPLIT_PAUSE_S = 0.002
POLL_MS = 50  # how long a blocked write waits before looking at stop() again
NO_READER_RETRY_S = 0.005
# pyserial flushes the input right after opening a port: frames written in that moment would be lost.
READER_SETTLE_S = 0.1
# Bytes already written at an unplug are on the wire: a reader that keeps up gets them before the pty closes.
UNPLUG_DRAIN_S = 0.2
MAX_GARBAGE_BYTES = 16
FAULTS = ("garbage", "bitflip", "drop", "repeat", "nan", "clear_status", "split")
CONFIG_POLL_S = 0.01  # kvh-a in configuration mode: how often the input is looked at
MAX_INPUT_BYTES = 4096  # of an unended input line kept
HEADER_BYTES = {"kvh-a": 4, "fogd": 4, "ascii": 0}  # bytes a bit flip leaves alone: sync, type, length


class SampleSource(TypingProtocol):
    """Rows of a run at `rate_hz`: `columns(start, stop)` gives (t_s from the first row, rate_dph, temp_c).

    A source with `imu` True has `imu_columns(start, stop)` instead: (t_s, gyro xyz deg/h, accel xyz g or None,
    temp_c), the arrays (rows, 3); a channel the source lacks is NaN (a gyro) or the accels are None."""

    rate_hz: float
    rows: int

    def columns(self, start: int, stop: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...


ImuColumns = tuple[np.ndarray, np.ndarray, "np.ndarray | None", np.ndarray]


class SimSource:
    """A live simulated chamber run (fogd.simulation.simulator), made block by block as it is streamed."""

    def __init__(self, profile: Profile, rate_hz: float, seed: int, params: SimParams | None = None, imu: bool = False) -> None:
        from fogd.simulation.simulator import (
            Simulation,  # imports scipy (most of a second): only when simulating
        )

        try:
            self._sim = Simulation(profile, rate_hz, seed, params)
        except ValueError as error:
            raise ConfigError(f"simulator: {error}") from None
        self.rate_hz = self._sim.rate_hz
        self.rows = self._sim.rows
        self.imu = imu

    def columns(self, start: int, stop: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        columns = self._sim.columns(start, stop)
        return columns["t_s"], columns["rate_dph"], columns["temp_c"]

    def imu_columns(self, start: int, stop: int) -> ImuColumns:
        columns = self._sim.imu_columns(start, stop)
        gyro = np.column_stack([columns[name] for name in GYRO_CHANNELS])
        accel = np.column_stack([columns[name] for name in ACCEL_CHANNELS])
        return columns["t_s"], gyro, accel, columns["temp_c"]


class RunSource:
    """A recorded run (fogd.core.runio.read_run), played at its own sample rate."""

    def __init__(self, run: Run) -> None:
        self.run = run
        self.rate_hz = run.rate_hz
        self.rows = run.rows
        self.imu = SINGLE_CHANNEL not in run.channels  # a multi-channel run: every channel it has

    def columns(self, start: int, stop: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        run = self.run
        return run.t_s[start:stop] - run.t_s[0], run.rate_dph[start:stop], run.temp_c[start:stop]

    def imu_columns(self, start: int, stop: int) -> ImuColumns:
        run = self.run
        channels = run.channels

        def stack(names: tuple[str, ...]) -> np.ndarray:
            return np.column_stack([channels[name][start:stop] if name in channels else np.full(stop - start, np.nan)
                                    for name in names])  # fmt: skip

        accel = stack(ACCEL_CHANNELS) if any(name in channels for name in ACCEL_CHANNELS) else None
        return run.t_s[start:stop] - run.t_s[0], stack(GYRO_CHANNELS), accel, run.temp_c[start:stop]


@dataclass(frozen=True)
class Faults:
    """What to inject: per-frame probabilities (0..1), the unplug schedule (wall-clock seconds: connected for
    `unplug_every_s`, then gone for `unplug_for_s`) and the seed every random choice is drawn from."""

    garbage: float = 0.0  # random bytes before a frame (never a sync byte, so they are pure garbage)
    bitflip: float = 0.0  # one bit flipped after the sync/type/length bytes: a bad CRC, not a lost sync
    drop: float = 0.0  # frame not sent (its sequence number is used up)
    repeat: float = 0.0  # frame sent twice
    nan: float = 0.0  # NaN rate with a good CRC and the status bit saying valid
    clear_status: float = 0.0  # one gyro-valid status bit cleared (kvh-a: x, y or z; fogd: z)
    split: float = 0.0  # frame cut in two writes with a short pause between
    unplug_every_s: float | None = None
    unplug_for_s: float = 1.0
    seed: int = 0

    def __post_init__(self) -> None:
        for name in FAULTS:
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ConfigError(f"fault probability {name.replace('_', '-')} must be within 0..1, not {value!r}")
        if self.unplug_every_s is not None and not self.unplug_every_s > 0:
            raise ConfigError(f"unplug-every-s must be > 0 s, not {self.unplug_every_s!r}")
        if not self.unplug_for_s >= 0:
            raise ConfigError(f"unplug-for-s must be >= 0 s, not {self.unplug_for_s!r}")


@dataclass
class EmulatorStats:
    """What the emulator did; `frames_sent` counts every frame written, repeats and corrupted ones included."""

    samples: int = 0
    frames_sent: int = 0
    faults: dict[str, int] = field(default_factory=lambda: dict.fromkeys(FAULTS, 0))
    garbage_bytes: int = 0
    dropped_full: int = 0
    lost_unplugged: int = 0
    replugs: int = 0
    backpressure_s: float = 0.0
    elapsed_s: float = 0.0

    def summary(self) -> str:
        injected = ", ".join(f"{name.replace('_', '-')} {count}" for name, count in self.faults.items() if count)
        return (
            f"sent {self.frames_sent} frames for {self.samples} samples in {self.elapsed_s:.2f} s "
            f"(backpressure {self.backpressure_s:.2f} s); faults: {injected or 'none'}; "
            f"dropped when full {self.dropped_full}; lost while unplugged {self.lost_unplugged}; "
            f"replugs {self.replugs}"
        )


@dataclass(slots=True)
class _Emission:
    """One frame's trip to the wire and its ledger line."""

    sample: int
    clean: bytes  # the frame as encoded, before a bit flip
    wire: bytes  # the frame as sent
    faults: list[str]
    parts: list[bytes]  # the writes: garbage + frame, cut in two by a split; empty when not sent
    garbage_bytes: int = 0
    t_s: float = 0.0

    @property
    def sent(self) -> bool:
        return bool(self.parts)

    def lose(self, reason: str) -> None:
        """Not sent after all ('full', 'unplugged'): the faults drawn for it never reached the wire."""
        self.faults, self.parts, self.garbage_bytes = [reason], [], 0


class _Stopped(Exception):
    """stop() was called while the emulator waited for the reader."""


class PtyEndpoint:
    """One pty pair. The emulator holds the master only: while no reader has the slave open, poll on the
    master says POLLHUP, so `reader_present` can tell; bytes written meanwhile wait in the pty buffer."""

    def __init__(self, link: str | None = None) -> None:
        self.master_fd, slave_fd = os.openpty()
        try:
            tty.setraw(slave_fd)  # no byte translated, no echo; the setting outlives this descriptor
            self.path = os.ttyname(slave_fd)
        finally:
            os.close(slave_fd)
        os.set_blocking(self.master_fd, False)
        self._poll = select.poll()
        self._poll.register(self.master_fd, select.POLLOUT)
        self.link = link
        if link is not None:
            try:
                point_link(link, self.path)
            except FogdError:
                os.close(self.master_fd)
                raise

    def reader_present(self) -> bool:
        return not any(events & select.POLLHUP for _, events in self._poll.poll(0))

    def wait_writable(self, timeout_ms: int) -> bool:
        """False when there is no reader and the buffer is full (poll would not block then)."""
        return any(events & select.POLLOUT for _, events in self._poll.poll(timeout_ms))

    def read_input(self) -> bytes:
        """What the reader wrote (e.g. KVH =CONFIG commands and queries), taken so its writes never block."""
        data = b""
        try:
            while chunk := os.read(self.master_fd, 4096):
                data += chunk
        except OSError:  # EAGAIN: nothing more; EIO: no reader
            pass
        return data

    def drain(self, timeout_s: float) -> bool:
        """Wait (at most timeout_s) until the reader has taken every written byte; closing the master
        earlier would throw them away."""
        deadline = time.monotonic() + timeout_s
        try:
            probe = os.open(self.path, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
        except OSError:  # e.g. a reader holding the tty with TIOCEXCL: no way to look, so give it the bound
            time.sleep(timeout_s)
            return False
        poller = select.poll()
        poller.register(probe, select.POLLIN)
        try:
            quiet = 0
            while True:
                # Written bytes reach the slave's queue through a kernel work queue that FIONREAD does not
                # wait for (poll does): ask both, twice.
                pending = poller.poll(0) or _queued_bytes(probe) > 0
                quiet = 0 if pending else quiet + 1
                if quiet == 2:
                    return True
                if time.monotonic() >= deadline:
                    return False
                time.sleep(0.01)
        finally:
            os.close(probe)

    def close(self) -> None:
        """Close the master (the reader sees the device vanish) and remove the link if it is still ours."""
        if self.master_fd < 0:
            return
        os.close(self.master_fd)
        self.master_fd = -1
        if self.link is not None:
            remove_link(self.link, self.path)


def open_pty(link: str | None = None) -> PtyEndpoint:
    """A raw pty pair; with `link`, that path becomes a symlink to the slave."""
    return PtyEndpoint(link)


def point_link(link: str, target: str) -> None:
    """Make `link` a symlink to `target`, replacing an old link atomically (never a regular file)."""
    if os.path.lexists(link) and not os.path.islink(link):
        raise DeviceError(f"{link}: exists and is not a symlink; refusing to replace it")
    directory, name = os.path.split(link)
    temporary = os.path.join(directory, f".{name}.{secrets.token_hex(8)}.tmp")  # random: nothing planted sits there
    try:
        os.symlink(target, temporary)  # never follows: fails if anything is at that name
        try:
            os.replace(temporary, link)
        except OSError:
            os.unlink(temporary)
            raise
    except OSError as error:  # the link's path, not the pty's (/dev/pts/N is fine; the link's directory is not)
        raise DeviceError(f"cannot create link {link}: {error.strerror or error}") from None


def remove_link(link: str, target: str) -> None:
    """Remove `link` if it still points to `target` (another emulator may have taken it over)."""
    try:
        if os.readlink(link) == target:
            os.unlink(link)
    except OSError:
        pass


def _queued_bytes(fd: int) -> int:
    return struct.unpack("i", fcntl.ioctl(fd, termios.FIONREAD, b"\0\0\0\0"))[0]


class Emulator:
    """Streams `source` as `protocol` frames onto a pty.

    speed: real time times this (frames stay paced); None: as fast as the reader takes them.
    count: stop after this many samples (one rate frame each; fogd temperature frames come on top);
    None: at the end of the source, or never with `loop`. temp_rate_hz: fogd temperature frame rate.
    wait_reader: send nothing until a reader has opened the slave (at start and after every replug).
    drop_when_full: drop (and count) a frame the pty cannot take now instead of waiting for the reader.
    ledger: a path; one JSON line per frame (see `_ledger_line`). on_replug(path): called with each new pty.
    protocol_options: the protocol's settings (kvh-a: rotfmt, linfmt, angle_unit, lin_unit, temp_unit); a
    `delta` setting takes the source's rate as the unit's data rate.
    """

    def __init__(
        self,
        source: SampleSource,
        protocol: str = "kvh-a",
        *,
        speed: float | None = 1.0,
        count: int | None = None,
        loop: bool = False,
        temp_rate_hz: float = 10.0,
        faults: Faults | None = None,
        link: str | None = None,
        ledger: str | None = None,
        drop_when_full: bool = False,
        wait_reader: bool = False,
        drain_timeout_s: float = 2.0,
        on_replug: Callable[[str], None] | None = None,
        protocol_options: dict[str, object] | None = None,
    ) -> None:
        options = dict(protocol_options or {})
        if protocol == "kvh-a":  # the unit's data rate (=DR): what a delta output is per, what ?DR answers
            options.setdefault("rate_hz", source.rate_hz)
        self.protocol = protocols.get(protocol, **options)
        self.imu = bool(getattr(source, "imu", False))
        if self.imu and protocol == "ascii":
            raise ConfigError("ascii lines carry one gyro axis: an IMU needs --protocol kvh-a or fogd")
        self.faults = faults or Faults()
        if speed is not None and not (speed > 0 and math.isfinite(speed)):
            raise ConfigError(f"speed must be a positive number, not {speed!r}")
        if count is not None and count < 1:
            raise ConfigError(f"count must be at least 1, not {count!r}")
        if protocol == "fogd" and not 0 < temp_rate_hz <= source.rate_hz:
            raise ConfigError(f"temperature rate must be within 0..{source.rate_hz:g} Hz (the rate), not {temp_rate_hz!r}")
        if self.faults.clear_status and protocol == "ascii":
            raise ConfigError("clear-status needs a protocol with status bits (kvh-a or fogd), not ascii")
        if protocol == "kvh-a" and isinstance(source, RunSource):
            bad = np.flatnonzero(~np.isfinite(source.run.temp_c))
            if bad.size:
                raise InputError(
                    f"{source.run.path}: data row {bad[0] + 1} has temperature {source.run.temp_c[bad[0]]}; "
                    "KVH Format A carries whole degrees only (use --protocol fogd or ascii)"
                )
        self.source, self.speed, self.count, self.loop = source, speed, count, loop
        self.temp_rate_hz, self.link, self.ledger_path = temp_rate_hz, link, ledger
        self.drop_when_full, self.wait_reader, self.drain_timeout_s = drop_when_full, wait_reader, drain_timeout_s
        self.on_replug = on_replug
        self.stats = EmulatorStats()
        self.pty: PtyEndpoint | None = None
        self._rng = random.Random(self.faults.seed)
        sync = self.protocol.sync
        # Garbage never holds the first sync byte, and ASCII garbage is a whole non-ASCII line: either way the
        # lexer can only count it as garbage (or one bad line), so its counters can be checked exactly.
        self._garbage_alphabet = bytes(range(0x80, 0x100)) if not sync else bytes(b for b in range(256) if b != sync[0])
        self._flip_from = HEADER_BYTES[protocol]
        self._flip_tail = 1 if protocol == "ascii" else 0  # keep the newline: a flipped line stays one line
        self._temp_frames = 0
        self._ledger: IO[str] | None = None
        self._ledger_index = 0
        self._schedule_shift_s = 0.0
        self._said_no_reader = False
        self._unsent = b""  # drop_when_full: the rest of a frame the pty took only part of
        self._input = b""  # the reader's last line, not yet ended
        self._config_mode = False  # kvh-a: between =CONFIG,1 and =CONFIG,0 the unit answers and does not stream
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None

    @property
    def path(self) -> str | None:
        """The current slave path (a new one after each replug)."""
        return self.pty.path if self.pty else None

    def start(self) -> str:
        """Open the pty (and the ledger), start streaming on a thread; returns the slave's path."""
        if self.ledger_path is not None:
            try:
                output_kind(self.ledger_path)  # a directory, block device or socket, or a missing directory: refused
                self._ledger = open(self.ledger_path, "w", encoding="utf-8")
            except OSError as error:
                raise OutputError(f"cannot write ledger {self.ledger_path}: {error.strerror or error}") from None
        try:
            self.pty = open_pty(self.link)
        except BaseException:
            self._close_ledger()
            raise
        self._thread = threading.Thread(target=self._main, name="fogd-emu", daemon=True)
        self._thread.start()
        return self.pty.path

    def stop(self) -> None:
        """Ask the stream to end; it drains and closes on its thread (see `join`)."""
        self._stop.set()

    def join(self, timeout: float | None = None) -> bool:
        """Wait for the end; True when it has ended. Raises what ended the stream abnormally."""
        if self._thread is None:
            return True
        self._thread.join(timeout)
        if self._thread.is_alive():
            return False
        if self._error is not None:
            error, self._error = self._error, None
            raise error
        return True

    def run(self) -> EmulatorStats:
        """start() and join(): stream in full."""
        self.start()
        self.join()
        return self.stats

    def __enter__(self) -> Emulator:
        self.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.stop()
        self.join()

    def _main(self) -> None:
        started = time.monotonic()
        try:
            self._stream()
        except _Stopped:
            pass
        except FogdError as error:
            self._error = error
        except OSError as error:
            self._error = DeviceError(f"pty: {describe_os_error(error)}")
        except BaseException as error:  # a bug: hand it to join() rather than dying silently
            self._error = error
        finally:
            try:
                if self.pty is not None and self.pty.master_fd >= 0:
                    self.pty.drain(self.drain_timeout_s)
            finally:
                if self.pty is not None:
                    self.pty.close()
                self._close_ledger()
                self.stats.elapsed_s = time.monotonic() - started

    def _close_ledger(self) -> None:
        if self._ledger is not None:
            self._ledger.close()
            self._ledger = None

    def _stream(self) -> None:
        paced = self.speed is not None
        period_s = 1.0 / (self.source.rate_hz * self.speed) if paced else 0.0
        faults = self.faults
        samples = self._samples()
        pending = next(samples, None)
        self._wait_for_reader()
        start = connected_at = time.monotonic()
        unplugged_until: float | None = None
        while pending is not None:
            if self._stop.is_set():
                return
            if self._config_mode and unplugged_until is None:
                paused = time.monotonic()
                self._stop.wait(CONFIG_POLL_S)
                self._answer_input()
                self._schedule_shift_s += time.monotonic() - paused  # the stream resumes at its pace, no burst
                continue
            now = time.monotonic()
            if unplugged_until is None and faults.unplug_every_s and now - connected_at >= faults.unplug_every_s:
                self._finish_unsent()
                self.pty.drain(UNPLUG_DRAIN_S)
                self.pty.close()
                unplugged_until = time.monotonic() + faults.unplug_for_s
            if unplugged_until is not None and now >= unplugged_until:
                waited_s = self._replug()
                self._schedule_shift_s += waited_s
                unplugged_until, connected_at = None, time.monotonic()
                continue
            if unplugged_until is not None and not paced:
                self._stop.wait(unplugged_until - now)
                continue
            batch = []
            if paced:
                due_s = start + self._schedule_shift_s
                while pending is not None and due_s + pending[0] * period_s <= now:
                    batch.append(pending)
                    pending = next(samples, None)
            else:
                while pending is not None and len(batch) < FAST_BATCH_SAMPLES:
                    batch.append(pending)
                    pending = next(samples, None)
            emissions = [emission for sample in batch for emission in self._emissions(*sample)]
            self.stats.samples += len(batch)
            if unplugged_until is not None:  # the gyro kept sampling; nobody could hear it
                for emission in emissions:
                    emission.lose("unplugged")
            else:
                self._answer_input()
                self._send(emissions)
            self._account(emissions)
            if paced and pending is not None:
                next_due_s = start + self._schedule_shift_s + pending[0] * period_s
                delay_s = max(next_due_s, now + TICK_S) - time.monotonic()
                if delay_s > 0:
                    self._stop.wait(delay_s)
        self._finish_unsent()

    def _answer_input(self) -> None:
        """Take what the reader wrote. A KVH unit answers its setting queries (`?ROTFMT` -> `ROTFMT,RATE`, as
        fogd.protocols.kvh.settings_reply) and sends no frames between `=CONFIG,1` and `=CONFIG,0`; anything
        else (other commands, other protocols) is ignored."""
        data = self.pty.read_input()
        if not data:
            return
        *lines, self._input = (self._input + data)[-MAX_INPUT_BYTES:].split(b"\n")
        if not isinstance(self.protocol, KvhProtocol):
            return
        for line in lines:
            command = line.strip().upper()
            if command in (b"=CONFIG,1", b"=CONFIG,0"):
                self._config_mode = command.endswith(b"1")
            elif command.startswith(b"?"):
                try:
                    reply = settings_reply(self.protocol, command[1:].decode("ascii", "replace"))
                except ValueError:  # a query this emulator does not know: no answer
                    continue
                self._write(reply)

    def _finish_unsent(self) -> None:
        self._write(self._unsent)
        self._unsent = b""

    def _samples(self) -> Iterator[tuple[int, float, object, float]]:
        """(sample index, device time s, rate_dph, temp_c); a loop continues the device clock. From an IMU
        source, rate_dph is (gyro xyz, accel xyz or None)."""
        source = self.source
        rows = source.rows
        total = self.count if self.count is not None else (None if self.loop else rows)
        index = 0
        while total is None or index < total:
            loop, row = divmod(index, rows)
            if loop and not self.loop:
                return
            stop = min(row + BLOCK_ROWS, rows) if total is None else min(row + BLOCK_ROWS, rows, row + total - index)
            offset_s = loop * rows / source.rate_hz
            if self.imu:
                t_s, gyro, accel, temp_c = source.imu_columns(row, stop)
                accels = [None] * t_s.size if accel is None else [tuple(values) for values in accel.tolist()]
                for t, rates, acc, temp in zip(t_s.tolist(), gyro.tolist(), accels, temp_c.tolist()):
                    yield index, t + offset_s, (tuple(rates), acc), temp
                    index += 1
                continue
            t_s, rate_dph, temp_c = source.columns(row, stop)
            for t, rate, temp in zip(t_s.tolist(), rate_dph.tolist(), temp_c.tolist()):
                yield index, t + offset_s, rate, temp
                index += 1

    def _frames(self, index: int, t_s: float, rate_dph: object, temp_c: float) -> list[Frame]:
        """The wire records for one sample: the rate on z (KVH x and y read zero) and for `fogd` the temperature
        frames that fell due since the last sample, each with its own sequence counter; or an IMU's six channels
        and temperature in one frame (KVH Format A, fogd type 04)."""
        name = self.protocol.name
        if self.imu:
            gyro, accel = rate_dph  # type: ignore[misc]
            if name == "kvh-a":
                gyro = tuple(0.0 if value != value else value for value in gyro)  # a channel the run lacks: 0
                if accel is not None:
                    accel = tuple(0.0 if value != value else value for value in accel)
                return [Frame(name, "imu", "A", index % 128, t_s, gyro, ALL_AXES, ALL_AXES, temp_c,
                              accel_g=accel, accel_valid=ALL_AXES, accel_present=ALL_AXES)]  # fmt: skip
            if name == "fogd":  # one IMU frame (type 04) per sample, temperature included
                accel_present = NO_AXES if accel is None else ALL_AXES
                return [Frame(name, "imu", "imu", index % 65536, t_s, gyro, ALL_AXES, ALL_AXES, temp_c,
                              accel_g=(NAN, NAN, NAN) if accel is None else accel, accel_valid=accel_present,
                              accel_present=accel_present)]  # fmt: skip
        if name == "kvh-a":
            return [Frame(name, "imu", "A", index % 128, t_s, (0.0, 0.0, rate_dph), ALL_AXES, ALL_AXES, temp_c)]
        if name == "ascii":
            return [Frame(name, "imu", "I", None, t_s, (NAN, NAN, rate_dph), Z_ONLY, Z_ONLY, temp_c)]
        frames = []
        while self._temp_frames * self.source.rate_hz <= index * self.temp_rate_hz:
            frames.append(Frame(name, "temp", "temp", self._temp_frames % 65536, t_s, temp_c=temp_c))
            self._temp_frames += 1
        frames.append(Frame(name, "rate", "rate", index % 65536, t_s, (NAN, NAN, rate_dph), Z_ONLY, Z_ONLY))
        return frames

    def _emissions(self, index: int, t_s: float, rate_dph: object, temp_c: float) -> list[_Emission]:
        faults, rng = self.faults, self._rng
        emissions = []
        for frame in self._frames(index, t_s, rate_dph, temp_c):
            if faults.drop and rng.random() < faults.drop:
                clean = self.protocol.encode(frame)
                emissions.append(_Emission(index, clean, clean, ["drop"], [], t_s=t_s))
                continue
            injected = []
            if frame.rate_dph is not None:
                if faults.nan and rng.random() < faults.nan:
                    frame.rate_dph = (frame.rate_dph[0], frame.rate_dph[1], NAN)
                    injected.append("nan")
                if faults.clear_status and rng.random() < faults.clear_status:
                    axis = rng.choice([axis for axis in range(3) if frame.axis_present[axis]])
                    frame.axis_valid = tuple(valid and other != axis for other, valid in enumerate(frame.axis_valid))
                    injected.append("clear_status")
            clean = wire = self.protocol.encode(frame)
            if faults.bitflip and rng.random() < faults.bitflip:
                flipped = bytearray(clean)
                flipped[rng.randrange(self._flip_from, len(clean) - self._flip_tail)] ^= 1 << rng.randrange(8)
                wire = bytes(flipped)
                injected.append("bitflip")
            garbage = b""
            if faults.garbage and rng.random() < faults.garbage:
                garbage = bytes(rng.choices(self._garbage_alphabet, k=rng.randint(1, MAX_GARBAGE_BYTES)))
                if self.protocol.line_based:
                    garbage += b"\n"
                injected.append("garbage")
            parts = [garbage + wire]
            if faults.split and rng.random() < faults.split:
                cut = rng.randrange(1, len(wire))
                parts = [garbage + wire[:cut], wire[cut:]]
                injected.append("split")
            emissions.append(_Emission(index, clean, wire, injected, parts, len(garbage), t_s))
            if faults.repeat and rng.random() < faults.repeat:
                emissions.append(_Emission(index, clean, wire, ["repeat"], [wire], t_s=t_s))
        return emissions

    def _send(self, emissions: list[_Emission]) -> None:
        """Write the emissions in order, in as few writes as splits allow."""
        if self.drop_when_full:
            self._send_or_drop(emissions)
            return
        batch = bytearray()
        for emission in emissions:
            if not emission.sent:
                continue
            first, *rest = emission.parts
            batch += first
            for part in rest:
                self._write(batch)
                batch.clear()
                self._stop.wait(SPLIT_PAUSE_S)
                batch += part
        self._write(batch)

    def _send_or_drop(self, emissions: list[_Emission]) -> None:
        """drop_when_full: a frame the pty has no room for is dropped; one cut short by a full pty is finished
        later (frames are dropped meanwhile), as from a UART's transmit FIFO. Never waits, except for a split."""
        for emission in emissions:
            if not emission.sent:
                continue
            self._unsent = self._unsent[self._try_write(self._unsent) :]
            first, *rest = emission.parts
            written = 0 if self._unsent else self._try_write(first)
            if written == 0:
                emission.lose("full")
                continue
            self._unsent = first[written:]
            for part in rest:
                self._stop.wait(SPLIT_PAUSE_S)
                self._unsent += part
                self._unsent = self._unsent[self._try_write(self._unsent) :]

    def _try_write(self, data: bytes) -> int:
        if not data:
            return 0
        try:
            return os.write(self.pty.master_fd, data)
        except BlockingIOError:
            return 0

    def _write(self, data: bytes | bytearray) -> None:
        """Write all of `data`, waiting while the pty is full (backpressure: the schedule slides so the
        stream resumes at its pace, with no burst)."""
        view = memoryview(data)
        blocked_since = None
        fd = self.pty.master_fd
        try:
            while view:
                try:
                    written = os.write(fd, view)
                except BlockingIOError:
                    written = 0
                if written:
                    view = view[written:]
                    continue
                if blocked_since is None:
                    blocked_since = time.monotonic()
                    if not self._said_no_reader and not self.pty.reader_present():
                        log.warning("no reader on %s: the pty is full, waiting for one to open it "
                                    "(--drop-when-full drops frames instead)", self.pty.path)  # fmt: skip
                        self._said_no_reader = True
                if self._stop.is_set():
                    raise _Stopped
                if not self.pty.wait_writable(POLL_MS) and not self.pty.reader_present():
                    self._stop.wait(NO_READER_RETRY_S)  # no reader: poll returns at once with POLLHUP
                # (a reader slower than POLL_MS is polled again at once: it is there, only busy)
        finally:  # a stop while blocked still counts the time it waited
            if blocked_since is not None:
                blocked_s = time.monotonic() - blocked_since
                self.stats.backpressure_s += blocked_s
                self._schedule_shift_s += blocked_s

    def _wait_for_reader(self) -> float:
        """With wait_reader, block until the slave is open; returns the seconds waited."""
        if not self.wait_reader:
            return 0.0
        started = time.monotonic()
        while not self.pty.reader_present():
            if self._stop.wait(NO_READER_RETRY_S):
                raise _Stopped
        if self._stop.wait(READER_SETTLE_S):
            raise _Stopped
        return time.monotonic() - started

    def _replug(self) -> float:
        """A new pty pair after an unplug; the link follows it. Returns the seconds spent waiting for a reader."""
        self.pty = open_pty(self.link)
        self.stats.replugs += 1
        if self.on_replug is not None:
            self.on_replug(self.pty.path)
        return self._wait_for_reader()

    def _account(self, emissions: list[_Emission]) -> None:
        stats = self.stats
        for emission in emissions:
            if emission.sent:
                stats.frames_sent += 1
                stats.garbage_bytes += emission.garbage_bytes
                for fault in emission.faults:
                    stats.faults[fault] += 1
            elif emission.faults == ["drop"]:
                stats.faults["drop"] += 1
            elif emission.faults == ["full"]:
                stats.dropped_full += 1
            else:
                stats.lost_unplugged += 1
            if self._ledger is not None:
                self._ledger.write(self._ledger_line(emission) + "\n")
        if self._ledger is not None:
            self._ledger.flush()

    def _ledger_line(self, emission: _Emission) -> str:
        """One JSON object: index (frame number, from 0), sample, kind, seq, t_s (device time), faults (list),
        sent, valid (a decoder accepts the bytes as sent), rate_dph (z), rate_ok (z usable), temp_c (the values
        the clean frame carries, as a decoder reads them; null for none or NaN), bytes, garbage_bytes; from an
        IMU source also rates_dph (x, y, z) and accel_g (x, y, z; null without accelerometers)."""
        carried = self.protocol.decode(emission.clean)
        valid = emission.wire is emission.clean or _decodes(self.protocol, emission.wire)
        rate_dph = carried.rate_dph[2] if carried.rate_dph is not None else None
        line = {
            "index": self._ledger_index,
            "sample": emission.sample,
            "kind": carried.kind,
            "seq": carried.seq,
            "t_s": emission.t_s,
            "faults": emission.faults,
            "sent": emission.sent,
            "valid": valid,
            "rate_dph": _json_number(rate_dph),
            "rate_ok": None if rate_dph is None else carried.axis_valid[2],
            "temp_c": _json_number(carried.temp_c),
            "bytes": len(emission.wire),
            "garbage_bytes": emission.garbage_bytes,
        }
        if self.imu:
            line["rates_dph"] = None if carried.rate_dph is None else [_json_number(v) for v in carried.rate_dph]
            line["accel_g"] = None if carried.accel_g is None else [_json_number(v) for v in carried.accel_g]
        self._ledger_index += 1
        return json.dumps(line)


def _json_number(value: float | None) -> float | None:
    """A float for JSON, None for none, NaN or Inf (JSON has no NaN)."""
    return value if value is not None and math.isfinite(value) else None


def _decodes(protocol: protocols.Protocol, raw: bytes) -> bool:
    try:
        protocol.decode(raw)
    except (FrameError, ValueError):
        return False
    return True
