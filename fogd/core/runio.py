"""Reading and writing run CSVs (`t_s,rate_dph,temp_c[,...]`), with errors that name the file and line.

A multi-channel run (`t_s,rate_x_dph,...,accel_z_g,temp_c`, the channels the unit has) reads into the
same `Run`: `channels` holds every measured channel and `channel(name)` gives the run as a single-channel
one, so everything written for one axis (training, replay, tables) serves each channel unchanged.

A run is read with numpy's C reader; only when that fails is the file scanned again in Python to name the
first bad line. Rows with NaN or Inf values are kept (callers flag or skip them) and counted.
"""

from __future__ import annotations

import codecs
import difflib
import hashlib
import io
import sys
import threading
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import IO, Iterator

import numpy as np

from fogd.core.atomic import replaced
from fogd.core.columns import CHANNELS, GYRO_CHANNELS, RUN_COLUMNS, SINGLE_CHANNEL, TRUE_ERROR_COLUMN, truth_column
from fogd.errors import InputError, NoInputError, describe_os_error

MAX_GAP_PERIODS = 5.0  # a time step longer than this many sample periods is a gap, not jitter
MIN_RATE_HZ, MAX_RATE_HZ = 1e-3, 100_000.0  # the daemon's range; beyond, t_s is not in seconds (or not a time)
_TRUTH_COLUMNS = frozenset(truth_column(name) for name in (SINGLE_CHANNEL, *CHANNELS))
LONG_LINE_BLOCK = 2048  # a line of twice this many bytes holds a whole aligned block without a newline
READ_CHUNK_BYTES = 1 << 20


@dataclass
class Run:
    """One recorded run: required columns as float64 arrays, extra numeric columns by name.

    `rate_dph` is the run's primary channel: `rate_dph` of a single-axis run, else rate_z_dph when the run has
    it (fogd's default axis), else its first gyro channel, else its first channel."""

    path: str
    t_s: np.ndarray
    rate_dph: np.ndarray
    temp_c: np.ndarray
    rate_hz: float
    sha256: str
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    channels: dict[str, np.ndarray] = field(default_factory=dict)  # every measured channel, in file order

    def __post_init__(self) -> None:
        if not self.channels:
            self.channels = {SINGLE_CHANNEL: self.rate_dph}

    def channel(self, name: str) -> Run:
        """This run as a single-channel run of `name`: its rate_dph is that channel (deg/h, or g for an
        accelerometer) and its true-error column that channel's truth, when the simulator wrote one."""
        if name not in self.channels:
            raise InputError(f"{self.path}: no channel {name!r}; it has {', '.join(self.channels)}")
        extra = {key: values for key, values in self.extra.items() if key not in _TRUTH_COLUMNS}
        truth = self.extra.get(truth_column(name))
        if truth is not None:
            extra[TRUE_ERROR_COLUMN] = truth
        return replace(self, rate_dph=self.channels[name], extra=extra, channels={name: self.channels[name]})

    @property
    def name(self) -> str:
        return Path(self.path).name

    @property
    def rows(self) -> int:
        return int(self.t_s.size)

    @property
    def nan_rows(self) -> int:
        """Rows whose rate or temperature is NaN or Inf."""
        return int(np.count_nonzero(~(np.isfinite(self.rate_dph) & np.isfinite(self.temp_c))))


def read_run(path: str | Path, *, max_gap_periods: float = MAX_GAP_PERIODS) -> Run:
    """Read and check a run CSV; raises InputError naming the file (and line) for anything unusable."""
    path = str(path)
    data = _read_bounded(path)
    if not data.strip():
        raise InputError(f"{path}: empty file (expected a header line {','.join(RUN_COLUMNS)} and data rows)")
    header_line, names = _header(path, data)
    channel_names = [name for name in names if name in CHANNELS]
    required = ("t_s", "temp_c") if channel_names and SINGLE_CHANNEL not in names else RUN_COLUMNS
    missing = [name for name in required if name not in names]
    if missing:
        hints = []
        for name in missing:
            close = difflib.get_close_matches(name, names, n=1)
            hints.append(f"{name} (did you mean {close[0]!r}?)" if close else name)
        raise InputError(
            f"{path}:{header_line}: missing column(s) {', '.join(hints)}; the header has "
            f"{','.join(names) or 'nothing'}; a run needs {','.join(RUN_COLUMNS)} (or, from an IMU, t_s, temp_c and "
            f"any of {','.join(CHANNELS)})"
        )
    digest = _Sha256(data)  # hashing releases the GIL: it runs while numpy parses
    text = _Text(data)  # decoded only to report an error
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # "input contained no data": reported below
            table = np.loadtxt(
                io.BytesIO(data[3:] if data.startswith(codecs.BOM_UTF8) else data), delimiter=",",
                # latin-1 decodes any byte: a comment's non-UTF-8 byte is skipped with it, a data row's is not a number
                skiprows=header_line, ndmin=2, comments=None, dtype=np.float64, encoding="latin-1",
            )  # fmt: skip
    except (ValueError, UnicodeDecodeError):
        raise InputError(_first_bad_line(path, str(text), header_line, len(names))) from None
    if table.shape[0] == 0:
        raise InputError(f"{path}: no data rows after the header")
    columns = {name: np.ascontiguousarray(table[:, index]) for index, name in enumerate(names)}
    t_s = columns.pop("t_s")
    rate_hz = _check_time(path, t_s, text, header_line, max_gap_periods)
    channels = {name: columns.pop(name) for name in names if name == SINGLE_CHANNEL or name in CHANNELS}
    return Run(
        path=path,
        t_s=t_s,
        rate_dph=channels[_primary(list(channels))],
        temp_c=columns.pop("temp_c"),
        rate_hz=rate_hz,
        sha256=digest.hexdigest(),
        extra=columns,
        channels=channels,
    )


def _primary(channels: list[str]) -> str:
    """The channel a run's `rate_dph` is (see Run)."""
    for name in (SINGLE_CHANNEL, "rate_z_dph", *GYRO_CHANNELS):
        if name in channels:
            return name
    return channels[0]


class _Sha256(threading.Thread):
    """sha256 of `data` on a thread (hashlib releases the GIL on large buffers)."""

    def __init__(self, data: bytes) -> None:
        super().__init__(name="fogd-sha256", daemon=True)
        self._data = data
        self._digest = ""
        self.start()

    def run(self) -> None:
        self._digest = hashlib.sha256(self._data).hexdigest()

    def hexdigest(self) -> str:
        self.join()
        return self._digest


class _Text:
    """The file decoded as text, made the first time an error message needs it."""

    def __init__(self, data: bytes) -> None:
        self._data = data
        self._text: str | None = None

    def __str__(self) -> str:
        if self._text is None:
            self._text = self._data.decode("utf-8-sig", errors="replace")
        return self._text


def _lines(data: bytes) -> Iterator[bytes]:
    """The lines of `data` one at a time (as bytes.splitlines, without splitting the whole file up front)."""
    start = 0
    while start < len(data):
        end = data.find(b"\n", start)
        end = len(data) if end < 0 else end + 1
        yield from data[start:end].splitlines() or [b""]
        start = end


def _header(path: str, data: bytes) -> tuple[int, list[str]]:
    """(1-based line number of the header, its column names); '#' lines before it are comments."""
    for number, raw in enumerate(_lines(data), start=1):
        line = raw.decode("utf-8-sig", errors="replace").strip()
        if not line or line.startswith("#"):
            continue
        names = [name.strip() for name in line.split(",")]
        if any(_is_number(name) for name in names):
            raise InputError(
                f"{path}:{number}: expected a header line ({','.join(RUN_COLUMNS)}), found data: {line[:60]!r}"
            )
        duplicates = sorted({name for name in names if names.count(name) > 1})
        if duplicates:
            raise InputError(f"{path}:{number}: column(s) {', '.join(duplicates)} appear more than once")
        return number, names
    raise InputError(f"{path}: no header line (expected {','.join(RUN_COLUMNS)})")


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _first_bad_line(path: str, text: str, header_line: int, width: int) -> str:
    """The message for the first data line numpy could not read (only run on the error path)."""
    for number, line in enumerate(text.splitlines(), start=1):
        if number <= header_line or not line:  # numpy skips empty lines, not lines of spaces
            continue
        cells = line.split(",")
        if len(cells) != width:
            return f"{path}:{number}: {len(cells)} cells where the header has {width}: {line[:60]!r}"
        for column, cell in enumerate(cells, start=1):
            if not _is_number(cell) or "_" in cell or not cell.strip().isascii():  # float() takes 1_0 and ١; numpy not
                return f"{path}:{number}: column {column} is not a number: {cell.strip()[:40]!r}"
    return f"{path}: unreadable data after line {header_line}"


def _read_bounded(path: str) -> bytes:
    """The file's bytes, read a chunk at a time from anything that can be read (a FIFO, a device: a stream);
    a line far longer than any run's is refused as soon as it is read (numpy's reader takes several times a
    line's size in memory; /dev/zero or a 2 GB line read until MemoryError), as is UTF-16 text. Memory is the
    file's size, which the line limit bounds by the rows kept."""
    lines = _LineLimit(path)
    chunks: list[bytes] = []
    try:
        with open(path, "rb", buffering=0) as stream:
            while chunk := stream.read(READ_CHUNK_BYTES):
                if not chunks:
                    _refuse_utf16(path, chunk)
                lines.check(chunk)
                chunks.append(chunk)
    except OSError as error:
        raise NoInputError(describe_os_error(error)) from None
    return b"".join(chunks)


def _refuse_utf16(path: str, start: bytes) -> None:
    head = start[:256]
    interleaved = len(head) >= 8 and any(  # one byte of every two NUL, the others not: UTF-16 without a BOM
        not head[side::2].strip(b"\0") and b"\0" not in head[1 - side :: 2] for side in (0, 1)
    )
    if head.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)) or interleaved:
        raise InputError(f"{path}: UTF-16 text; save it as UTF-8 (a run CSV is plain ASCII)")


class _LineLimit:
    """InputError for a line far longer than any run's: any aligned block of LONG_LINE_BLOCK bytes without a
    newline (a line of twice that holds one), checked chunk by chunk as the file is read."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.pending = b""  # the file after the last whole block checked
        self.newlines = 0  # before it

    def check(self, chunk: bytes) -> None:
        text, block = self.pending + chunk, LONG_LINE_BLOCK
        if b"\0" in chunk:
            line = self.newlines + text.count(b"\n", 0, text.index(b"\0")) + 1
            raise InputError(f"{self.path}:{line}: a NUL byte; not a text file (a device, or a binary file?)")
        whole = len(text) // block * block
        for start in range(0, whole, block):
            piece = text[start : start + block]
            if b"\n" not in piece:
                line = self.newlines + text.count(b"\n", 0, start) + 1
                if b"\r" in piece:
                    raise InputError(
                        f"{self.path}:{line}: CR line endings (an old Mac text file); save it with LF line endings"
                    )
                raise InputError(f"{self.path}:{line}: a line longer than {block} bytes; not a run CSV")
        self.newlines += text.count(b"\n", 0, whole)
        self.pending = text[whole:]


def _check_time(path: str, t_s: np.ndarray, text: _Text, header_line: int, max_gap_periods: float) -> float:
    """Checks that time increases with no gaps; returns the data rate in Hz."""
    finite = np.flatnonzero(np.isfinite(t_s))
    if finite.size < 2:
        raise InputError(f"{path}: fewer than two rows with a finite time; cannot tell the data rate")
    with np.errstate(over="ignore"):  # times near the float limit: an infinite step, refused below
        step = np.diff(t_s[finite])
    bad = np.flatnonzero(step <= 0)
    if bad.size:
        row = finite[bad[0] + 1]
        raise InputError(
            f"{path}:{_line_of(row, text, header_line)}: time does not increase "
            f"({t_s[finite[bad[0]]]:.6g} s then {t_s[row]:.6g} s)"
        )
    period_s = float(np.median(step))
    if not MIN_RATE_HZ <= 1.0 / period_s <= MAX_RATE_HZ:
        raise InputError(
            f"{path}: time steps of {period_s:.6g} s ({1.0 / period_s:.6g} Hz) are outside "
            f"{MIN_RATE_HZ:g}..{MAX_RATE_HZ:g} Hz; is t_s in seconds?"
        )
    gaps = np.flatnonzero(step > max_gap_periods * period_s)
    if gaps.size:
        row = finite[gaps[0] + 1]
        raise InputError(
            f"{path}:{_line_of(row, text, header_line)}: gap of {step[gaps[0]]:.6g} s in time "
            f"(sample period {period_s:.6g} s); split the run into separate files at the gap"
        )
    return 1.0 / period_s


def _line_of(row: int, text: _Text, header_line: int) -> int:
    """File line of data row `row` (0-based); numpy skips empty lines, so they are not counted as rows."""
    lines = str(text).splitlines()[header_line:]
    return [number for number, line in enumerate(lines, start=header_line + 1) if line][int(row)]


def write_csv(
    path: str, columns: dict[str, np.ndarray], formats: dict[str, str], *, comments: list[str] = (), inputs: list[str] = ()
) -> None:
    """Write equal-length columns as CSV (header from the dict's keys), in chunks to bound memory. A file is
    replaced whole, '-', a FIFO or a character device written as a stream (fogd.core.atomic): a failed write
    leaves the old file as it was and is an OutputError naming `path`; an output that is one of `inputs` is
    refused."""
    names = list(columns)
    length = len(next(iter(columns.values())))
    fmt = ",".join(formats.get(name, "%.9g") for name in names)

    def write(stream: IO[str]) -> None:
        for line in comments:
            stream.write(f"# {line}\n")
        stream.write(",".join(names) + "\n")
        for start, stop in _chunks(length, 200_000):
            block = np.column_stack([np.asarray(columns[name][start:stop], dtype=np.float64) for name in names])
            np.savetxt(stream, block, fmt=fmt, delimiter=",")

    with replaced(path, inputs=inputs) as stream:
        write(stream)


def _chunks(length: int, size: int) -> Iterator[tuple[int, int]]:
    for start in range(0, length, size):
        yield start, min(start + size, length)
