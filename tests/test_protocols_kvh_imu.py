"""KVH frames as a whole IMU: the accelerometers decoded (real captures), their status bits, delta-velocity and
delta-angle output in either unit, re-encoding with compensated accelerations, the unit's settings replies."""

import math
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fogd import protocols
from fogd.errors import ConfigError
from fogd.protocols import Frame
from fogd.protocols.crc import crc32_mpeg2
from fogd.protocols.kvh import (
    SETTING_QUERIES,
    KvhProtocol,
    parse_reply,
    query,
    settings_from_replies,
    settings_reply,
)
from fogd.protocols.lexer import Lexer

# KVH's two real captures and the accelerations docs/reference/wire-formats.md lists for them (g).
VECTOR_1 = bytes.fromhex("FE81FF55 37A96A6E 38586C1F B75BF862 BF803E78 BB650D28 3B0A37AC 77 3D 0028 4BFA34D8")
VECTOR_2 = bytes.fromhex("FE81FF55 B606D81E B6C4940F 36D95A83 3C61AD86 3BE5D086 3F7FDCD4 77 72 0026 C0F2D540")
ACCELS = [(VECTOR_1, (-1.0019, -0.0034950, 0.0021090)), (VECTOR_2, (0.013774, 0.0070134, 0.99946))]
G_MS2 = 9.80665  # standard gravity, written out
FT = 0.3048
ALL = (True, True, True)
KVH = KvhProtocol()


def with_crc(body: bytes) -> bytes:
    return body + struct.pack(">I", crc32_mpeg2(body))


def format_a(gyro, accel, status=0x77, seq=1, temp=25) -> bytes:
    return with_crc(struct.pack(">4s3f3fBBh", b"\xfe\x81\xff\x55", *gyro, *accel, status, seq, temp))


@pytest.mark.parametrize(("raw", "accel_g"), ACCELS)
def test_real_vectors_carry_the_documented_accelerations(raw, accel_g):
    frame = KVH.decode(raw)
    assert frame.accel_g == pytest.approx(accel_g, rel=1e-4)
    assert frame.accel_valid == frame.accel_present == ALL
    assert struct.unpack(">3f", raw[16:28]) == frame.accel_g  # in g, unscaled: exactly the float32s


@pytest.mark.parametrize(("raw", "accel_g"), ACCELS)
def test_real_vectors_reencode_to_themselves_with_their_own_values(raw, accel_g):
    frame = KVH.decode(raw)
    assert KVH.reencode(frame, frame.rate_dph, frame.accel_g) == raw
    assert KVH.encode(frame) == raw


@pytest.mark.parametrize(
    ("status", "nan_axis", "valid"),
    [(0x07, None, (False, False, False)), (0x57, None, (True, False, True)), (0x37, None, (True, True, False)),
     (0x77, 1, (True, False, True)), (0x77, 2, (True, True, False))],
)  # fmt: skip
def test_accel_status_bits_and_nan_make_only_that_accel_invalid(status, nan_axis, valid):
    accel = [0.01, 0.02, 1.0]
    if nan_axis is not None:
        accel[nan_axis] = math.inf if nan_axis == 2 else math.nan
    frame = KVH.decode(format_a((1e-5, 2e-5, 3e-5), accel, status))
    assert frame.accel_valid == valid
    assert frame.axis_valid == ALL  # the gyros' own bits are untouched


def test_a_frame_without_accels_encodes_zeros_marked_valid_as_before():
    record = Frame("kvh-a", "imu", "A", 5, None, (1.0, 2.0, 3.0), (True, False, True), ALL, 30.0)
    raw = KVH.encode(record)
    assert raw[16:28] == bytes(12) and raw[28] == 0x75
    decoded = KVH.decode(raw)
    assert decoded.accel_g == (0.0, 0.0, 0.0) and decoded.accel_valid == ALL


def test_invalid_or_absent_accels_are_sent_with_their_status_bit_cleared():
    record = Frame("kvh-a", "imu", "A", 5, None, (1.0, 2.0, 3.0), ALL, ALL, 30.0,
                   accel_g=(0.1, 0.2, 1.0), accel_valid=(True, False, True), accel_present=(True, True, False))  # fmt: skip
    assert KVH.encode(record)[28] == 0x17


def test_delta_velocity_in_metres_and_feet_and_delta_angle_decode_to_g_and_deg_per_hour():
    rate_hz = 1000.0
    one_g_m = G_MS2 / rate_hz  # m/s gained in one 1 ms sample at 1 g
    raw = format_a((1e-6, 0.0, 0.0), (0.0, 0.0, one_g_m))
    frame = KvhProtocol(rotfmt="delta", linfmt="delta", rate_hz=rate_hz).decode(raw)
    assert frame.accel_g[2] == pytest.approx(1.0, rel=1e-7)
    assert frame.rate_dph[0] == pytest.approx(struct.unpack(">f", struct.pack(">f", 1e-6))[0] * rate_hz * 180 / math.pi * 3600)
    feet = format_a((0.0, 0.0, 0.0), (0.0, -G_MS2 / FT / rate_hz, 0.0))
    assert KvhProtocol(linfmt="delta", lin_unit="ft", rate_hz=rate_hz).decode(feet).accel_g[1] == pytest.approx(-1.0, rel=1e-7)
    # rotfmt alone does not change the accelerometers: they stay in g
    assert KvhProtocol(rotfmt="delta", rate_hz=rate_hz).decode(raw).accel_g[2] == pytest.approx(one_g_m, rel=1e-7)


def test_delta_settings_need_the_data_rate_and_bad_settings_are_one_line():
    for options in ({"linfmt": "delta"}, {"linfmt": "delta", "rate_hz": 0}, {"rotfmt": "delta", "rate_hz": math.inf}):
        with pytest.raises(ConfigError, match="rate_hz") as error:
            protocols.get("kvh-a", **options)
        assert "\n" not in str(error.value)
    for options in ({"linfmt": "velocity"}, {"lin_unit": "yd"}, {"comp_accel_axes": [3]}):
        with pytest.raises(ConfigError):
            protocols.get("kvh-a", **options)


def test_reencode_replaces_only_valid_accels_of_comp_accel_axes():
    raw = format_a((1e-5, 2e-5, 3e-5), (0.01, 0.02, 1.0), status=0x67)  # accel x invalid
    frame = KVH.decode(raw)
    out = KvhProtocol(comp_accel_axes=(0, 2)).reencode(frame, frame.rate_dph, (5.0, 6.0, 0.5))
    x, y, z = struct.unpack(">3f", out[16:28])
    assert (x, y, z) == (struct.unpack(">f", raw[16:20])[0], struct.unpack(">f", raw[20:24])[0], 0.5)
    assert out[:16] == raw[:16] and out[28:32] == raw[28:32] and crc32_mpeg2(out) == 0
    assert KVH.reencode(frame, frame.rate_dph) == raw  # no accel_g: the accelerometers' bytes are kept
    rate_hz = 500.0
    delta = KvhProtocol(linfmt="delta", rate_hz=rate_hz)
    out = delta.reencode(delta.decode(raw), frame.rate_dph, (0.0, 0.0, 2.0))
    assert struct.unpack(">f", out[24:28])[0] == pytest.approx(2.0 * G_MS2 / rate_hz, rel=1e-7)


finite32 = st.floats(width=32, allow_nan=False, allow_infinity=False)
status_bits = st.integers(0, 0x77).filter(lambda status: not status & 0x88)


@settings(max_examples=300)
@given(
    gyro=st.tuples(finite32, finite32, finite32),
    accel=st.tuples(finite32, finite32, finite32),
    status=status_bits,
    seq=st.integers(0, 127),
    temp=st.integers(-40, 85),
    message=st.sampled_from(["A", "B", "C"]),
    time_us=st.integers(0, 2**32 - 1),
    rotfmt=st.sampled_from(["rate", "delta"]),
    linfmt=st.sampled_from(["accel", "delta"]),
    angle_unit=st.sampled_from(["rad", "deg"]),
    lin_unit=st.sampled_from(["m", "ft"]),
    rate_hz=st.sampled_from([1.0, 100.0, 1000.0, 3600.0, 5000.0]),
)
def test_any_finite_frame_decodes_and_encodes_back_to_its_own_bytes(
    gyro, accel, status, seq, temp, message, time_us, rotfmt, linfmt, angle_unit, lin_unit, rate_hz
):
    codec = KvhProtocol(rotfmt=rotfmt, linfmt=linfmt, angle_unit=angle_unit, lin_unit=lin_unit, rate_hz=rate_hz)
    if message == "A":
        body = struct.pack(">4s3f3fBBh", b"\xfe\x81\xff\x55", *gyro, *accel, status, seq, temp)
    elif message == "B":
        body = struct.pack(">4s3f3fIBBh", b"\xfe\x81\xff\x56", *gyro, *accel, time_us, status, seq, temp)
    else:
        body = struct.pack(">4s3f3ffBB", b"\xfe\x81\xff\x57", *gyro, *accel, float(temp) if seq % 4 == 0 else 0.0, status, seq)
    raw = with_crc(body)
    frame = codec.decode(raw)
    assert frame.accel_valid == tuple(bool(status & (0x10 << axis)) for axis in range(3))
    assert frame.axis_valid == tuple(bool(status & (1 << axis)) for axis in range(3))
    if all(math.isfinite(value) for value in (*frame.rate_dph, *frame.accel_g)):  # a huge float32 x a big scale may not be
        assert codec.encode(frame) == raw
        assert codec.reencode(frame, frame.rate_dph, frame.accel_g) == raw


any_value = st.one_of(st.floats(-1e6, 1e6), st.sampled_from([4e38, -4e38, 3.4e38, math.inf, math.nan]))
axes_subsets = st.sets(st.integers(0, 2)).map(lambda axes: tuple(sorted(axes)))


@settings(max_examples=300)
@given(
    status=status_bits,
    comp_axes=axes_subsets,
    comp_accel_axes=axes_subsets,
    rates=st.tuples(any_value, any_value, any_value),
    accels=st.one_of(st.none(), st.tuples(any_value, any_value, any_value)),
)
def test_reencode_writes_each_compensated_valid_field_as_float32_and_keeps_every_other_byte(
    status, comp_axes, comp_accel_axes, rates, accels
):
    raw = format_a((1e-5, -2e-5, 3e-5), (0.01, 0.02, 1.0), status=status)
    codec = KvhProtocol(comp_axes=comp_axes, comp_accel_axes=comp_accel_axes)
    frame = codec.decode(raw)
    out = codec.reencode(frame, rates, accels)
    assert len(out) == len(raw) and crc32_mpeg2(out) == 0
    assert out[:4] == raw[:4] and out[28:-4] == raw[28:-4]
    fields = [(4 + 4 * axis, axis in comp_axes and status & (1 << axis), rates[axis] / codec.dph_per_unit)
              for axis in range(3)]  # fmt: skip
    fields += [(16 + 4 * axis, accels is not None and axis in comp_accel_axes and status & (0x10 << axis),
                accels[axis] if accels is not None else None) for axis in range(3)]  # fmt: skip
    for offset, replaced, value in fields:
        field = out[offset : offset + 4]
        if not replaced:
            assert field == raw[offset : offset + 4]
        elif math.isnan(value):
            assert math.isnan(struct.unpack(">f", field)[0])
        else:  # float32's nearest, or infinity of the same sign beyond its range
            want = value if abs(value) <= 3.4028234663852886e38 else math.copysign(math.inf, value)
            assert field == struct.pack(">f", want)


@settings(max_examples=100)
@given(
    accels=st.lists(st.tuples(finite32, finite32, finite32), min_size=1, max_size=12),
    garbage=st.lists(st.binary(max_size=40), min_size=13, max_size=13),
)
def test_imu_frames_are_found_whole_in_any_garbage(accels, garbage):
    records = [Frame("kvh-a", "imu", "A", seq, None, (1.0, 2.0, 3.0), ALL, ALL, 20.0, accel_g=accel, accel_valid=ALL,
                     accel_present=ALL) for seq, accel in enumerate(accels)]  # fmt: skip
    frames = [KVH.encode(record) for record in records]
    stream = b"".join(junk + frame for junk, frame in zip(garbage, frames)) + garbage[-1]
    lexer = Lexer(KVH)
    decoded = [frame for frame in lexer.feed(stream) + lexer.flush() if frame.kind == "imu"]
    assert [frame.accel_g for frame in decoded] == [tuple(accel) for accel in accels]
    assert [frame.seq for frame in decoded] == list(range(len(accels)))


def test_settings_replies_parse_into_protocol_options_and_back():
    configured = KvhProtocol(rotfmt="delta", linfmt="delta", lin_unit="ft", angle_unit="deg", temp_unit="F", rate_hz=1000)
    replies = [b"CONFIG,1\r\n", b"?ROTFMT\r\n"] + [settings_reply(configured, name) for name in SETTING_QUERIES]
    options = settings_from_replies(replies)
    expected = {"rotfmt": "delta", "angle_unit": "deg", "linfmt": "delta", "lin_unit": "ft", "temp_unit": "F", "rate_hz": 1000.0}
    assert options == expected
    assert protocols.get("kvh-a", **options).g_per_unit == configured.g_per_unit
    assert query("dr") == b"?DR\r\n"
    assert parse_reply("rotfmt,rate\n") == ("rotfmt", "rate")


@pytest.mark.parametrize("line", ["ROTFMT,SPIN", "DR,fast", "DR,-5", "BAUD,921600", "garbage"])
def test_a_reply_fogd_cannot_read_is_a_one_line_config_error(line):
    with pytest.raises(ConfigError) as error:
        parse_reply(line)
    assert "\n" not in str(error.value)
