"""The shape every wire protocol shares: the decoded record (`Frame`), the error a rejected frame raises
(`FrameError`) and the `Protocol` interface the lexer and the daemon drive (find, size, decode, encode,
re-encode with compensated rates).

Axes are indexed x=0, y=1, z=2; a single-axis format (DSP-3000, fogd ASCII lines) fills z and marks x and y
absent (`axis_present` False, value NaN). Rates are deg/h, accelerations g, temperatures C, times s, whatever the
wire says (rate or delta, radians or degrees, g or m/s per sample: converted at the edge).
"""

from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass

NAN = float("nan")
Axes3 = tuple[float, float, float]
Mask3 = tuple[bool, bool, bool]
ALL_AXES: Mask3 = (True, True, True)
NO_AXES: Mask3 = (False, False, False)
Z_ONLY: Mask3 = (False, False, True)
IMPLAUSIBLE = 0x8000  # Frame.flags of a rate frame: the plausibility check marked its axis invalid
TIME_BACKWARDS = 0x4000  # Frame.flags: the device time is earlier than the frame's before (the lexer's mark)
MAX_T_S = 2.0**53 / 1e6  # device times beyond this (285 years in us) are no clock's: the frame is refused


@dataclass(slots=True)
class Frame:
    """One decoded frame; `kind` says which fields carry data (see docs/reference/wire-formats.md).

    kind 'imu': rate and temperature together (KVH A/B); 'rate': rate only; 'temp': temperature only;
    'comp': fogd's compensated output (adds temp_rate_cps, comp_dph, rate_comp_dph, flags);
    'other': recognised and checked but carrying nothing fogd uses (KVH BIT replies).
    `message` names the wire message ('A', 'B', 'C', 'BIT', 'BIT2'; 'rate', 'temp', 'comp', 'other';
    'dsp3000', 'R', 'T', 'I', 'C'); sequence numbers are counted per (protocol, message).
    An axis is usable only when both `axis_present` and `axis_valid` say so; `axis_valid` is False when the
    sensor's status bit says invalid or the value is NaN/Inf. `temp_c` may be NaN (an invalid reading).
    The accelerometers follow the same rules in `accel_g`, `accel_valid` and `accel_present` (None and no axes
    for formats without accelerometers).
    """

    protocol: str
    kind: str
    message: str = ""
    seq: int | None = None
    t_s: float | None = None
    rate_dph: Axes3 | None = None
    axis_valid: Mask3 = NO_AXES
    axis_present: Mask3 = NO_AXES
    temp_c: float | None = None
    raw: bytes = b""
    temp_rate_cps: float | None = None
    comp_dph: Axes3 | None = None
    rate_comp_dph: Axes3 | None = None
    flags: int = 0
    accel_g: Axes3 | None = None
    accel_valid: Mask3 = NO_AXES
    accel_present: Mask3 = NO_AXES


class FrameError(ValueError):
    """A candidate frame that must be dropped; `counter` names the lexer counter it is counted in."""

    def __init__(self, counter: str, message: str) -> None:
        super().__init__(message)
        self.counter = counter


class Protocol(ABC):
    """One wire format: how the lexer finds and sizes its frames, and how frames become records and back.

    `frame_length(buf, start)` looks at a candidate found by `find` and returns its length in bytes,
    0 when more bytes are needed to tell, or -k to skip k bytes as garbage (not this protocol's header).
    `decode` checks (CRC, syntax) and decodes one whole frame or raises FrameError.
    """

    name: str
    sync: bytes  # the byte pattern `find` looks for; b"" for line formats
    max_frame_len: int
    seq_modulus: int | None  # sequence numbers wrap modulo this; None when the format has none
    line_based: bool = False  # a rejected line is skipped whole; a rejected binary frame by one byte
    # a frame whose sequence number equals the one before is a copy, dropped (KVH's 7-bit counter cannot
    # tell a copy from 128 frames lost, so there it is only counted)
    repeats_are_copies: bool = False
    gyro_axes: Mask3 = ALL_AXES  # the gyro axes the format can carry (what a recorder makes columns of)
    accel_axes: Mask3 = NO_AXES  # the accelerometer axes the format can carry

    def find(self, buf: bytes, pos: int) -> int:
        """Offset of the next candidate frame start at or after `pos`, or -1."""
        return buf.find(self.sync, pos)

    @abstractmethod
    def frame_length(self, buf: bytes, start: int) -> int: ...

    @abstractmethod
    def decode(self, raw: bytes) -> Frame: ...

    @abstractmethod
    def encode(self, frame: Frame) -> bytes: ...

    @abstractmethod
    def reencode(self, frame: Frame, rate_dph: Sequence[float]) -> bytes:
        """`frame.raw` with the compensated axes' rates replaced by `rate_dph` and a fresh CRC.

        Only axes that the protocol compensates and that are present and valid in `frame` change; every
        other byte is kept. Frames without a rate (temperature, BIT, ...) come back unchanged.
        """
