"""Line formats for humans and scripts (protocol `ascii`): KVH DSP-3000 output lines and fogd's own
comma-separated lines for rate, temperature, both, and compensated output (grammar in docs/reference/wire-formats.md).

Both are single-axis: the rate is the z axis (index 2), x and y are absent. A line that does not parse is
rejected whole and counted as `bad_line`; blank lines are skipped as garbage.

fogd's lines may end in an NMEA-style checksum, `*HH`: the XOR of every byte before the `*`, in two hex digits.
fogd writes it and checks it when present (a mismatch counts as `bad_crc`), and once a sender has sent one,
a line without one is refused too (a flipped `*` becomes a newline). A line from a sender without checksums,
and every
DSP-3000 line, carries nothing that detects a flipped digit. For those, `max_jump_dph` adds a plausibility
check: a rate that jumps by more than that from both the previous rate and the last accepted one has its axis
marked invalid (`IMPLAUSIBLE` in the frame's flags; the lexer counts it). A time or rate beyond what the
output formats carry (|t| > 2^53 us, |rate| > float32's range) rejects the line.
"""

import math
import re
from collections.abc import Sequence

from ..errors import ConfigError
from .base import (
    IMPLAUSIBLE,
    MAX_T_S,
    NAN,
    Z_ONLY,
    Axes3,
    Frame,
    FrameError,
    Mask3,
    Protocol,
)

MAX_LINE_LEN = 256
MAX_RATE_DPH = 3.4e38  # float32's range: every output format can carry it
FIELD_COUNTS = {"R": 3, "T": 3, "I": 4, "C": 8}
DSP3000_EXACT_DPH = 1e-10  # a re-encoded DSP-3000 value decodes to the compensated rate within this
DSP3000_MAX_DECIMALS = 24  # beyond a double's precision for any rate a DSP-3000 sends
_DSP3000_LINE = re.compile(r"^(\s*)(\S+)(\s+[01]\s*)$")


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise FrameError("bad_line", f"ascii: {text!r} is not a number") from None


def _time(text: str) -> float | None:
    if not text.strip():
        return None
    t_s = _number(text)
    if not abs(t_s) <= MAX_T_S:  # also NaN
        raise FrameError("bad_line", f"ascii: time {text[:40]!r} is not a usable time")
    return t_s


def _rate(value: float, text: str) -> float:
    if abs(value) > MAX_RATE_DPH:  # NaN and Inf stay: they mark the axis invalid
        raise FrameError("bad_line", f"ascii: rate {text[:40]!r} is out of range")
    return value


def checksum(body: bytes) -> bytes:
    """The two hex digits of the XOR of `body`'s bytes (NMEA 0183's checksum)."""
    value = 0
    for byte in body:
        value ^= byte
    return b"%02X" % value


def _text(value: float | None) -> str:
    return "" if value is None else repr(float(value))


def _z_axis(rate_dph: float) -> tuple[Axes3, Mask3]:
    return (NAN, NAN, rate_dph), (False, False, math.isfinite(rate_dph))


class AsciiProtocol(Protocol):
    """DSP-3000 lines and fogd's R/T/I/C lines; rotfmt/rate_hz say how the DSP-3000 is configured
    ('rate': deg/s; 'delta': deg per sample, needs rate_hz). fogd's own lines are always deg/h."""

    name = "ascii"
    sync = b""
    max_frame_len = MAX_LINE_LEN
    seq_modulus = None
    line_based = True
    gyro_axes = Z_ONLY  # one axis, on z

    def __init__(self, rotfmt: str = "rate", rate_hz: float | None = None, max_jump_dph: float | None = None) -> None:
        if max_jump_dph is not None and not max_jump_dph > 0:
            raise ConfigError(f"ascii: max_jump_dph must be positive, not {max_jump_dph!r}")
        self.max_jump_dph = max_jump_dph
        self._checksummed = False  # once a sender has sent a checksum, every fogd line must carry one
        self._previous_dph = NAN  # the plausibility check's previous rate and last accepted rate
        self._accepted_dph = NAN
        if rotfmt not in ("rate", "delta"):
            raise ConfigError(f"ascii: rotfmt must be 'rate' or 'delta', not {rotfmt!r}")
        if rotfmt == "delta" and not (rate_hz and rate_hz > 0):
            raise ConfigError("ascii: rotfmt 'delta' needs the DSP-3000's output rate (rate_hz > 0)")
        self.rotfmt, self.rate_hz = rotfmt, rate_hz
        self.dsp3000_dph_per_unit = 3600.0 * (rate_hz if rotfmt == "delta" else 1.0)

    def find(self, buf: bytes, pos: int) -> int:
        return pos if pos < len(buf) else -1

    def frame_length(self, buf: bytes, start: int) -> int:
        end = buf.find(b"\n", start)
        if end < 0:
            pending = len(buf) - start
            return -pending if pending > MAX_LINE_LEN else 0
        length = end + 1 - start
        return -length if buf[start : end + 1].isspace() else length

    def decode(self, raw: bytes) -> Frame:
        if len(raw) > MAX_LINE_LEN:
            raise FrameError("bad_line", f"ascii: line longer than {MAX_LINE_LEN} bytes")
        try:
            line = raw.decode("ascii").strip()
        except UnicodeDecodeError:
            raise FrameError("bad_line", "ascii: line is not ASCII") from None
        if "," not in line:
            return self._plausible(self._decode_dsp3000(line, raw))
        checked = False
        if "*" in line:
            line, _, digits = line.rpartition("*")
            if checksum(line.encode("ascii")) != digits.upper().encode("ascii"):
                raise FrameError("bad_crc", "ascii: checksum mismatch")
            checked = self._checksummed = True
        elif self._checksummed:  # a flipped '*' (0x2A -> 0x0A, a newline) must not turn a line unchecked
            raise FrameError("bad_crc", "ascii: checksum missing from a sender that sends them")
        frame = self._decode_fogd(line, raw)
        return frame if checked or frame.kind not in ("rate", "imu") else self._plausible(frame)

    def _plausible(self, frame: Frame) -> Frame:
        """The plausibility check for a line nothing else checks: flag a jump from both the previous rate
        and the last accepted one (a spike is flagged alone, a real step costs one sample)."""
        if self.max_jump_dph is None or not frame.axis_valid[2]:
            return frame
        rate = frame.rate_dph[2]
        jump = self.max_jump_dph
        previous, self._previous_dph = self._previous_dph, rate
        if abs(rate - previous) > jump and abs(rate - self._accepted_dph) > jump:
            frame.axis_valid = (False, False, False)
            frame.flags |= IMPLAUSIBLE
            return frame
        self._accepted_dph = rate
        return frame

    def _decode_fogd(self, line: str, raw: bytes) -> Frame:
        fields = line.split(",")
        tag = fields[0].strip()
        if FIELD_COUNTS.get(tag) != len(fields):
            raise FrameError("bad_line", f"ascii: not an R, T, I or C line: {line[:40]!r}")
        t_s = _time(fields[1])
        if tag == "T":
            return Frame("ascii", "temp", "T", None, t_s, temp_c=_number(fields[2]), raw=raw)
        rates, valid = _z_axis(_rate(_number(fields[2]), fields[2]))
        if tag == "R":
            return Frame("ascii", "rate", "R", None, t_s, rates, valid, Z_ONLY, None, raw)
        if tag == "I":
            return Frame("ascii", "imu", "I", None, t_s, rates, valid, Z_ONLY, _number(fields[3]), raw)
        flags = _number(fields[7])
        if not (flags.is_integer() and 0 <= flags < 1 << 16):
            raise FrameError("bad_line", f"ascii: flags {fields[7]!r} is not a 16-bit unsigned integer")
        return Frame(
            "ascii", "comp", "C", None, t_s, rates, valid, Z_ONLY, _number(fields[3]), raw,
            _number(fields[4]), (NAN, NAN, _number(fields[5])), (NAN, NAN, _number(fields[6])), int(flags),
        )

    def _decode_dsp3000(self, line: str, raw: bytes) -> Frame:
        fields = line.split()
        if len(fields) != 2 or fields[1] not in ("0", "1"):
            raise FrameError("bad_line", f"ascii: not a DSP-3000 line: {line[:40]!r}")
        rates, valid = _z_axis(_rate(_number(fields[0]) * self.dsp3000_dph_per_unit, fields[0]))
        valid = (False, False, valid[2] and fields[1] == "1")
        return Frame("ascii", "rate", "dsp3000", None, None, rates, valid, Z_ONLY, None, raw)

    def encode(self, frame: Frame) -> bytes:
        """A DSP-3000 line (kind 'rate', message 'dsp3000'), else an R, T, I or C line by kind."""
        rate_dph = NAN
        if frame.rate_dph is not None and frame.axis_present[2]:
            rate_dph = frame.rate_dph[2] if frame.axis_valid[2] else NAN
        if frame.kind == "rate" and frame.message == "dsp3000":
            raw_z = NAN if frame.rate_dph is None else frame.rate_dph[2]
            flag = 1 if frame.axis_valid[2] and frame.axis_present[2] else 0
            return f"{raw_z / self.dsp3000_dph_per_unit:15.6f}   {flag}\r\n".encode("ascii")
        t_s = _text(frame.t_s)
        if frame.kind == "rate":
            line = f"R,{t_s},{_text(rate_dph)}"
        elif frame.kind == "temp":
            line = f"T,{t_s},{_text(_or_nan(frame.temp_c))}"
        elif frame.kind == "imu":
            line = f"I,{t_s},{_text(rate_dph)},{_text(_or_nan(frame.temp_c))}"
        elif frame.kind == "comp":
            comp_dph = NAN if frame.comp_dph is None else frame.comp_dph[2]
            rate_comp_dph = NAN if frame.rate_comp_dph is None else frame.rate_comp_dph[2]
            line = (
                f"C,{t_s},{_text(rate_dph)},{_text(_or_nan(frame.temp_c))},{_text(_or_nan(frame.temp_rate_cps))},"
                f"{_text(comp_dph)},{_text(rate_comp_dph)},{frame.flags}"
            )
        else:
            raise ValueError(f"ascii: lines carry kind 'rate', 'temp', 'imu' or 'comp', not {frame.kind!r}")
        body = line.encode("ascii")
        return body + b"*" + checksum(body) + b"\n"

    def reencode(self, frame: Frame, rate_dph: Sequence[float]) -> bytes:
        raw = frame.raw
        if frame.kind not in ("rate", "imu") or not frame.axis_valid[2]:
            return raw
        text = raw.decode("ascii")
        if frame.message == "dsp3000":
            lead, value, rest = _DSP3000_LINE.match(text.rstrip("\r\n")).groups()
            new_value = _dsp3000_digits(rate_dph[2], self.dsp3000_dph_per_unit, len(lead) + len(value),
                                        len(value.partition(".")[2]))  # fmt: skip
            return (new_value + rest + text[len(text.rstrip("\r\n")) :]).encode("ascii")
        body = text.rstrip("\r\n")
        body, star, _ = body.rpartition("*") if "*" in body else (body, "", "")
        fields = body.split(",")
        fields[2] = repr(float(rate_dph[2]))
        line = ",".join(fields)
        if star:
            line += "*" + checksum(line.encode("ascii")).decode("ascii")
        return (line + text[len(text.rstrip("\r\n")) :]).encode("ascii")


def _dsp3000_digits(rate_dph: float, dph_per_unit: float, width: int, decimals: int) -> str:
    """The DSP-3000 field for `rate_dph`: the unit's own decimals when they carry it to DSP3000_EXACT_DPH
    (what a consumer decodes minus the raw reading is then the model's compensation), else as many more
    as it needs (a compensation of 0.0234 deg/h written to 6 decimals of deg/s loses 0.0018 deg/h)."""
    value = rate_dph / dph_per_unit
    text = f"{value:{width}.{decimals}f}"
    while decimals < DSP3000_MAX_DECIMALS and not abs(float(text) * dph_per_unit - rate_dph) <= DSP3000_EXACT_DPH:
        decimals += 1
        text = f"{value:{width}.{decimals}f}"
    return text


def _or_nan(value: float | None) -> float:
    return NAN if value is None else value
