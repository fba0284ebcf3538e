"""KVH DSP-1750 / DSP-1760 / 1775 binary frames (protocol `kvh-a`): Format A is the primary format; Formats
B and C and the built-in-test (BIT) replies are recognised too, so a 1775 or a BIT request never costs sync.

Layouts, CRC and test vectors are in docs/fogd-frames.md. Every multi-byte field is big-endian and
frames A/B/C end in a CRC-32/MPEG-2 over everything before it. The BIT replies end in one checksum byte that
KVH does not document; fogd takes it as the 8-bit sum of all bytes before it (as a public KVH driver
does) and only ever uses BIT frames as kind 'other', so a wrong guess costs a counted drop, never data.
"""

import math
import struct
from collections.abc import Sequence

from ..errors import ConfigError
from .base import ALL_AXES, NAN, Axes3, Frame, FrameError, Mask3, Protocol
from .crc import crc32_mpeg2, crc32_mpeg2_ok
from .fogdbin import f32

HEADER_A = b"\xfe\x81\xff\x55"
HEADER_B = b"\xfe\x81\xff\x56"
HEADER_C = b"\xfe\x81\xff\x57"
HEADER_BIT = b"\xfe\x81\x00\xaa"
HEADER_BIT2 = b"\xfe\x81\x00\xab"
FRAME_LENGTHS = {HEADER_A: 36, HEADER_B: 40, HEADER_C: 38, HEADER_BIT: 11, HEADER_BIT2: 13}
MESSAGES = {HEADER_A: "A", HEADER_B: "B", HEADER_C: "C", HEADER_BIT: "BIT", HEADER_BIT2: "BIT2"}

DPH_PER_RAD_S = 180.0 / math.pi * 3600.0
ACCEL_STATUS_BITS = 0x70  # fogd's encoder marks the (zero) accels valid, as a DSP-1750 IMU does
SEQ_MODULUS = 128

# Bodies after the 4-byte header, without the CRC: gyro xyz, accel xyz (skipped), then per format.
_BODY_A = struct.Struct(">3f12xBBh")  # status, seq, temperature (whole degrees)
_BODY_B = struct.Struct(">3f12xIBBh")  # time since start (us), status, seq, temperature
_BODY_C = struct.Struct(">3f12xfBB")  # temperature C (seq % 4 == 0) or magnetometer, status, seq
_FRAME_A = struct.Struct(">4s3f3fBBh")
_FRAME_B = struct.Struct(">4s3f3fIBBh")
_FRAME_C = struct.Struct(">4s3f3ffBB")
_CRC = struct.Struct(">I")
_GYRO = struct.Struct(">f")


def bit_reply(bits: bytes) -> bytes:
    """A BIT reply frame around 6 (short BIT) or 8 (extended BIT) status bytes, with its checksum byte."""
    header = {6: HEADER_BIT, 8: HEADER_BIT2}.get(len(bits))
    if header is None:
        raise ValueError(f"a KVH BIT reply carries 6 or 8 status bytes, not {len(bits)}")
    body = header + bits
    return body + bytes([sum(body) & 0xFF])


class KvhProtocol(Protocol):
    """KVH Format A/B/C and BIT replies; options say how the unit is configured.

    rotfmt 'rate' (gyro field is angle/s) or 'delta' (angle per sample; needs rate_hz); angle_unit 'rad' or
    'deg' (the DSP-1760 can send degrees); temp_unit 'C' or 'F' (=TEMPUNITS; Format C is always C);
    comp_axes: the axes whose rates `reencode` replaces.
    """

    name = "kvh-a"
    sync = HEADER_A[:2]
    max_frame_len = max(FRAME_LENGTHS.values())
    seq_modulus = SEQ_MODULUS

    def __init__(
        self,
        rotfmt: str = "rate",
        rate_hz: float | None = None,
        angle_unit: str = "rad",
        temp_unit: str = "C",
        comp_axes: Sequence[int] = (0, 1, 2),
    ) -> None:
        if rotfmt not in ("rate", "delta"):
            raise ConfigError(f"kvh-a: rotfmt must be 'rate' or 'delta', not {rotfmt!r}")
        if rotfmt == "delta" and not (rate_hz and rate_hz > 0):
            raise ConfigError("kvh-a: rotfmt 'delta' needs the unit's output rate (rate_hz > 0)")
        if angle_unit not in ("rad", "deg"):
            raise ConfigError(f"kvh-a: angle_unit must be 'rad' or 'deg', not {angle_unit!r}")
        if temp_unit not in ("C", "F"):
            raise ConfigError(f"kvh-a: temp_unit must be 'C' or 'F', not {temp_unit!r}")
        if not set(comp_axes) <= {0, 1, 2}:
            raise ConfigError(f"kvh-a: comp_axes must be among 0, 1, 2 (x, y, z), not {list(comp_axes)}")
        self.rotfmt, self.rate_hz, self.angle_unit, self.temp_unit = rotfmt, rate_hz, angle_unit, temp_unit
        self.comp_axes = tuple(sorted(set(comp_axes)))
        per_second = rate_hz if rotfmt == "delta" else 1.0
        self.dph_per_unit = (DPH_PER_RAD_S if angle_unit == "rad" else 3600.0) * per_second
        self._decoders = {
            HEADER_A: self._decode_a,
            HEADER_B: self._decode_b,
            HEADER_C: self._decode_c,
            HEADER_BIT: self._decode_bit,
            HEADER_BIT2: self._decode_bit,
        }

    def frame_length(self, buf: bytes, start: int) -> int:
        if len(buf) - start < 4:
            return 0
        return FRAME_LENGTHS.get(buf[start : start + 4], -1)

    def decode(self, raw: bytes) -> Frame:
        decoder = self._decoders.get(raw[:4])
        if decoder is None or len(raw) != FRAME_LENGTHS[raw[:4]]:
            raise ValueError(f"kvh-a: not a whole KVH frame: {raw[:4].hex()}... ({len(raw)} bytes)")
        return decoder(raw)

    def _rates(self, x: float, y: float, z: float, status: int) -> tuple[Axes3, Mask3]:
        isfinite = math.isfinite
        scale = self.dph_per_unit
        if status & 7 == 7 and isfinite(x) and isfinite(y) and isfinite(z):
            return (x * scale, y * scale, z * scale), ALL_AXES  # the usual frame: one shared tuple, not a new one
        valid = (bool(status & 1) and isfinite(x), bool(status & 2) and isfinite(y), bool(status & 4) and isfinite(z))
        return (x * scale, y * scale, z * scale), valid

    def _temp_c(self, whole_degrees: int) -> float:
        return (whole_degrees - 32) * (5.0 / 9.0) if self.temp_unit == "F" else float(whole_degrees)

    def _decode_a(self, raw: bytes) -> Frame:
        if not crc32_mpeg2_ok(raw):
            raise FrameError("bad_crc", "kvh-a: Format A CRC mismatch")
        x, y, z, status, seq, temp = _BODY_A.unpack_from(raw, 4)
        rates, valid = self._rates(x, y, z, status)
        return Frame("kvh-a", "imu", "A", seq, None, rates, valid, ALL_AXES, self._temp_c(temp), raw)

    def _decode_b(self, raw: bytes) -> Frame:
        if not crc32_mpeg2_ok(raw):
            raise FrameError("bad_crc", "kvh-a: Format B CRC mismatch")
        x, y, z, time_us, status, seq, temp = _BODY_B.unpack_from(raw, 4)
        rates, valid = self._rates(x, y, z, status)
        # The uint32 microsecond clock wraps every 4294.967296 s; consumers unwrap it.
        return Frame("kvh-a", "imu", "B", seq, time_us / 1e6, rates, valid, ALL_AXES, self._temp_c(temp), raw)

    def _decode_c(self, raw: bytes) -> Frame:
        if not crc32_mpeg2_ok(raw):
            raise FrameError("bad_crc", "kvh-a: Format C CRC mismatch")
        x, y, z, temp_or_mag, status, seq = _BODY_C.unpack_from(raw, 4)
        rates, valid = self._rates(x, y, z, status)
        if seq % 4 == 0:
            return Frame("kvh-a", "imu", "C", seq, None, rates, valid, ALL_AXES, temp_or_mag, raw)
        return Frame("kvh-a", "rate", "C", seq, None, rates, valid, ALL_AXES, None, raw)

    def _decode_bit(self, raw: bytes) -> Frame:
        if sum(raw[:-1]) & 0xFF != raw[-1]:
            raise FrameError("bad_crc", "kvh-a: BIT reply checksum mismatch")
        return Frame("kvh-a", "other", MESSAGES[raw[:4]], raw=raw)

    def encode(self, frame: Frame) -> bytes:
        """Format A (message '' or 'A'), B or C from a record with rate_dph; BIT replies: see `bit_reply`."""
        message = frame.message or "A"
        if frame.rate_dph is None:
            raise ValueError("kvh-a: a KVH frame needs rate_dph")
        gyro = [value / self.dph_per_unit for value in frame.rate_dph]
        status = ACCEL_STATUS_BITS
        for axis in range(3):
            if frame.axis_valid[axis] and frame.axis_present[axis]:
                status |= 1 << axis
        seq = (frame.seq or 0) % SEQ_MODULUS
        if message == "A":
            body = _FRAME_A.pack(HEADER_A, *gyro, 0.0, 0.0, 0.0, status, seq, self._wire_temp(frame.temp_c))
        elif message == "B":
            if frame.t_s is None:
                raise ValueError("kvh-a: Format B needs t_s")
            time_us = round(frame.t_s * 1e6) % 2**32
            body = _FRAME_B.pack(HEADER_B, *gyro, 0.0, 0.0, 0.0, time_us, status, seq, self._wire_temp(frame.temp_c))
        elif message == "C":
            temp_c = NAN if frame.temp_c is None else frame.temp_c
            temp_or_mag = temp_c if seq % 4 == 0 else 0.0
            body = _FRAME_C.pack(HEADER_C, *gyro, 0.0, 0.0, 0.0, temp_or_mag, status, seq)
        else:
            raise ValueError(f"kvh-a: cannot encode message {message!r}; use 'A', 'B' or 'C'")
        return body + _CRC.pack(crc32_mpeg2(body))

    def _wire_temp(self, temp_c: float | None) -> int:
        if temp_c is None or not math.isfinite(temp_c):
            raise ValueError("kvh-a: Formats A and B need a finite temperature")
        wire = round(temp_c * 9.0 / 5.0 + 32.0 if self.temp_unit == "F" else temp_c)
        if not -32768 <= wire <= 32767:
            raise ValueError(f"kvh-a: temperature {temp_c!r} C does not fit Format A/B's int16")
        return wire

    def reencode(self, frame: Frame, rate_dph: Sequence[float]) -> bytes:
        raw = frame.raw
        if frame.rate_dph is None:
            return raw
        out = bytearray(raw)
        for axis in self.comp_axes:
            if frame.axis_valid[axis]:
                value = rate_dph[axis] / self.dph_per_unit
                try:
                    _GYRO.pack_into(out, 4 + 4 * axis, value)
                except OverflowError:  # beyond float32 (a rate near its limit, compensated): infinity
                    _GYRO.pack_into(out, 4 + 4 * axis, f32(value))
        _CRC.pack_into(out, len(out) - 4, crc32_mpeg2(out[:-4]))
        return bytes(out)

