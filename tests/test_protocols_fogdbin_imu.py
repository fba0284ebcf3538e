"""fogd's IMU frame (type 04): six channels and a temperature in one frame, round trips for any values, re-encoding
with compensated gyros and accelerometers, found whole in garbage."""

import math
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fogd.protocols import Frame, FrameError
from fogd.protocols.crc import crc16_ccitt_false
from fogd.protocols.fogdbin import FRAME_LENGTHS, TYPE_IMU, FogdProtocol
from fogd.protocols.lexer import Lexer

FOGD = FogdProtocol()
ALL = (True, True, True)


def imu(seq=1, t_s=2.5, rates=(1.0, 2.0, 3.0), accels=(0.01, -0.02, 1.0), valid=ALL, present=ALL,
        accel_valid=ALL, accel_present=ALL, temp_c=25.5) -> Frame:  # fmt: skip
    return Frame("fogd", "imu", "imu", seq, t_s, rates, valid, present, temp_c, accel_g=accels, accel_valid=accel_valid,
                 accel_present=accel_present)  # fmt: skip


def test_layout_is_the_documented_one():
    raw = FOGD.encode(imu())
    assert len(raw) == FRAME_LENGTHS[TYPE_IMU] == 46
    assert raw[:6] == bytes.fromhex("F00D 04 2E 0001")
    assert struct.unpack(">Q", raw[6:14])[0] == 2_500_000
    assert struct.unpack(">6f", raw[14:38]) == pytest.approx((1.0, 2.0, 3.0, 0.01, -0.02, 1.0), rel=1e-7)
    assert (raw[38], raw[39]) == (0x77, 0x77)
    assert struct.unpack(">f", raw[40:44])[0] == 25.5
    assert crc16_ccitt_false(raw[:-2]) == struct.unpack(">H", raw[-2:])[0]


def test_accel_axes_byte_marks_invalid_and_absent_accelerometers():
    raw = FOGD.encode(imu(accels=(0.0, math.nan, 1.0), accel_valid=(False, True, True), accel_present=(True, True, False)))
    frame = FOGD.decode(raw)
    assert raw[39] == 0x32  # x present not valid, y present valid (then NaN), z absent
    assert frame.accel_valid == (False, False, False) and frame.accel_present == (True, True, False)
    assert frame.axis_valid == ALL


finite32 = st.floats(width=32, allow_nan=False, allow_infinity=False)
masks = st.tuples(st.booleans(), st.booleans(), st.booleans())


@settings(max_examples=200)
@given(rates=st.tuples(finite32, finite32, finite32), accels=st.tuples(finite32, finite32, finite32),
       valid=masks, present=masks, accel_valid=masks, accel_present=masks, seq=st.integers(0, 65535),
       time_us=st.integers(0, 2**53), temp_c=finite32)  # fmt: skip
def test_any_finite_imu_frame_round_trips(rates, accels, valid, present, accel_valid, accel_present, seq, time_us, temp_c):
    raw = FOGD.encode(imu(seq, time_us / 1e6, rates, accels, valid, present, accel_valid, accel_present, temp_c))
    frame = FOGD.decode(raw)
    assert (frame.kind, frame.seq, frame.rate_dph, frame.accel_g, frame.temp_c) == ("imu", seq, rates, accels, temp_c)
    assert frame.axis_valid == tuple(v and p for v, p in zip(valid, present))
    assert frame.accel_valid == tuple(v and p for v, p in zip(accel_valid, accel_present))
    assert (frame.axis_present, frame.accel_present) == (present, accel_present)
    assert FOGD.encode(frame) == raw
    assert FOGD.reencode(frame, frame.rate_dph, frame.accel_g) == raw


def test_reencode_replaces_compensated_valid_gyros_and_accelerometers_only():
    frame = FOGD.decode(FOGD.encode(imu(accel_valid=(True, False, True))))
    out = FogdProtocol(comp_axes=(2,), comp_accel_axes=(1, 2)).reencode(frame, (9.0, 9.0, 2.5), (7.0, 7.0, 0.5))
    decoded = FOGD.decode(out)
    assert decoded.rate_dph == (1.0, 2.0, 2.5)
    assert decoded.accel_g == (frame.accel_g[0], frame.accel_g[1], 0.5)
    assert FOGD.reencode(frame, (1.0, 2.0, 3.0)) == frame.raw  # no accel_g: accelerometers kept


def test_a_bad_crc_is_refused_and_imu_frames_resync_after_garbage():
    raw = bytearray(FOGD.encode(imu()))
    raw[20] ^= 0x10
    with pytest.raises(FrameError):
        FOGD.decode(bytes(raw))
    frames = [FOGD.encode(imu(seq)) for seq in range(5)]
    lexer = Lexer(FOGD)
    got = lexer.feed(b"\xf0\x0d\x04\x2e" + frames[0][:20] + b"".join(frames) + b"\xf0") + lexer.flush()
    assert [frame.raw for frame in got] == frames
    assert lexer.counters.frames_ok == 5
