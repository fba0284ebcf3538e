"""Which protocol a byte stream speaks (`--protocol auto`, as gpsd hunts for a device's protocol): every
candidate scans the same bytes with its own checks (header, length, CRC or line syntax, through its `find`,
`frame_length` and `decode`), and the first to find `FRAMES_NEEDED` valid frames in a row, back to back with no
byte between them, wins. The rate of its frames is measured from the device's clock where the frames carry
one, else from when the bytes arrived.

The detector only looks: it keeps every byte it was given (`held`), so whoever framed nothing meanwhile hands
those bytes to the chosen protocol's lexer and no frame seen during detection is lost. When nothing is found
in `max_bytes`, it keeps the newest bytes and counts the rest as `dropped_bytes` (they held no run of valid
frames of any candidate). `describe()` says what unrecognised bytes look like, for the operator.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from .base import Frame, FrameError, Protocol

FRAMES_NEEDED = 5  # valid frames in a row: for a CRC-16 protocol, 1 in 2^80 for random bytes
MEASURE_S = 0.5  # and this long a run (arrival or device time) to measure the rate over, unless...
BURST_FRAMES = 256  # ...this many arrive at once (a backlog): decide without waiting
MAX_BYTES = 1 << 16
RATE_KINDS = ("imu", "rate", "comp")  # the frames that carry a sample of the rate (what rate_hz counts)


@dataclass(frozen=True, slots=True)
class Found:
    """The verdict: `name` of the protocol, how many valid frames in a row it found, and the rate of its
    rate-carrying frames (per second, None when they all came at once and carry no time) and where that rate
    came from ('device time' or 'arrival')."""

    name: str
    frames: int
    span_s: float  # how much of the stream the run covers (device time, else arrival)
    rate_hz: float | None
    rate_from: str


class _Scan:
    """One candidate's pass over the held bytes: where it got to and its current run of valid frames."""

    def __init__(self, protocol: Protocol) -> None:
        self.protocol = protocol
        self.pos = 0
        self.failed = 0  # candidates its checks rejected (a header with a bad CRC, a line that did not parse)
        self.reset_run()

    def reset_run(self) -> None:
        self.run = 0
        self.rate_frames = 0
        self.first_arrival_s: float | None = None
        self.last_arrival_s = 0.0
        self.after_first = 0  # rate frames that arrived after the run's first read
        self.first_device_s: float | None = None  # the device times of its first and last rate frames (None:
        self.last_device_s: float | None = None  # some frame of the run carries no time)

    def scan(self, buf: bytes, arrival_s: float) -> None:
        protocol, end = self.protocol, len(buf)
        while self.pos < end:
            start = protocol.find(buf, self.pos)
            if start < 0:  # no header in what is left: skip it but a sync pattern's first bytes
                keep_from = max(self.pos, end - max(len(protocol.sync) - 1, 0))
                if keep_from > self.pos:
                    self.pos, _ = keep_from, self.reset_run()
                return
            length = protocol.frame_length(buf, start)
            if length < 0:
                self.pos, _ = start - length, self.reset_run()
                continue
            if length == 0 or start + length > end:
                if start != self.pos:
                    self.reset_run()
                self.pos = start
                return
            try:
                frame = protocol.decode(buf[start : start + length])
            except FrameError:
                self.failed += 1
                self.pos = start + (length if protocol.line_based else 1)
                self.reset_run()
                continue
            if start != self.pos:  # bytes between this frame and the one before: a new run
                self.reset_run()
            self.pos = start + length
            self._count(frame, arrival_s)

    def _count(self, frame: Frame, arrival_s: float) -> None:
        self.run += 1
        if frame.kind not in RATE_KINDS:
            return
        self.rate_frames += 1
        if self.first_arrival_s is None:
            self.first_arrival_s = arrival_s
        elif arrival_s > self.first_arrival_s:
            self.after_first += 1
        self.last_arrival_s = arrival_s
        if self.rate_frames == 1:
            self.first_device_s = self.last_device_s = frame.t_s
        elif self.first_device_s is not None and frame.t_s is not None:
            self.last_device_s = frame.t_s
        else:
            self.first_device_s = None

    def _device_span_s(self) -> float:
        if self.first_device_s is None or self.last_device_s is None:
            return 0.0
        return max(0.0, self.last_device_s - self.first_device_s)

    def span_s(self) -> float:
        """How long the run lasts, by the device's clock where its frames carry one, else by arrival."""
        device_span_s = self._device_span_s()
        if device_span_s > 0:
            return device_span_s
        return self.last_arrival_s - self.first_arrival_s if self.first_arrival_s is not None else 0.0

    def found(self) -> Found:
        device_span_s = self._device_span_s()
        if device_span_s > 0:
            rate_hz: float | None = (self.rate_frames - 1) / device_span_s
            return Found(self.protocol.name, self.run, device_span_s, rate_hz, "device time")
        span_s = self.span_s()
        rate_hz = self.after_first / span_s if span_s > 0 and self.after_first >= 2 else None
        return Found(self.protocol.name, self.run, span_s, rate_hz, "arrival")


class Detector:
    """Feed it bytes as they arrive (`feed(data, arrival_s)`) until it returns a `Found`."""

    def __init__(self, candidates: Sequence[Protocol], *, frames_needed: int = FRAMES_NEEDED, measure_s: float = MEASURE_S,
                 burst_frames: int = BURST_FRAMES, max_bytes: int = MAX_BYTES) -> None:  # fmt: skip
        if not candidates:
            raise ValueError("protocol detection needs at least one candidate protocol")
        self.names = [protocol.name for protocol in candidates]
        self._scans = [_Scan(protocol) for protocol in candidates]
        self.frames_needed, self.measure_s, self.burst_frames = frames_needed, measure_s, burst_frames
        self.max_bytes = max(max_bytes, 4 * max(protocol.max_frame_len for protocol in candidates))
        self.held = b""
        self.dropped_bytes = 0
        self.bytes_seen = 0

    def feed(self, data: bytes, arrival_s: float) -> Found | None:
        """The verdict once one candidate has its run of valid frames (measured long enough), else None."""
        self.bytes_seen += len(data)
        self.held += data
        for scan in self._scans:
            scan.scan(self.held, arrival_s)
        ready = [scan for scan in self._scans if self._ready(scan)]
        if ready:
            return max(ready, key=lambda scan: scan.run).found()  # max keeps the table's order on a tie
        if len(self.held) > self.max_bytes:
            self._drop_oldest()
        return None

    def settle(self) -> Found | None:
        """The verdict when the bytes pause: the longest run of at least `frames_needed`, measured or not (a
        short stream, a slow unit)."""
        runs = [scan for scan in self._scans if scan.run >= self.frames_needed]
        return max(runs, key=lambda scan: scan.run).found() if runs else None

    def _ready(self, scan: _Scan) -> bool:
        return scan.run >= self.frames_needed and (scan.run >= self.burst_frames or scan.span_s() >= self.measure_s)

    def _drop_oldest(self) -> None:
        """Keep the newest half: a run that starts in it is still found; what goes held no run long enough."""
        cut = len(self.held) - self.max_bytes // 2
        self.held = self.held[cut:]
        self.dropped_bytes += cut
        for scan in self._scans:
            if scan.pos >= cut:
                scan.pos -= cut
            else:
                scan.pos = 0
                scan.reset_run()

    def describe(self) -> str:
        """What the held bytes look like, in a few words (for the warning that nothing was recognised)."""
        text = printable(self.held[-4096:])
        failed = {scan.protocol.name: scan.failed for scan in self._scans if text or not scan.protocol.line_based}
        return describe(self.held, failed)


def describe(data: bytes, failed: dict[str, int] | None = None) -> str:
    """'no bytes', 'all zero bytes', 'one byte repeated (0xff)', 'printable text (...)' or 'binary with no known
    header (...)', with how many candidate frames each protocol's checks rejected."""
    if not data:
        return "no bytes"
    sample = data[-4096:]
    if not sample.strip(b"\x00"):
        text = "all zero bytes"
    elif len(set(sample)) == 1:
        text = f"one byte repeated (0x{sample[0]:02x})"
    elif printable(sample):
        lines = [line for line in sample.decode("ascii", "replace").splitlines() if line.strip()]
        line = lines[1] if len(lines) > 1 else lines[0] if lines else ""  # the first may be cut
        text = f"printable text, e.g. {line[:48]!r}"
    else:
        text = f"binary with no known header (e.g. {sample[:12].hex(' ')})"
    rejected = [f"{count} {name}" for name, count in (failed or {}).items() if count]
    return text + (f"; frames rejected by their checks: {', '.join(rejected)}" if rejected else "")


def printable(data: bytes) -> bool:
    """Whether `data` is (at least 95 %) printable ASCII text."""
    return bool(data) and sum(32 <= byte < 127 or byte in b"\r\n\t" for byte in data) >= 0.95 * len(data)
