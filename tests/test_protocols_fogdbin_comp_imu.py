"""fogd's compensated-IMU frame (type 05, the daemon's `fogd` output for a multi-channel model): 111 bytes, every
field round-trips through float32, the lexer frames it, a bad CRC is refused, and it decodes as a `comp` frame."""

from __future__ import annotations

import math

import pytest

from fogd.protocols import get
from fogd.protocols.base import FrameError
from fogd.protocols.fogdbin import (
    FRAME_LENGTHS,
    TYPE_COMP_IMU,
    CompImu,
    decode_comp_imu,
    encode_comp_imu,
)
from fogd.protocols.lexer import Lexer

ALL = (True, True, True)


def record(seq: int = 7, **change) -> CompImu:
    fields = dict(
        seq=seq, t_s=2.5, rate_dph=(1.5, -2.25, 3.0), accel_g=(0.0, 0.5, 1.0), axis_valid=(True, False, True),
        axis_present=ALL, accel_valid=ALL, accel_present=ALL, comp=(0.25, 0.0, -0.5, 0.125, 0.0, 0.0625),
        compensated=(1.25, -2.25, 3.5, -0.125, 0.5, 0.9375), covered=(True, False, True, True, False, True),
        temp_c=31.5, temp_rate_cps=0.015625, flags=(1, 0, 8, 2, 0, 32),
    )  # fmt: skip
    fields.update(change)
    return CompImu(**fields)


def test_a_compensated_imu_frame_round_trips_every_field():
    raw = encode_comp_imu(record())
    assert len(raw) == FRAME_LENGTHS[TYPE_COMP_IMU] == 111 and raw[2] == TYPE_COMP_IMU
    assert decode_comp_imu(raw) == record(axis_valid=(True, False, True))  # every value is float32-exact


def test_it_decodes_as_a_comp_frame_with_the_gyros_and_the_flags_together():
    frame = get("fogd").decode(encode_comp_imu(record()))
    assert (frame.kind, frame.message, frame.seq, frame.t_s) == ("comp", "comp_imu", 7, 2.5)
    assert frame.comp_dph == (0.25, 0.0, -0.5) and frame.rate_comp_dph == (1.25, -2.25, 3.5)
    assert frame.accel_g == (0.0, 0.5, 1.0) and frame.flags == 1 | 8 | 2 | 32 and frame.temp_c == 31.5


def test_the_lexer_frames_it_among_other_fogd_frames_and_refuses_a_bad_crc():
    good = [encode_comp_imu(record(seq)) for seq in range(3)]
    damaged = bytearray(good[1])
    damaged[50] ^= 0x10
    lexer = Lexer(get("fogd"))
    frames = lexer.feed(good[0] + bytes(damaged) + good[2]) + lexer.flush()
    assert [frame.seq for frame in frames] == [0, 2] and lexer.counters.bad_crc == 1
    with pytest.raises(FrameError):
        decode_comp_imu(bytes(damaged))


def test_values_beyond_float32_become_infinity_rather_than_failing():
    raw = encode_comp_imu(record(compensated=(1e39, 0.0, 0.0, 0.0, 0.0, -1e39)))
    decoded = decode_comp_imu(raw)
    assert decoded.compensated[0] == math.inf and decoded.compensated[5] == -math.inf
