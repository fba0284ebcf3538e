"""fogd-record's multi-channel rows (in process, from decoded frames) and the emulator's IMU frames from runs that
lack some channels."""

import io
import math

import numpy as np
import pytest
from test_emulator import stream

from fogd.core.columns import CHANNELS
from fogd.core.runio import read_run
from fogd.errors import UsageError
from fogd.protocols import get
from fogd.protocols.base import ALL_AXES, Frame
from fogd.protocols.lexer import Lexer
from fogd.serving.recorder import Recorder, chosen_channels
from fogd.simulation.emulator import Emulator, RunSource

KVH = get("kvh-a")


def imu_frame(seq: int, *, gyro_valid=ALL_AXES, accel_valid=ALL_AXES, temp_c: float = 21.0) -> Frame:
    raw = KVH.encode(Frame("kvh-a", "imu", "A", seq, None, (1.0 + seq, 2.0, 3.0), gyro_valid, ALL_AXES, temp_c,
                           accel_g=(0.01, 0.02, 1.0 + seq / 1000), accel_valid=accel_valid, accel_present=ALL_AXES))  # fmt: skip
    return KVH.decode(raw)


def test_rows_hold_every_channel_and_nan_where_a_frame_marks_one_invalid():
    out = io.StringIO()
    recorder = Recorder(out, 2, 100.0, channels=list(CHANNELS))
    frames = [imu_frame(0), imu_frame(1, gyro_valid=(True, False, True)), imu_frame(2, accel_valid=(True, True, False))]
    recorder.write((frames, [0.0, 0.01, 0.02]))
    lines = (recorder.header() + out.getvalue()).splitlines()
    assert lines[0] == "t_s," + ",".join(CHANNELS) + ",temp_c"
    rows = [[float(value) for value in line.split(",")] for line in lines[1:]]
    assert [row[0] for row in rows] == [0.0, 0.01, 0.02]  # Format A has no clock: count / rate
    assert rows[0][1:] == [*frames[0].rate_dph, *frames[0].accel_g, 21.0]
    assert math.isnan(rows[1][2]) and rows[1][1] == frames[1].rate_dph[0]
    assert math.isnan(rows[2][6]) and rows[2][5] == frames[2].accel_g[1]
    assert recorder.rows == 3


def test_decimated_rows_are_means_of_every_channel():
    out = io.StringIO()
    recorder = Recorder(out, 2, 100.0, decimate=2, channels=["rate_x_dph", "accel_z_g"])
    frames = [imu_frame(seq) for seq in range(5)]
    recorder.write((frames[:3], [0.0] * 3))
    recorder.write((frames[3:], [0.0] * 2))
    rows = [[float(value) for value in line.split(",")] for line in out.getvalue().splitlines()]
    assert len(rows) == 2  # the fifth sample waits for a partner that never comes
    for row, pair in zip(rows, (frames[0:2], frames[2:4]), strict=True):
        assert row[1] == pytest.approx(np.mean([frame.rate_dph[0] for frame in pair]))
        assert row[2] == pytest.approx(np.mean([frame.accel_g[2] for frame in pair]))


def test_chosen_channels_follow_what_the_protocol_carries():
    assert chosen_channels("all", KVH) == list(CHANNELS)
    assert chosen_channels("all", get("fogd")) == list(CHANNELS)  # IMU frames (type 04)
    assert chosen_channels("all", get("ascii")) == ["rate_z_dph"]
    assert chosen_channels("accel_z_g, rate_x_dph", KVH) == ["rate_x_dph", "accel_z_g"]  # file order, not typed order
    with pytest.raises(UsageError):
        chosen_channels("rate_x_dph", get("ascii"))


def test_a_run_without_accelerometers_streams_kvh_frames_with_zero_accels_and_its_gyros(tmp_path):
    run_csv = tmp_path / "gyros.csv"
    rows = 50
    rate = np.arange(rows, dtype=np.float64)
    table = np.column_stack([np.arange(rows) / 100.0, rate * 10.0, rate * -5.0, np.full(rows, 30.0)])
    np.savetxt(run_csv, table, delimiter=",", header="t_s,rate_x_dph,rate_z_dph,temp_c", comments="", fmt="%.17g")
    source = RunSource(read_run(run_csv))
    assert source.imu
    lexer = Lexer(KVH)
    frames = lexer.feed(stream(Emulator(source, "kvh-a", speed=None))) + lexer.flush()
    assert len(frames) == rows
    x = np.array([frame.rate_dph[0] for frame in frames])
    np.testing.assert_allclose(x, rate * 10.0, rtol=1e-7)
    assert all(frame.rate_dph[1] == 0.0 for frame in frames)  # a gyro the run lacks reads zero, as before
    assert all(frame.accel_g == (0.0, 0.0, 0.0) and frame.accel_valid == ALL_AXES for frame in frames)
