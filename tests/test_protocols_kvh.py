"""KVH Format A/B/C and BIT frames, the CRC-32/MPEG-2 they use, and the protocol registry."""

import math
import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fogd import protocols
from fogd.errors import ConfigError, UsageError
from fogd.protocols import Frame, FrameError
from fogd.protocols.crc import crc32_mpeg2, crc32_mpeg2_ok
from fogd.protocols.kvh import KvhProtocol, bit_reply

# Both vectors and their decoded values are KVH's real captures, as listed in docs/reference/wire-formats.md.
VECTOR_1 = bytes.fromhex("FE81FF55 37A96A6E 38586C1F B75BF862 BF803E78 BB650D28 3B0A37AC 77 3D 0028 4BFA34D8")
VECTOR_2 = bytes.fromhex("FE81FF55 B606D81E B6C4940F 36D95A83 3C61AD86 3BE5D086 3F7FDCD4 77 72 0026 C0F2D540")
VECTORS = [
    (VECTOR_1, (2.0196e-05, 5.1599e-05, -1.3111e-05), 61, 40, 0x4BFA34D8),
    (VECTOR_2, (-2.0093e-06, -5.8585e-06, 6.4776e-06), 114, 38, 0xC0F2D540),
]
DPH_PER_RAD_S = 206264.80624709636  # 180 / pi * 3600, written out
KVH = KvhProtocol()


def crc32_mpeg2_bitwise(data: bytes) -> int:
    """The textbook bit-at-a-time CRC-32/MPEG-2, independent of the implementation under test."""
    crc = 0xFFFFFFFF
    for byte in data:
        crc ^= byte << 24
        for _ in range(8):
            crc = ((crc << 1) ^ 0x04C11DB7) & 0xFFFFFFFF if crc & 0x80000000 else (crc << 1) & 0xFFFFFFFF
    return crc


def with_crc(body: bytes) -> bytes:
    return body + struct.pack(">I", crc32_mpeg2_bitwise(body))


def test_registry_names_and_unknown_name():
    assert protocols.names() == ["kvh-a", "fogd", "ascii"]
    assert isinstance(protocols.get("kvh-a"), KvhProtocol)
    with pytest.raises(UsageError, match="kvh-a, fogd, ascii") as error:
        protocols.get("nmea")
    assert "\n" not in str(error.value)


def test_registry_rejects_bad_options():
    with pytest.raises(UsageError):
        protocols.get("kvh-a", baud=9600)
    with pytest.raises(ConfigError, match="rate_hz"):
        protocols.get("kvh-a", rotfmt="delta")
    with pytest.raises(ConfigError):
        protocols.get("kvh-a", temp_unit="K")


def test_crc32_mpeg2_check_value():
    assert crc32_mpeg2(b"123456789") == 0x0376E6E7


@given(st.binary(max_size=64))
def test_crc32_mpeg2_matches_bitwise_reference(data):
    assert crc32_mpeg2(data) == crc32_mpeg2_bitwise(data)
    assert crc32_mpeg2_ok(data + struct.pack(">I", crc32_mpeg2_bitwise(data)))


@given(st.binary(min_size=1, max_size=64), st.data())
def test_any_single_bit_flip_fails_the_fast_crc_check(data, draw):
    frame = bytearray(data + struct.pack(">I", crc32_mpeg2_bitwise(data)))
    bit = draw.draw(st.integers(0, 8 * len(frame) - 1))
    frame[bit // 8] ^= 1 << (bit % 8)
    assert not crc32_mpeg2_ok(bytes(frame))
    assert crc32_mpeg2(bytes(frame[:-4])) != int.from_bytes(frame[-4:], "big")


@pytest.mark.parametrize(("raw", "gyro_rad_s", "seq", "temp_c", "crc"), VECTORS)
def test_real_vectors_decode_to_documented_values(raw, gyro_rad_s, seq, temp_c, crc):
    assert len(raw) == 36
    assert crc32_mpeg2(raw[:32]) == crc == struct.unpack(">I", raw[32:])[0]
    assert crc32_mpeg2(raw) == 0
    frame = KVH.decode(raw)
    assert (frame.protocol, frame.kind, frame.message) == ("kvh-a", "imu", "A")
    for axis in range(3):
        assert frame.rate_dph[axis] == pytest.approx(gyro_rad_s[axis] * DPH_PER_RAD_S, rel=1e-4)
    assert frame.axis_valid == frame.axis_present == (True, True, True)
    assert frame.seq == seq
    assert frame.temp_c == temp_c
    assert frame.t_s is None
    assert frame.raw == raw


def test_bad_crc_raises():
    corrupted = bytearray(VECTOR_1)
    corrupted[10] ^= 0x04
    with pytest.raises(FrameError) as error:
        KVH.decode(bytes(corrupted))
    assert error.value.counter == "bad_crc"


def test_status_bits_and_nan_make_axes_invalid():
    body = bytearray(VECTOR_1[:32])
    body[28] = 0x75  # gyro Y status bit cleared
    body[12:16] = struct.pack(">f", math.nan)  # gyro Z NaN with its status bit set
    frame = KVH.decode(with_crc(bytes(body)))
    assert frame.axis_valid == (True, False, False)


def test_fahrenheit_temperature_units():
    body = bytearray(VECTOR_1[:32])
    body[30:32] = struct.pack(">h", 104)
    frame = KvhProtocol(temp_unit="F").decode(with_crc(bytes(body)))
    assert frame.temp_c == pytest.approx(40.0)


def test_delta_and_degree_rotation_formats():
    delta = KvhProtocol(rotfmt="delta", rate_hz=1000.0).decode(VECTOR_1)
    assert delta.rate_dph[0] == pytest.approx(2.0196e-05 * 1000.0 * DPH_PER_RAD_S, rel=1e-4)
    degrees = KvhProtocol(angle_unit="deg").decode(VECTOR_1)
    assert degrees.rate_dph[0] == pytest.approx(2.0196e-05 * 3600.0, rel=1e-4)


def test_format_b_decodes_time_and_temperature():
    body = struct.pack(">4s6fIBBh", b"\xfe\x81\xff\x56", 1e-4, 2e-4, 3e-4, 0, 0, 1, 1_234_567, 0x07, 5, -12)
    frame = KVH.decode(with_crc(body))
    assert len(frame.raw) == 40
    assert (frame.kind, frame.message, frame.seq, frame.temp_c) == ("imu", "B", 5, -12.0)
    assert frame.t_s == pytest.approx(1.234567)
    assert frame.rate_dph[2] == pytest.approx(3e-4 * DPH_PER_RAD_S, rel=1e-6)


def test_format_c_carries_sub_degree_temperature_every_fourth_frame():
    temp_frame = KVH.decode(with_crc(struct.pack(">4s7fBB", b"\xfe\x81\xff\x57", 1e-4, 0, 0, 0, 0, 1, 25.375, 0x77, 8)))
    assert (temp_frame.kind, temp_frame.message, temp_frame.temp_c) == ("imu", "C", 25.375)
    mag_frame = KVH.decode(with_crc(struct.pack(">4s7fBB", b"\xfe\x81\xff\x57", 1e-4, 0, 0, 0, 0, 1, 0.31, 0x77, 9)))
    assert (mag_frame.kind, mag_frame.temp_c, len(mag_frame.raw)) == ("rate", None, 38)


def test_bit_replies_are_other_frames_with_a_sum_checksum():
    short = bit_reply(bytes([0x7F] * 6))
    extended = bit_reply(bytes([0x7F] * 8))
    assert (len(short), len(extended)) == (11, 13)
    assert short[-1] == sum(short[:-1]) & 0xFF
    assert (KVH.decode(short).kind, KVH.decode(short).message) == ("other", "BIT")
    assert KVH.decode(extended).message == "BIT2"
    with pytest.raises(FrameError):
        KVH.decode(short[:-1] + bytes([short[-1] ^ 1]))


def test_reencode_changes_only_the_compensated_valid_axes():
    frame = KvhProtocol().decode(VECTOR_1)
    out = KvhProtocol(comp_axes=[2]).reencode(frame, (1.0, 2.0, 3600.0))
    assert out[:12] == VECTOR_1[:12] and out[16:32] == VECTOR_1[16:32]
    assert struct.unpack(">f", out[12:16])[0] == pytest.approx(3600.0 / DPH_PER_RAD_S, rel=1e-7)
    assert crc32_mpeg2(out) == 0
    body = bytearray(VECTOR_1[:32])
    body[28] = 0x73  # gyro Z invalid: never overwritten as if it had been compensated
    invalid_z = KVH.decode(with_crc(bytes(body)))
    assert KVH.reencode(invalid_z, (1.0, 2.0, 3.0))[12:16] == VECTOR_1[12:16]
    assert KvhProtocol(comp_axes=[2], comp_accel_axes=[]).reencode(invalid_z, (1.0, 2.0, 3.0))[12:16] == VECTOR_1[12:16]


@pytest.mark.parametrize("comp_axes", [[2], [0, 1, 2]])
def test_a_compensated_rate_beyond_float32_goes_out_as_infinity_with_a_good_crc(comp_axes):
    """A rate near float32's limit, compensated past it: the wire carries +-inf (what a decoder reads as
    invalid), the other axes as they were, and the CRC still checks; never an exception in the loop."""
    frame = KVH.decode(VECTOR_1)
    rates = list(frame.rate_dph)
    rates[2] = 1e39 * DPH_PER_RAD_S
    out = KvhProtocol(comp_axes=comp_axes, comp_accel_axes=[]).reencode(frame, rates)  # as a one-channel model plans it
    assert struct.unpack(">f", out[12:16])[0] == math.inf
    assert out[4:12] == (VECTOR_1[4:12] if comp_axes == [2] else struct.pack(">2f", *(r / DPH_PER_RAD_S for r in rates[:2])))
    assert crc32_mpeg2(out) == 0


def test_reencode_with_unchanged_rates_gives_the_input_back():
    for raw, *_ in VECTORS:
        frame = KVH.decode(raw)
        assert KVH.reencode(frame, frame.rate_dph) == raw


rates = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False)


@given(
    rate_dph=st.tuples(rates, rates, rates),
    valid=st.tuples(st.booleans(), st.booleans(), st.booleans()),
    seq=st.integers(0, 127),
    temp_c=st.integers(-40, 85),
    message=st.sampled_from(["A", "B", "C"]),
    time_us=st.integers(0, 2**32 - 1),
)
def test_encode_decode_round_trip(rate_dph, valid, seq, temp_c, message, time_us):
    record = Frame("kvh-a", "imu", message, seq, time_us / 1e6, rate_dph, valid, (True, True, True), float(temp_c))
    raw = KVH.encode(record)
    assert crc32_mpeg2(raw) == 0
    frame = KVH.decode(raw)
    assert (frame.message, frame.seq, frame.axis_valid) == (message, seq, valid)
    for axis in range(3):
        assert frame.rate_dph[axis] == pytest.approx(rate_dph[axis], rel=1e-7, abs=1e-30)
    assert frame.temp_c == (None if message == "C" and seq % 4 else temp_c)
    assert frame.t_s == (pytest.approx(time_us / 1e6, abs=1e-9) if message == "B" else None)


@pytest.mark.parametrize("position", range(6))
@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_the_fast_path_marks_any_non_finite_value_as_decode_does(position, value):
    """Every status bit set and one gyro or accelerometer NaN or infinite: the fast path's one-expression
    finiteness check must send the frame the way decode does (that axis invalid), whichever of the six it is.
    The property test below rarely draws a fully valid status with a non-finite value, so each is named here."""
    floats = [1.5, -2.25, 3.0, 0.5, -0.125, 1.0]
    floats[position] = value
    body = b"\xfe\x81\xff\x55" + struct.pack(">3f3fBBh", *floats, 0xFF, 7, 25)
    raw = body + struct.pack(">I", crc32_mpeg2(body))
    frame, length = KVH.decode_fast(raw, 0)
    assert length == 36
    assert repr(frame) == repr(KVH.decode(raw))
    valid = frame.axis_valid if position < 3 else frame.accel_valid
    assert valid[position % 3] is False and sum(valid) == 2


@given(
    floats=st.lists(st.floats(width=32), min_size=6, max_size=6),
    status=st.integers(0, 255),
    seq=st.integers(0, 255),
    temp=st.integers(-32768, 32767),
    flip=st.one_of(st.none(), st.integers(0, 36 * 8 - 1)),
    before=st.binary(max_size=3),
    options=st.sampled_from([{}, {"temp_unit": "F"}, {"rotfmt": "delta", "rate_hz": 1000.0}, {"linfmt": "delta", "rate_hz": 100.0}]),
)
def test_the_lexers_fast_path_decodes_as_decode(floats, status, seq, temp, flip, before, options):
    """KvhProtocol.decode_fast (the lexer's Format A path) gives decode's frame, field for field, or None where
    decode would refuse the bytes (a flipped bit, another header): never a different frame."""
    protocol = KvhProtocol(**options)
    body = b"\xfe\x81\xff\x55" + struct.pack(">3f3fBBh", *floats, status, seq, temp)
    raw = bytearray(body + struct.pack(">I", crc32_mpeg2(body)))
    if flip is not None:
        raw[flip // 8] ^= 1 << (flip % 8)
    buf = before + bytes(raw)
    got = protocol.decode_fast(buf, len(before))
    try:
        want = protocol.decode(bytes(raw))
    except (FrameError, ValueError):
        assert got is None
        return
    if got is None:
        assert raw[:4] != b"\xfe\x81\xff\x55"
        return
    frame, length = got
    assert length == 36
    assert repr(frame) == repr(want)  # every field, NaN included
