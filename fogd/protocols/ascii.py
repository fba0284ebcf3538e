"""Line formats for humans and scripts (protocol `ascii`): KVH DSP-3000 output lines and fogd's own
comma-separated lines for rate, temperature, both, and compensated output (grammar in docs/fogd-frames.md).

Both are single-axis: the rate is the z axis (index 2), x and y are absent. A line that does not parse is
rejected whole and counted as `bad_line`; blank lines are skipped as garbage.
"""

import math
import re
from collections.abc import Sequence

from ..errors import ConfigError
from .base import NAN, Z_ONLY, Axes3, Frame, FrameError, Mask3, Protocol

MAX_LINE_LEN = 256
FIELD_COUNTS = {"R": 3, "T": 3, "I": 4, "C": 8}
_DSP3000_LINE = re.compile(r"^(\s*)(\S+)(\s+[01]\s*)$")


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise FrameError("bad_line", f"ascii: {text!r} is not a number") from None


def _time(text: str) -> float | None:
    return _number(text) if text.strip() else None


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

    def __init__(self, rotfmt: str = "rate", rate_hz: float | None = None) -> None:
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
            return self._decode_dsp3000(line, raw)
        fields = line.split(",")
        tag = fields[0].strip()
        if FIELD_COUNTS.get(tag) != len(fields):
            raise FrameError("bad_line", f"ascii: not an R, T, I or C line: {line[:40]!r}")
        t_s = _time(fields[1])
        if tag == "T":
            return Frame("ascii", "temp", "T", None, t_s, temp_c=_number(fields[2]), raw=raw)
        rates, valid = _z_axis(_number(fields[2]))
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
        rates, valid = _z_axis(_number(fields[0]) * self.dsp3000_dph_per_unit)
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
        return (line + "\n").encode("ascii")

    def reencode(self, frame: Frame, rate_dph: Sequence[float]) -> bytes:
        raw = frame.raw
        if frame.kind not in ("rate", "imu") or not frame.axis_valid[2]:
            return raw
        text = raw.decode("ascii")
        if frame.message == "dsp3000":
            lead, value, rest = _DSP3000_LINE.match(text.rstrip("\r\n")).groups()
            decimals = len(value.partition(".")[2])
            new_value = f"{rate_dph[2] / self.dsp3000_dph_per_unit:{len(lead) + len(value)}.{decimals}f}"
            return (new_value + rest + text[len(text.rstrip("\r\n")) :]).encode("ascii")
        body = text.rstrip("\r\n")
        fields = body.split(",")
        fields[2] = repr(float(rate_dph[2]))
        return (",".join(fields) + text[len(body) :]).encode("ascii")


def _or_nan(value: float | None) -> float:
    return NAN if value is None else value
