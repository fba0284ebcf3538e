"""KVH DSP-1750 / DSP-1760 / 1775 binary frames (protocol `kvh-a`): Format A is the primary format; Formats
B and C and the built-in-test (BIT) replies are recognised too, so a 1775 or a BIT request never costs sync.

Layouts, CRC and test vectors are in docs/reference/wire-formats.md. Every multi-byte field is big-endian and
frames A/B/C end in a CRC-32/MPEG-2 over everything before it. The BIT replies end in one checksum byte that
KVH does not document; fogd takes it as the 8-bit sum of all bytes before it (as a public KVH driver
does) and only ever uses BIT frames as kind 'other', so a wrong guess costs a counted drop, never data.

Whatever the unit is set to (=ROTFMT rate or delta, =ROTUNITS rad or deg, =LINFMT acceleration or delta
velocity, =LINUNITS m or ft, =TEMPUNITS C or F, =DR), a Frame carries deg/h, g and C; the same settings turn
them back into the unit's wire values. The replies to the unit's ASCII queries (?ROTFMT, ?DR, ...) are parsed
into the same settings by `settings_from_replies`.
"""

import binascii
import math
import struct
from collections.abc import Sequence

from ..errors import ConfigError
from .base import ALL_AXES, NAN, Axes3, Frame, FrameError, Mask3, Protocol
from .crc import MIRRORED_BYTES, crc32_mpeg2, crc32_mpeg2_ok
from .fogdbin import f32

HEADER_A = b"\xfe\x81\xff\x55"
HEADER_B = b"\xfe\x81\xff\x56"
HEADER_C = b"\xfe\x81\xff\x57"
HEADER_BIT = b"\xfe\x81\x00\xaa"
HEADER_BIT2 = b"\xfe\x81\x00\xab"
FRAME_LENGTHS = {HEADER_A: 36, HEADER_B: 40, HEADER_C: 38, HEADER_BIT: 11, HEADER_BIT2: 13}
MESSAGES = {HEADER_A: "A", HEADER_B: "B", HEADER_C: "C", HEADER_BIT: "BIT", HEADER_BIT2: "BIT2"}

DPH_PER_RAD_S = 180.0 / math.pi * 3600.0
STANDARD_GRAVITY_MS2 = 9.80665  # delta velocity to g: KVH does not say which g it means; this is the standard one
M_PER_FT = 0.3048
ACCEL_STATUS_BITS = 0x70  # fogd's encoder marks the (zero) accels valid, as a DSP-1750 IMU does
SEQ_MODULUS = 128
ROTFMTS = ("rate", "delta")
LINFMTS = ("accel", "delta")
ANGLE_UNITS = ("rad", "deg")
LIN_UNITS = ("m", "ft")
TEMP_UNITS = ("C", "F")

# Bodies after the 4-byte header, without the CRC: gyro xyz, accel xyz, then per format.
_BODY_A = struct.Struct(">3f3fBBh")  # status, seq, temperature (whole degrees)
_BODY_B = struct.Struct(">3f3fIBBh")  # time since start (us), status, seq, temperature
_BODY_C = struct.Struct(">3f3ffBB")  # temperature C (seq % 4 == 0) or magnetometer, status, seq
_FRAME_A = struct.Struct(">4s3f3fBBh")
_FRAME_B = struct.Struct(">4s3f3fIBBh")
_FRAME_C = struct.Struct(">4s3f3ffBB")
_CRC = struct.Struct(">I")
_GYRO = struct.Struct(">f")
_GYROS = struct.Struct(">3f")  # the three gyros, or with the three accelerometers after them
_GYROS_ACCELS = struct.Struct(">6f")
_EVERY = (True, True, True)


def bit_reply(bits: bytes) -> bytes:
    """A BIT reply frame around 6 (short BIT) or 8 (extended BIT) status bytes, with its checksum byte."""
    header = {6: HEADER_BIT, 8: HEADER_BIT2}.get(len(bits))
    if header is None:
        raise ValueError(f"a KVH BIT reply carries 6 or 8 status bytes, not {len(bits)}")
    body = header + bits
    return body + bytes([sum(body) & 0xFF])


class KvhProtocol(Protocol):
    """KVH Format A/B/C and BIT replies; options say how the unit is configured.

    rotfmt 'rate' (gyro field is angle/s) or 'delta' (angle per sample; needs rate_hz, the unit's =DR);
    angle_unit 'rad' or 'deg' (=ROTUNITS); linfmt 'accel' (accelerometer field in g, the default) or 'delta'
    (velocity change per sample, needs rate_hz) in lin_unit 'm' or 'ft' (=LINUNITS: m/s or ft/s);
    temp_unit 'C' or 'F' (=TEMPUNITS; Format C is always C); comp_axes and comp_accel_axes: the gyro and
    accelerometer axes whose values `reencode` replaces.
    """

    name = "kvh-a"
    sync = HEADER_A[:2]
    max_frame_len = max(FRAME_LENGTHS.values())
    seq_modulus = SEQ_MODULUS
    accel_axes = ALL_AXES

    def __init__(
        self,
        rotfmt: str = "rate",
        rate_hz: float | None = None,
        angle_unit: str = "rad",
        temp_unit: str = "C",
        comp_axes: Sequence[int] = (0, 1, 2),
        linfmt: str = "accel",
        lin_unit: str = "m",
        comp_accel_axes: Sequence[int] = (0, 1, 2),
    ) -> None:
        for option, value, allowed in (("rotfmt", rotfmt, ROTFMTS), ("linfmt", linfmt, LINFMTS),
                                       ("angle_unit", angle_unit, ANGLE_UNITS), ("lin_unit", lin_unit, LIN_UNITS),
                                       ("temp_unit", temp_unit, TEMP_UNITS)):  # fmt: skip
            if value not in allowed:
                raise ConfigError(f"kvh-a: {option} must be {' or '.join(map(repr, allowed))}, not {value!r}")
        for option, value in (("rotfmt", rotfmt), ("linfmt", linfmt)):
            if value == "delta" and not (isinstance(rate_hz, (int, float)) and 0 < rate_hz < math.inf):
                raise ConfigError(f"kvh-a: {option} 'delta' needs the unit's output rate (rate_hz > 0)")
        for option, axes in (("comp_axes", comp_axes), ("comp_accel_axes", comp_accel_axes)):
            if not set(axes) <= {0, 1, 2}:
                raise ConfigError(f"kvh-a: {option} must be among 0, 1, 2 (x, y, z), not {list(axes)}")
        self.rotfmt, self.rate_hz, self.angle_unit, self.temp_unit = rotfmt, rate_hz, angle_unit, temp_unit
        self.linfmt, self.lin_unit = linfmt, lin_unit
        self.comp_axes = tuple(sorted(set(comp_axes)))
        self.comp_accel_axes = tuple(sorted(set(comp_accel_axes)))
        self._every_gyro, self._every_accel = self.comp_axes == (0, 1, 2), self.comp_accel_axes == (0, 1, 2)
        # a single compensated gyro (a one-axis model): its one pack, no loop over axes, when no accelerometer is
        # given to replace (the daemon's one-gyro plan gives none, whatever comp_accel_axes says)
        self._one_gyro = self.comp_axes[0] if len(self.comp_axes) == 1 else None
        per_second = rate_hz if rotfmt == "delta" else 1.0
        self.dph_per_unit = (DPH_PER_RAD_S if angle_unit == "rad" else 3600.0) * per_second
        # delta velocity (m/s or ft/s per sample) x samples per second = m/s^2 or ft/s^2
        metres = 1.0 if lin_unit == "m" else M_PER_FT
        self.g_per_unit = rate_hz * metres / STANDARD_GRAVITY_MS2 if linfmt == "delta" else 1.0
        self._plain = temp_unit == "C" and linfmt == "accel"  # decode_fast's frames need no unit conversion
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

    def decode_fast(self, buf: bytes, start: int) -> tuple[Frame, int] | None:
        """The lexer's fast path: a whole Format A frame with a good CRC at `start` of `buf`, decoded as
        `decode` does, with its length; None for anything else (the lexer's general path takes it)."""
        if buf[start : start + 4] != HEADER_A or len(buf) - start < 36:
            return None
        raw = buf[start : start + 36] if start or len(buf) != 36 else buf
        if binascii.crc32(raw.translate(MIRRORED_BYTES)) != 0xFFFFFFFF:  # crc32_mpeg2_ok, inlined
            return None
        x, y, z, ax, ay, az, status, seq, temp = _BODY_A.unpack_from(raw, 4)
        # every value finite in one expression, not six isfinite calls: v - v is 0.0 for a finite v, NaN for NaN or Inf
        if status & 0x77 == 0x77 and self._plain and (x - x) + (y - y) + (z - z) + (ax - ax) + (ay - ay) + (az - az) == 0.0:
            scale = self.dph_per_unit
            return Frame("kvh-a", "imu", "A", seq, None, (x * scale, y * scale, z * scale), ALL_AXES, ALL_AXES,
                         float(temp), raw, None, None, None, 0, (ax, ay, az), ALL_AXES, ALL_AXES), 36  # fmt: skip
        return self._decode_a(raw), 36

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

    def _accels(self, x: float, y: float, z: float, status: int) -> tuple[Axes3, Mask3]:
        isfinite = math.isfinite
        scale = self.g_per_unit
        if status & 0x70 == 0x70 and isfinite(x) and isfinite(y) and isfinite(z):
            return (x * scale, y * scale, z * scale), ALL_AXES
        valid = (bool(status & 0x10) and isfinite(x), bool(status & 0x20) and isfinite(y),
                 bool(status & 0x40) and isfinite(z))  # fmt: skip
        return (x * scale, y * scale, z * scale), valid

    def _temp_c(self, whole_degrees: int) -> float:
        return (whole_degrees - 32) * (5.0 / 9.0) if self.temp_unit == "F" else float(whole_degrees)

    def _decode_a(self, raw: bytes) -> Frame:
        if not crc32_mpeg2_ok(raw):
            raise FrameError("bad_crc", "kvh-a: Format A CRC mismatch")
        x, y, z, ax, ay, az, status, seq, temp = _BODY_A.unpack_from(raw, 4)
        rates, valid = self._rates(x, y, z, status)
        accels, accel_valid = self._accels(ax, ay, az, status)
        return Frame("kvh-a", "imu", "A", seq, None, rates, valid, ALL_AXES, self._temp_c(temp), raw,
                     accel_g=accels, accel_valid=accel_valid, accel_present=ALL_AXES)  # fmt: skip

    def _decode_b(self, raw: bytes) -> Frame:
        if not crc32_mpeg2_ok(raw):
            raise FrameError("bad_crc", "kvh-a: Format B CRC mismatch")
        x, y, z, ax, ay, az, time_us, status, seq, temp = _BODY_B.unpack_from(raw, 4)
        rates, valid = self._rates(x, y, z, status)
        accels, accel_valid = self._accels(ax, ay, az, status)
        # The uint32 microsecond clock wraps every 4294.967296 s; consumers unwrap it.
        return Frame("kvh-a", "imu", "B", seq, time_us / 1e6, rates, valid, ALL_AXES, self._temp_c(temp), raw,
                     accel_g=accels, accel_valid=accel_valid, accel_present=ALL_AXES)  # fmt: skip

    def _decode_c(self, raw: bytes) -> Frame:
        if not crc32_mpeg2_ok(raw):
            raise FrameError("bad_crc", "kvh-a: Format C CRC mismatch")
        x, y, z, ax, ay, az, temp_or_mag, status, seq = _BODY_C.unpack_from(raw, 4)
        rates, valid = self._rates(x, y, z, status)
        accels, accel_valid = self._accels(ax, ay, az, status)
        kind, temp_c = ("imu", temp_or_mag) if seq % 4 == 0 else ("rate", None)
        return Frame("kvh-a", kind, "C", seq, None, rates, valid, ALL_AXES, temp_c, raw,
                     accel_g=accels, accel_valid=accel_valid, accel_present=ALL_AXES)  # fmt: skip

    def _decode_bit(self, raw: bytes) -> Frame:
        if sum(raw[:-1]) & 0xFF != raw[-1]:
            raise FrameError("bad_crc", "kvh-a: BIT reply checksum mismatch")
        return Frame("kvh-a", "other", MESSAGES[raw[:4]], raw=raw)

    def encode(self, frame: Frame) -> bytes:
        """Format A (message '' or 'A'), B or C from a record with rate_dph; BIT replies: see `bit_reply`.

        A record without accel_g gets zero accelerations with status bits 4-6 set, as a DSP-1750 IMU sends.
        """
        message = frame.message or "A"
        if frame.rate_dph is None:
            raise ValueError("kvh-a: a KVH frame needs rate_dph")
        gyro = [value / self.dph_per_unit for value in frame.rate_dph]
        if frame.accel_g is None:
            accel, status = [0.0, 0.0, 0.0], ACCEL_STATUS_BITS
        else:
            accel, status = [value / self.g_per_unit for value in frame.accel_g], 0
            for axis in range(3):
                if frame.accel_valid[axis] and frame.accel_present[axis]:
                    status |= 0x10 << axis
        for axis in range(3):
            if frame.axis_valid[axis] and frame.axis_present[axis]:
                status |= 1 << axis
        seq = (frame.seq or 0) % SEQ_MODULUS
        if message == "A":
            body = _FRAME_A.pack(HEADER_A, *gyro, *accel, status, seq, self._wire_temp(frame.temp_c))
        elif message == "B":
            if frame.t_s is None:
                raise ValueError("kvh-a: Format B needs t_s")
            time_us = round(frame.t_s * 1e6) % 2**32
            body = _FRAME_B.pack(HEADER_B, *gyro, *accel, time_us, status, seq, self._wire_temp(frame.temp_c))
        elif message == "C":
            temp_c = NAN if frame.temp_c is None else frame.temp_c
            temp_or_mag = temp_c if seq % 4 == 0 else 0.0
            body = _FRAME_C.pack(HEADER_C, *gyro, *accel, temp_or_mag, status, seq)
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

    def reencode(self, frame: Frame, rate_dph: Sequence[float], accel_g: Sequence[float] | None = None) -> bytes:
        """As `Protocol.reencode`; with `accel_g`, the valid accelerometers of comp_accel_axes are replaced too."""
        raw = frame.raw
        if frame.rate_dph is None:
            return raw
        out = bytearray(raw)
        if not self._pack_whole(out, frame, rate_dph, accel_g):
            self._pack_axes(out, frame, rate_dph, accel_g)
        # crc32_mpeg2 packed big-endian: the mirrored register's little-endian bytes, each mirrored back
        reflected = binascii.crc32(out[:-4].translate(MIRRORED_BYTES)) ^ 0xFFFFFFFF
        out[-4:] = reflected.to_bytes(4, "little").translate(MIRRORED_BYTES)
        return bytes(out)

    def _pack_whole(self, out: bytearray, frame: Frame, rate_dph: Sequence[float], accel_g: Sequence[float] | None) -> bool:
        """The common frame in one pack: a one-gyro model's axis, or every gyro (and every accelerometer)
        compensated and valid; False where `_pack_axes` must go axis by axis (some invalid, a value beyond
        float32's range)."""
        one = self._one_gyro
        if one is not None and (accel_g is None or frame.accel_g is None or not self.comp_accel_axes):
            if frame.axis_valid[one]:  # (an invalid axis keeps its wire value, as in `_pack_axes`)
                try:
                    _GYRO.pack_into(out, 4 + 4 * one, rate_dph[one] / self.dph_per_unit)
                except OverflowError:
                    return False
            return True
        if not (self._every_gyro and frame.axis_valid == _EVERY):
            return False
        to_unit = self.dph_per_unit
        try:
            if accel_g is None or frame.accel_g is None or not self.comp_accel_axes:
                _GYROS.pack_into(out, 4, rate_dph[0] / to_unit, rate_dph[1] / to_unit, rate_dph[2] / to_unit)
                return True
            if self._every_accel and frame.accel_valid == _EVERY:
                g = self.g_per_unit
                _GYROS_ACCELS.pack_into(out, 4, rate_dph[0] / to_unit, rate_dph[1] / to_unit, rate_dph[2] / to_unit,
                                        accel_g[0] / g, accel_g[1] / g, accel_g[2] / g)  # fmt: skip
                return True
        except OverflowError:  # rare: the axes one by one, each beyond float32's range as infinity
            pass
        return False

    def _pack_axes(self, out: bytearray, frame: Frame, rate_dph: Sequence[float], accel_g: Sequence[float] | None) -> None:
        for axis in self.comp_axes:
            if frame.axis_valid[axis]:
                value = rate_dph[axis] / self.dph_per_unit
                try:
                    _GYRO.pack_into(out, 4 + 4 * axis, value)
                except OverflowError:  # beyond float32 (a rate near its limit, compensated): infinity
                    _GYRO.pack_into(out, 4 + 4 * axis, f32(value))
        if accel_g is not None and frame.accel_g is not None:
            for axis in self.comp_accel_axes:
                if frame.accel_valid[axis]:
                    _GYRO.pack_into(out, 16 + 4 * axis, f32(accel_g[axis] / self.g_per_unit))



# The unit's settings as its ASCII query replies name them (`?ROTFMT` -> `ROTFMT,DELTA`), mapped to the
# protocol options above. =LINFMT's words are not in the manual pages fogd was written from; ACCEL / DELTA
# follow =ROTFMT's RATE / DELTA.
SETTING_QUERIES = ("ROTFMT", "ROTUNITS", "LINFMT", "LINUNITS", "TEMPUNITS", "DR")
_REPLY_VALUES: dict[str, tuple[str, dict[str, str]]] = {
    "ROTFMT": ("rotfmt", {"RATE": "rate", "DELTA": "delta"}),
    "ROTUNITS": ("angle_unit", {"RAD": "rad", "DEG": "deg"}),
    "LINFMT": ("linfmt", {"ACCEL": "accel", "DELTA": "delta"}),
    "LINUNITS": ("lin_unit", {"METERS": "m", "FEET": "ft"}),
    "TEMPUNITS": ("temp_unit", {"C": "C", "F": "F"}),
}
DATA_RATES_HZ = (1, 5, 10, 25, 50, 100, 250, 500, 750, 1000, 3600, 5000)  # =DR's permitted values (1775)


def query(name: str) -> bytes:
    """The ASCII query for one setting (`?DR\\r\\n`); the unit answers it in configuration mode."""
    if name.upper() not in SETTING_QUERIES:
        raise ValueError(f"kvh-a: no setting query {name!r}; known: {', '.join(SETTING_QUERIES)}")
    return f"?{name.upper()}\r\n".encode("ascii")


def parse_reply(line: bytes | str) -> tuple[str, object]:
    """One reply line (`ROTFMT,DELTA`, `DR,1000`) as (protocol option, value): ('rotfmt', 'delta'),
    ('rate_hz', 1000.0). Raises ConfigError naming the line for anything else."""
    text = line.decode("ascii", "replace") if isinstance(line, bytes) else line
    key, _, value = text.strip().upper().partition(",")
    value = value.strip()
    if key == "DR":
        try:
            rate_hz = float(value)
        except ValueError:
            rate_hz = math.nan
        if not 0 < rate_hz <= 100_000:
            raise ConfigError(f"kvh-a: the unit's data rate reply {text.strip()!r} is not a rate in Hz")
        return "rate_hz", rate_hz
    if key not in _REPLY_VALUES:
        raise ConfigError(f"kvh-a: {text.strip()!r} is not a reply to a settings query ({', '.join(SETTING_QUERIES)})")
    option, values = _REPLY_VALUES[key]
    if value not in values:
        raise ConfigError(f"kvh-a: unknown {key} setting {value!r} (known: {', '.join(values)})")
    return option, values[value]


def settings_from_replies(lines: Sequence[bytes | str]) -> dict[str, object]:
    """Protocol options from the unit's reply lines; blank lines, echoes of queries and `CONFIG,...` are skipped."""
    settings: dict[str, object] = {}
    for line in lines:
        text = line.decode("ascii", "replace") if isinstance(line, bytes) else line
        if not text.strip() or text.lstrip().startswith(("?", "=")) or text.strip().upper().startswith("CONFIG"):
            continue
        option, value = parse_reply(text)
        settings[option] = value
    return settings


def settings_reply(protocol: KvhProtocol, name: str) -> bytes:
    """What a unit configured as `protocol` answers to `?<name>` (for emulators and tests)."""
    key = name.upper()
    if key == "DR":
        if protocol.rate_hz is None:
            raise ValueError("kvh-a: no data rate (rate_hz) to reply with")
        return f"DR,{protocol.rate_hz:g}\r\n".encode("ascii")
    if key not in _REPLY_VALUES:
        raise ValueError(f"kvh-a: no setting query {name!r}; known: {', '.join(SETTING_QUERIES)}")
    option, values = _REPLY_VALUES[key]
    wire = {ours: theirs for theirs, ours in values.items()}[getattr(protocol, option)]
    return f"{key},{wire}\r\n".encode("ascii")
