"""fogd's binary frames: CRC-16/CCITT-FALSE, the documented byte layout, round trips and re-encoding."""

import math
import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fogd.core.flags import Flag
from fogd.protocols import Frame, FrameError, get
from fogd.protocols.crc import crc16_ccitt_false, crc16_ccitt_false_ok
from fogd.protocols.fogdbin import FogdProtocol

FOGD = FogdProtocol()


def crc16_bitwise(data: bytes) -> int:
    """The textbook bit-at-a-time CRC-16/CCITT-FALSE, independent of the implementation under test."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def with_crc(body: bytes) -> bytes:
    return body + struct.pack(">H", crc16_bitwise(body))


def test_crc16_check_value():
    assert crc16_ccitt_false(b"123456789") == 0x29B1


@given(st.binary(max_size=64))
def test_crc16_matches_bitwise_reference(data):
    assert crc16_ccitt_false(data) == crc16_bitwise(data)
    assert crc16_ccitt_false_ok(data + struct.pack(">H", crc16_bitwise(data)))


def test_rate_frame_built_from_the_documented_byte_table():
    # docs/reference/wire-formats.md: F0 0D, type 01, length 29, seq, t_us, 3 x f32 deg/h, axes byte, CRC-16.
    body = struct.pack(">BBBBHQfffB", 0xF0, 0x0D, 0x01, 29, 513, 2_500_000, 0.0, -1.5, 12.25, 0x44)
    frame = FOGD.decode(with_crc(body))
    assert (frame.kind, frame.message, frame.seq, frame.t_s) == ("rate", "rate", 513, 2.5)
    assert frame.rate_dph == (0.0, -1.5, 12.25)
    assert frame.axis_present == (False, False, True)
    assert frame.axis_valid == (False, False, True)
    assert frame.temp_c is None


def test_temp_and_comp_frames_built_from_the_documented_byte_table():
    temp = FOGD.decode(with_crc(struct.pack(">BBBBHQf", 0xF0, 0x0D, 0x02, 20, 7, 10, 31.5)))
    assert (temp.kind, temp.seq, temp.t_s, temp.temp_c) == ("temp", 7, 1e-5, 31.5)
    comp_body = struct.pack(
        ">BBBBHQ3f3f3fBffH", 0xF0, 0x0D, 0x03, 63, 1, 0,
        1.0, 2.0, 3.0, 0.5, 0.25, 0.125, 0.5, 1.75, 2.875, 0x73, 40.5, -0.0625, Flag.WARMUP | Flag.TEMP_STALE,
    )
    comp = FOGD.decode(with_crc(comp_body))
    assert comp.kind == "comp"
    assert (comp.rate_dph, comp.comp_dph, comp.rate_comp_dph) == ((1.0, 2.0, 3.0), (0.5, 0.25, 0.125), (0.5, 1.75, 2.875))
    assert comp.axis_valid == (True, True, False) and comp.axis_present == (True, True, True)
    assert (comp.temp_c, comp.temp_rate_cps, comp.flags) == (40.5, -0.0625, Flag.WARMUP | Flag.TEMP_STALE)


def test_unknown_type_with_good_crc_is_other_and_bad_crc_raises():
    raw = with_crc(struct.pack(">BBBBHQ4s", 0xF0, 0x0D, 0x7E, 20, 3, 0, b"abcd"))
    assert FOGD.frame_length(raw, 0) == 20
    assert FOGD.decode(raw).kind == "other"
    with pytest.raises(FrameError) as error:
        FOGD.decode(raw[:-1] + bytes([raw[-1] ^ 0x80]))
    assert error.value.counter == "bad_crc"


def test_frame_length_rejects_known_types_with_foreign_lengths():
    assert FOGD.frame_length(b"\xf0\x0d\x01\x1d", 0) == 29
    assert FOGD.frame_length(b"\xf0\x0d\x01\x1c", 0) == -1
    assert FOGD.frame_length(b"\xf0\x0d\x7e\x0f", 0) == -1
    assert FOGD.frame_length(b"\xf0\x0d\x01", 0) == 0


def test_reencode_replaces_only_valid_compensated_axes():
    rate = Frame("fogd", "rate", seq=4, t_s=1.0, rate_dph=(1.0, 2.0, 3.0), axis_valid=(True, False, True),
                 axis_present=(True, True, True))
    raw = FOGD.encode(rate)
    out = get("fogd", comp_axes=[0, 1]).reencode(FOGD.decode(raw), (10.0, 20.0, 30.0))
    assert FOGD.decode(out).rate_dph == (10.0, 2.0, 3.0)
    assert out[:14] == raw[:14] and out[18:-2] == raw[18:-2]
    temp = FOGD.decode(FOGD.encode(Frame("fogd", "temp", seq=1, t_s=0.5, temp_c=20.0)))
    assert FOGD.reencode(temp, (1.0, 1.0, 1.0)) == temp.raw


finite = st.floats(width=32, allow_nan=False, allow_infinity=False)
masks = st.tuples(st.booleans(), st.booleans(), st.booleans())
times_us = st.integers(0, 10**15)  # 31 years in us: a float64 t_s still resolves 1 us


@given(rate=st.tuples(finite, finite, finite), valid=masks, present=masks, seq=st.integers(0, 65535), time_us=times_us)
def test_rate_round_trip(rate, valid, present, seq, time_us):
    record = Frame("fogd", "rate", "rate", seq, time_us / 1e6, rate, valid, present)
    frame = FOGD.decode(FOGD.encode(record))
    assert (frame.seq, frame.rate_dph, frame.axis_present) == (seq, rate, present)
    assert frame.axis_valid == tuple(v and p for v, p in zip(valid, present))
    assert round(frame.t_s * 1e6) == time_us


@given(temp_c=st.floats(width=32), seq=st.integers(0, 65535), time_us=times_us)
def test_temp_round_trip(temp_c, seq, time_us):
    frame = FOGD.decode(FOGD.encode(Frame("fogd", "temp", "temp", seq, time_us / 1e6, temp_c=temp_c)))
    assert frame.seq == seq and round(frame.t_s * 1e6) == time_us
    assert frame.temp_c == temp_c or (math.isnan(temp_c) and math.isnan(frame.temp_c))


@given(
    rates=st.tuples(*[finite] * 9),
    valid=masks,
    temp_c=finite,
    temp_rate_cps=finite,
    flags=st.integers(0, 63),
    seq=st.integers(0, 65535),
)
def test_comp_round_trip(rates, valid, temp_c, temp_rate_cps, flags, seq):
    record = Frame("fogd", "comp", "comp", seq, 12.5, rates[0:3], valid, (True, True, True), temp_c, b"",
                   temp_rate_cps, rates[3:6], rates[6:9], flags)
    frame = FOGD.decode(FOGD.encode(record))
    assert (frame.rate_dph, frame.comp_dph, frame.rate_comp_dph) == (rates[0:3], rates[3:6], rates[6:9])
    assert (frame.axis_valid, frame.temp_c, frame.temp_rate_cps, frame.flags) == (valid, temp_c, temp_rate_cps, flags)
    assert (frame.seq, frame.t_s) == (seq, 12.5)


def test_encode_needs_a_time_and_a_known_kind():
    with pytest.raises(ValueError, match="t_s"):
        FOGD.encode(Frame("fogd", "temp", temp_c=20.0))
    with pytest.raises(ValueError, match="'other'"):  # imu became a frame type (04); 'other' has none
        FOGD.encode(Frame("fogd", "other", t_s=0.0))


def test_example_frames_in_the_docs_decode():
    rate = FOGD.decode(bytes.fromhex("F00D011D020100000000002625A07FC000007FC0000041440000445ADB".replace(" ", "")))
    assert (rate.seq, rate.t_s, rate.rate_dph[2], rate.axis_valid) == (513, 2.5, 12.25, (False, False, True))
    temp = FOGD.decode(bytes.fromhex("F00D0214000700000000002625A041FC0000C88D".replace(" ", "")))
    assert (temp.seq, temp.t_s, temp.temp_c) == (7, 2.5, 31.5)
