"""fogd's own binary frames (protocol `fogd`): a FOG-rate frame, a temperature frame, a compensated-output frame,
an IMU frame (three gyros, three accelerometers and a temperature) and a compensated-IMU frame (the daemon's
output for a multi-channel model: every channel's reading, compensation, compensated value and flags), each
with a sync word, type, length, per-type sequence counter, device timestamp and CRC-16.

Rate and temperature frames carry their own timestamps and counters so a rig with a separate FOG and
temperature sensor can feed fogd at different rates, over one link or two. Byte tables: docs/reference/wire-formats.md.
Everything is big-endian, like the KVH frames; floats are IEEE-754 single.
"""

import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass

from ..errors import ConfigError
from .base import MAX_T_S, NAN, Axes3, Frame, FrameError, Mask3, Protocol
from .crc import crc16_ccitt_false, crc16_ccitt_false_ok

SYNC = b"\xf0\x0d"
TYPE_RATE = 0x01
TYPE_TEMP = 0x02
TYPE_COMP = 0x03
TYPE_IMU = 0x04
TYPE_COMP_IMU = 0x05
SEQ_MODULUS = 1 << 16
F32_MAX = 3.4028234663852886e38
MAX_TIME_US = round(MAX_T_S * 1e6)

_HEADER = struct.Struct(">2sBBHQ")  # sync, type, length (whole frame), seq, device time (us)
_RATE = struct.Struct(">3fB")  # rate xyz (deg/h), axes
_TEMP = struct.Struct(">f")  # temperature (C)
_COMP = struct.Struct(">3f3f3fBffH")  # rate, compensation, compensated rate xyz (deg/h), axes, C, C/s, flags
_IMU = struct.Struct(">3f3fBBf")  # rate xyz (deg/h), accel xyz (g), gyro axes, accel axes, temperature (C)
# rate xyz (deg/h), accel xyz (g), comp gyro xyz, comp accel xyz, compensated gyro xyz, compensated accel xyz,
# gyro axes, accel axes, compensated channels, temperature (C), temperature rate (C/s), flags of the six channels
_COMP_IMU = struct.Struct(">3f3f3f3f3f3fBBBff6H")
_CRC = struct.Struct(">H")
_F32 = struct.Struct(">f")
HEADER_LEN = _HEADER.size
MIN_FRAME_LEN = HEADER_LEN + _CRC.size
FRAME_LENGTHS = {
    TYPE_RATE: HEADER_LEN + _RATE.size + _CRC.size,
    TYPE_TEMP: HEADER_LEN + _TEMP.size + _CRC.size,
    TYPE_COMP: HEADER_LEN + _COMP.size + _CRC.size,
    TYPE_IMU: HEADER_LEN + _IMU.size + _CRC.size,
    TYPE_COMP_IMU: HEADER_LEN + _COMP_IMU.size + _CRC.size,
}


def _axes_byte(valid: Sequence[bool], present: Sequence[bool]) -> int:
    """Bits 0-2: axis x/y/z valid; bits 4-6: axis x/y/z present (fitted)."""
    byte = 0
    for axis in range(3):
        if present[axis]:
            byte |= 0x10 << axis
            if valid[axis]:
                byte |= 1 << axis
    return byte


def _axes(byte: int, x: float, y: float, z: float) -> tuple[Mask3, Mask3]:
    present = (bool(byte & 0x10), bool(byte & 0x20), bool(byte & 0x40))
    isfinite = math.isfinite
    valid = (
        present[0] and bool(byte & 1) and isfinite(x),
        present[1] and bool(byte & 2) and isfinite(y),
        present[2] and bool(byte & 4) and isfinite(z),
    )
    return valid, present


class FogdProtocol(Protocol):
    """fogd frames; comp_axes and comp_accel_axes are the gyro and accelerometer axes whose values `reencode`
    replaces in a rate or IMU frame."""

    name = "fogd"
    sync = SYNC
    max_frame_len = 255
    seq_modulus = SEQ_MODULUS
    repeats_are_copies = True
    accel_axes = (True, True, True)  # in IMU frames (type 04)

    def __init__(self, comp_axes: Sequence[int] = (0, 1, 2), comp_accel_axes: Sequence[int] = (0, 1, 2)) -> None:
        for option, axes in (("comp_axes", comp_axes), ("comp_accel_axes", comp_accel_axes)):
            if not set(axes) <= {0, 1, 2}:
                raise ConfigError(f"fogd: {option} must be among 0, 1, 2 (x, y, z), not {list(axes)}")
        self.comp_axes = tuple(sorted(set(comp_axes)))
        self.comp_accel_axes = tuple(sorted(set(comp_accel_axes)))

    def frame_length(self, buf: bytes, start: int) -> int:
        if len(buf) - start < 4:
            return 0
        length = buf[start + 3]
        expected = FRAME_LENGTHS.get(buf[start + 2], length)
        # A known type with a foreign length, or a length too short for header and CRC, is no header at all.
        return length if length == expected and length >= MIN_FRAME_LEN else -1

    def decode(self, raw: bytes) -> Frame:
        if not crc16_ccitt_false_ok(raw):
            raise FrameError("bad_crc", "fogd: CRC mismatch")
        sync, frame_type, length, seq, time_us = _HEADER.unpack_from(raw)
        if sync != SYNC or length != len(raw) or FRAME_LENGTHS.get(frame_type, length) != length:
            raise ValueError(f"fogd: not a whole fogd frame ({len(raw)} bytes)")
        if time_us > MAX_TIME_US:  # the CRC passed, but no clock says this: not encodable in any output
            raise FrameError("bad_value", f"fogd: device time {time_us} us is beyond 2^53 us")
        t_s = time_us / 1e6
        if frame_type == TYPE_RATE:
            x, y, z, axes = _RATE.unpack_from(raw, HEADER_LEN)
            valid, present = _axes(axes, x, y, z)
            return Frame("fogd", "rate", "rate", seq, t_s, (x, y, z), valid, present, None, raw)
        if frame_type == TYPE_TEMP:
            (temp_c,) = _TEMP.unpack_from(raw, HEADER_LEN)
            return Frame("fogd", "temp", "temp", seq, t_s, temp_c=temp_c, raw=raw)
        if frame_type == TYPE_COMP:
            x, y, z, cx, cy, cz, rx, ry, rz, axes, temp_c, temp_rate_cps, flags = _COMP.unpack_from(raw, HEADER_LEN)
            valid, present = _axes(axes, x, y, z)
            return Frame(
                "fogd", "comp", "comp", seq, t_s, (x, y, z), valid, present, temp_c, raw,
                temp_rate_cps, (cx, cy, cz), (rx, ry, rz), flags,
            )
        if frame_type == TYPE_IMU:
            x, y, z, ax, ay, az, axes, accel_axes, temp_c = _IMU.unpack_from(raw, HEADER_LEN)
            valid, present = _axes(axes, x, y, z)
            accel_valid, accel_present = _axes(accel_axes, ax, ay, az)
            return Frame("fogd", "imu", "imu", seq, t_s, (x, y, z), valid, present, temp_c, raw,
                         accel_g=(ax, ay, az), accel_valid=accel_valid, accel_present=accel_present)  # fmt: skip
        if frame_type == TYPE_COMP_IMU:
            record = _comp_imu(raw, seq, t_s)
            flags = 0
            for value in record.flags:
                flags |= value
            # the gyros as a 'comp' frame; every channel, accelerometers too, through decode_comp_imu(frame.raw)
            return Frame("fogd", "comp", "comp_imu", seq, t_s, record.rate_dph, record.axis_valid, record.axis_present,
                         record.temp_c, raw, record.temp_rate_cps, record.comp[:3], record.compensated[:3], flags,
                         accel_g=record.accel_g, accel_valid=record.accel_valid, accel_present=record.accel_present)  # fmt: skip
        return Frame("fogd", "other", "other", seq, t_s, raw=raw)

    def encode(self, frame: Frame) -> bytes:
        """A rate, temp, comp or imu frame from a record of that kind (t_s must be >= 0; it travels in whole us)."""
        if frame.t_s is None:
            raise ValueError("fogd: a fogd frame needs t_s")
        if frame.kind == "rate":
            payload = _pack(_RATE, *_rates(frame.rate_dph), _axes_byte(frame.axis_valid, frame.axis_present))
            frame_type = TYPE_RATE
        elif frame.kind == "temp":
            payload = _pack(_TEMP, NAN if frame.temp_c is None else frame.temp_c)
            frame_type = TYPE_TEMP
        elif frame.kind == "comp":
            payload = _pack(
                _COMP, *_rates(frame.rate_dph), *_rates(frame.comp_dph), *_rates(frame.rate_comp_dph),
                _axes_byte(frame.axis_valid, frame.axis_present),
                NAN if frame.temp_c is None else frame.temp_c,
                NAN if frame.temp_rate_cps is None else frame.temp_rate_cps,
                frame.flags,
            )  # fmt: skip
            frame_type = TYPE_COMP
        elif frame.kind == "imu":
            payload = _pack(
                _IMU, *_rates(frame.rate_dph), *_rates(frame.accel_g),
                _axes_byte(frame.axis_valid, frame.axis_present), _axes_byte(frame.accel_valid, frame.accel_present),
                NAN if frame.temp_c is None else frame.temp_c,
            )  # fmt: skip
            frame_type = TYPE_IMU
        else:
            raise ValueError(f"fogd: frames carry kind 'rate', 'temp', 'comp' or 'imu', not {frame.kind!r}")
        seq = (frame.seq or 0) % SEQ_MODULUS
        time_us = round(frame.t_s * 1e6)
        if not 0 <= time_us <= MAX_TIME_US:
            raise ValueError(f"fogd: t_s {frame.t_s!r} is outside 0..2^53 us")
        body = _HEADER.pack(SYNC, frame_type, FRAME_LENGTHS[frame_type], seq, time_us) + payload
        return body + _CRC.pack(crc16_ccitt_false(body))

    def reencode(self, frame: Frame, rate_dph: Sequence[float], accel_g: Sequence[float] | None = None) -> bytes:
        """As `Protocol.reencode`; in an IMU frame, with `accel_g`, the valid accelerometers of comp_accel_axes
        are replaced too."""
        raw = frame.raw
        if frame.kind not in ("rate", "imu"):
            return raw
        out = bytearray(raw)
        for axis in self.comp_axes:
            if frame.axis_valid[axis]:
                try:
                    _F32.pack_into(out, HEADER_LEN + 4 * axis, rate_dph[axis])
                except OverflowError:  # beyond float32 (a rate near its limit, compensated): infinity
                    _F32.pack_into(out, HEADER_LEN + 4 * axis, f32(rate_dph[axis]))
        if accel_g is not None and frame.kind == "imu":
            for axis in self.comp_accel_axes:
                if frame.accel_valid[axis]:
                    _F32.pack_into(out, HEADER_LEN + 12 + 4 * axis, f32(accel_g[axis]))
        _CRC.pack_into(out, len(out) - 2, crc16_ccitt_false(out[:-2]))
        return bytes(out)


@dataclass(frozen=True)
class CompImu:
    """One compensated-IMU frame (type 05): the six channels in the order rate x, y, z (deg/h), accel x, y, z
    (g). `covered[i]` says whether channel i was compensated; a channel passed through has comp 0, its
    reading as the compensated value, and flags 0."""

    seq: int
    t_s: float
    rate_dph: Axes3
    accel_g: Axes3
    axis_valid: Mask3
    axis_present: Mask3
    accel_valid: Mask3
    accel_present: Mask3
    comp: tuple[float, ...]  # six: the compensation subtracted
    compensated: tuple[float, ...]  # six: reading - comp
    covered: tuple[bool, ...]  # six
    temp_c: float
    temp_rate_cps: float
    flags: tuple[int, ...]  # six: fogd.core.flags.Flag bits of each channel


def encode_comp_imu(record: CompImu) -> bytes:
    """A type-05 frame (t_s >= 0, in whole us)."""
    covered = 0
    for i, done in enumerate(record.covered):
        if done:
            covered |= 1 << i if i < 3 else 0x10 << (i - 3)
    payload = _pack(
        _COMP_IMU, *_rates(record.rate_dph), *_rates(record.accel_g), *record.comp, *record.compensated,
        _axes_byte(record.axis_valid, record.axis_present), _axes_byte(record.accel_valid, record.accel_present),
        covered, record.temp_c, record.temp_rate_cps, *record.flags,
    )  # fmt: skip
    time_us = round(record.t_s * 1e6)
    if not 0 <= time_us <= MAX_TIME_US:
        raise ValueError(f"fogd: t_s {record.t_s!r} is outside 0..2^53 us")
    length = FRAME_LENGTHS[TYPE_COMP_IMU]
    body = _HEADER.pack(SYNC, TYPE_COMP_IMU, length, record.seq % SEQ_MODULUS, time_us) + payload
    return body + _CRC.pack(crc16_ccitt_false(body))


def decode_comp_imu(raw: bytes) -> CompImu:
    """Every field of a whole type-05 frame (CRC checked); FrameError or ValueError otherwise."""
    if not crc16_ccitt_false_ok(raw):
        raise FrameError("bad_crc", "fogd: CRC mismatch")
    _, frame_type, length, seq, time_us = _HEADER.unpack_from(raw)
    if frame_type != TYPE_COMP_IMU or not length == len(raw) == FRAME_LENGTHS[TYPE_COMP_IMU]:
        raise ValueError(f"fogd: not a whole compensated-IMU frame ({len(raw)} bytes, type {frame_type})")
    return _comp_imu(raw, seq, time_us / 1e6)


def _comp_imu(raw: bytes, seq: int, t_s: float) -> CompImu:
    values = _COMP_IMU.unpack_from(raw, HEADER_LEN)
    rates, accels = values[0:3], values[3:6]
    axes, accel_axes, covered, temp_c, temp_rate_cps = values[18:23]
    valid, present = _axes(axes, *rates)
    accel_valid, accel_present = _axes(accel_axes, *accels)
    return CompImu(
        seq, t_s, rates, accels, valid, present, accel_valid, accel_present, values[6:12], values[12:18],
        tuple(bool(covered & (1 << i if i < 3 else 0x10 << (i - 3))) for i in range(6)), temp_c, temp_rate_cps,
        values[23:29],
    )  # fmt: skip


def f32(value: float) -> float:
    """`value` as float32 can carry it: beyond its range, infinity of the same sign (never OverflowError)."""
    return value if not abs(value) > F32_MAX else math.copysign(math.inf, value)


def _pack(layout: struct.Struct, *values: float) -> bytes:
    try:
        return layout.pack(*values)
    except OverflowError:  # a float beyond float32's range: rare, so the check is not paid per frame
        return layout.pack(*(f32(value) if isinstance(value, float) else value for value in values))


def _rates(values: Sequence[float] | None) -> Axes3:
    return (NAN, NAN, NAN) if values is None else (values[0], values[1], values[2])
