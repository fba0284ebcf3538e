"""The simulated three-axis IMU: z is the single-axis gyro number for number, every other channel has its own
thermal error of the same coil states and its own noise; fogd-sim --imu writes it as a multi-channel run."""

import math
import subprocess
import sys

import numpy as np
import pytest

from fogd.core.columns import ACCEL_CHANNELS, CHANNELS, GYRO_CHANNELS, truth_column
from fogd.core.runio import read_run
from fogd.simulation import profiles
from fogd.simulation.profiles import Profile
from fogd.simulation.simulator import (
    ACCEL_ERRORS,
    EARTH_RATE_DPH,
    IMU_CHANNELS,
    SimParams,
    Simulation,
    channel_errors,
    params_for,
)

CYCLE = profiles.builtin("cycle")
SHORT = Profile("r", ((600.0, 20.0), (1800.0, 45.0), (1200.0, 45.0), (1800.0, 10.0)))


@pytest.fixture(scope="module")
def cycle_imu():
    return Simulation(CYCLE, 1.0, 1).imu_columns()


def test_z_is_the_single_axis_gyro_number_for_number():
    sim = Simulation(SHORT, 20.0, 4)
    single, imu = sim.columns(), sim.imu_columns()
    np.testing.assert_array_equal(imu["rate_z_dph"], single["rate_dph"])
    np.testing.assert_array_equal(imu[truth_column("rate_z_dph")], single["true_error_dph"])
    np.testing.assert_array_equal(imu["temp_c"], single["temp_c"])
    np.testing.assert_array_equal(imu["t_s"], single["t_s"])
    assert IMU_CHANNELS == CHANNELS


def test_rows_are_the_same_whichever_blocks_they_are_made_in():
    sim = Simulation(SHORT, 50.0, 2)
    sim.ARW_BLOCK_ROWS = 1000  # several noise blocks inside the run
    whole = sim.imu_columns()
    cuts = [0, 1, 999, 1000, 2500, 77_777, sim.rows]
    for name in (*IMU_CHANNELS, *(truth_column(channel) for channel in IMU_CHANNELS)):
        pieces = np.concatenate([sim.imu_columns(a, b)[name] for a, b in zip(cuts[:-1], cuts[1:])])
        np.testing.assert_array_equal(pieces, whole[name], err_msg=name)


def test_same_seed_same_run_and_channels_draw_their_own_noise():
    first, again, other = (Simulation(SHORT, 10.0, seed).imu_columns() for seed in (7, 7, 8))
    for channel in IMU_CHANNELS:
        np.testing.assert_array_equal(first[channel], again[channel])
        assert not np.array_equal(first[channel], other[channel])
    noise = {channel: first[channel] - first[truth_column(channel)] for channel in GYRO_CHANNELS}
    detrended = {channel: np.diff(values) for channel, values in noise.items()}
    correlation = np.corrcoef(list(detrended.values()))
    assert np.all(np.abs(correlation[np.triu_indices(3, 1)]) < 0.05)  # independent white noise per axis


def test_without_noise_each_channel_is_its_truth_plus_earth_rate_or_gravity():
    params = SimParams().without_noise()
    columns = Simulation(SHORT, 5.0, 3, params).imu_columns()
    latitude = math.radians(params.latitude_deg)
    offsets = {"rate_x_dph": EARTH_RATE_DPH * math.cos(latitude), "rate_y_dph": 0.0,
               "rate_z_dph": EARTH_RATE_DPH * math.sin(latitude), "accel_x_g": 0.0, "accel_y_g": 0.0, "accel_z_g": 1.0}  # fmt: skip
    for channel, offset in offsets.items():
        np.testing.assert_allclose(columns[channel] - columns[truth_column(channel)], offset, atol=1e-12, err_msg=channel)


def test_each_channel_is_its_own_function_of_the_coil_temperatures(cycle_imu):
    truths = {channel: cycle_imu[truth_column(channel)] for channel in IMU_CHANNELS}
    for channel, truth in truths.items():
        assert np.ptp(truth) > 0, channel
    names = list(truths)
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            # no channel is an affine function of another: a straight-line fit leaves a real residual
            slope, intercept = np.polyfit(truths[b], truths[a], 1)
            residual = truths[a] - (slope * truths[b] + intercept)
            assert residual.std() > 0.1 * truths[a].std(), (a, b)
    signs = {np.sign(np.corrcoef(truths["rate_z_dph"], truths[channel])[0, 1]) for channel in names}
    assert signs == {-1.0, 1.0}  # some channels drift the other way


def test_accelerometers_read_gravity_on_z_and_errors_of_a_few_milli_g(cycle_imu):
    assert np.mean(cycle_imu["accel_z_g"]) == pytest.approx(1.0, abs=5e-3)
    for channel in ACCEL_CHANNELS:
        span = np.ptp(cycle_imu[truth_column(channel)])
        assert 1e-4 < span < 1e-2, channel
    for channel in GYRO_CHANNELS:
        assert 0.01 < np.ptp(cycle_imu[truth_column(channel)]) < 1.0, channel


def test_accelerometer_white_noise_has_the_configured_level():
    params = SimParams(accel_noise_g=1e-4, accel_turn_on_bias_g=0.0)
    rate_hz = 100.0
    columns = Simulation(Profile("soak", ((600.0, 25.0),)), rate_hz, 5, params).imu_columns()
    noise = columns["accel_y_g"] - columns[truth_column("accel_y_g")]
    assert noise.std() == pytest.approx(1e-4 * math.sqrt(rate_hz), rel=0.05)


def test_x_and_y_gyros_scale_with_the_single_axis_terms():
    loud = channel_errors(SimParams(shupe_rate_dph_per_cps=12.0))
    base = channel_errors(SimParams())
    for channel in ("rate_x_dph", "rate_y_dph"):
        assert loud[channel].rate_per_cps == pytest.approx(2 * base[channel].rate_per_cps)
    assert base["rate_x_dph"].rate_per_cps < 0 < base["rate_y_dph"].rate_per_cps


def test_every_channels_play_follows_the_gyros_hysteresis():
    default = channel_errors(SimParams())
    assert {channel: default[channel].hysteresis for channel in ACCEL_CHANNELS} == {
        channel: error.hysteresis for channel, error in ACCEL_ERRORS.items()}  # fmt: skip
    assert all(error.hysteresis == 0.0 for error in channel_errors(SimParams(hysteresis_dph=0.0)).values())
    doubled = channel_errors(SimParams(hysteresis_dph=2 * SimParams().hysteresis_dph))
    for channel in IMU_CHANNELS:
        assert doubled[channel].hysteresis == pytest.approx(2 * default[channel].hysteresis), channel


def _block_floor(values: np.ndarray, rate_hz: float) -> float:
    """The std of 100 s block means after 600 s, as tools/accuracy_table.py divides by."""
    rows, skip = int(100 * rate_hz), int(600 * rate_hz)
    usable = (values.size - skip) // rows * rows
    return float(values[skip : skip + usable].reshape(-1, rows).mean(axis=1).std())


def test_the_navigation_grade_keeps_every_channels_play_near_its_noise_floor_as_the_gyros():
    """The navigation grade keeps the play hysteresis (which no finite thermal memory describes) near the gyro's
    noise floor; an accelerometer's play must stand no further above its own floor than the gyro's does."""
    rate_hz = 10.0
    params = params_for("navigation")
    columns = Simulation(profiles.builtin("fast-ramp"), rate_hz, 1, params).imu_columns()
    errors = channel_errors(params)
    ratios = {channel: errors[channel].hysteresis / _block_floor(columns[channel] - columns[truth_column(channel)], rate_hz)
              for channel in IMU_CHANNELS}  # fmt: skip
    assert 0.5 < ratios["rate_z_dph"] < 2.0, ratios
    for channel in ACCEL_CHANNELS:
        assert ratios[channel] <= 2.0 * ratios["rate_z_dph"], ratios


def test_fogd_sim_imu_writes_a_multi_channel_run(tmp_path):
    imu_csv, single_csv = tmp_path / "imu.csv", tmp_path / "one.csv"
    for path, extra in ((imu_csv, ["--imu"]), (single_csv, [])):
        result = subprocess.run(
            [sys.executable, "-m", "fogd.cli.sim", "--profile", "fast-ramp", "--rate-hz", "2", "--seed", "9", "-o", str(path), *extra],
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        assert result.returncode == 0, result.stderr
    header = next(line for line in imu_csv.read_text().splitlines() if not line.startswith("#"))
    assert header.split(",") == ["t_s", *CHANNELS, "temp_c", *(truth_column(channel) for channel in CHANNELS)]
    imu, single = read_run(imu_csv), read_run(single_csv)
    assert list(imu.channels) == list(CHANNELS)
    np.testing.assert_array_equal(imu.channels["rate_z_dph"], single.rate_dph)
    np.testing.assert_array_equal(imu.channel("rate_z_dph").extra["true_error_dph"], single.extra["true_error_dph"])
    accel_z = imu.channel("accel_z_g")
    assert np.mean(accel_z.rate_dph) == pytest.approx(1.0, abs=5e-3)
    assert "true_error_dph" in accel_z.extra  # each channel's own truth, as runio names it
