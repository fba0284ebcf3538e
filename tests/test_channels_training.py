"""Training an IMU's channels: the runs' temperature inputs are computed once for all the channels, and each
channel's fit is the fit of that channel alone."""

from __future__ import annotations

import numpy as np
import pytest
from imu_runs import imu_columns

from fogd.calibration import channels, features
from fogd.calibration.channels import Settings, channel_jobs, fit_channels
from fogd.calibration.models import FitOptions
from fogd.calibration.training import TrainConfig, train
from fogd.core.inputs import parse_inputs
from fogd.core.runio import Run
from fogd.errors import InputError

CHANNELS = ("rate_x_dph", "rate_z_dph", "accel_y_g")


def imu_run(profile: str, seed: int) -> Run:
    columns = imu_columns(profile, seed, channels=CHANNELS)
    extra = {name: values for name, values in columns.items() if name.startswith("true_error_")}
    channels = {name: columns[name] for name in CHANNELS}
    return Run(f"{profile}.csv", columns["t_s"], channels["rate_z_dph"], columns["temp_c"], 1.0, profile, extra, channels)


@pytest.fixture(scope="module")
def runs() -> list[Run]:
    return [imu_run("fast-ramp", 1), imu_run("cool-40-to-0", 2)]


def test_inputs_are_computed_once_and_each_channel_fits_as_alone(runs, monkeypatch):
    # the play's lag given (with the default's play@2:auto every channel chooses its own, on its own rate), and
    # the sensor's noise (chosen once for the unit otherwise: the next test)
    config = TrainConfig(method="linear", inputs=parse_inputs("temp,lags@10..3000/7,play@2:300"), fit=FitOptions(progress=False),
                         sensor_noise_c=0.01)  # fmt: skip
    settings = Settings(config, [config.inputs])
    calls = []
    batch = features.inputs_batch
    monkeypatch.setattr(features, "inputs_batch", lambda *args: calls.append(args[1]) or batch(*args))
    jobs = channel_jobs("", runs, [], None, settings)
    assert [job.channel for job in jobs] == list(CHANNELS) and len(calls) == len(runs)  # once per run
    fits = fit_channels(jobs, settings, n_jobs=1)
    assert len(calls) == len(runs)  # the channels' training took the shared inputs
    for fit in fits:
        assert fit.error is None and fit.transcript.lines[0][1] == f"\n=== {fit.channel} ==="
        alone = train([run.channel(fit.channel) for run in runs], config)
        for key in ("params", "input_scaling", "output_scaling", "domain", "reference_dph"):
            assert fit.chosen.document[key] == alone.document[key], (fit.channel, key)
        np.testing.assert_array_equal(fit.chosen.error_dph, alone.error_dph)


def test_one_channel_shares_nothing_and_a_missing_channel_is_named(runs):
    settings = Settings(TrainConfig(method="linear"), [TrainConfig().inputs])
    (job,) = channel_jobs("", runs, [], ["accel_y_g"], settings)
    assert job.inputs is None and job.runs[0].rate_dph is runs[0].channels["accel_y_g"]
    with pytest.raises(InputError, match="unit u: fast-ramp.csv has no channel accel_z_g"):
        channel_jobs("u", runs, [], ["accel_z_g"], settings)


def test_the_units_sensor_noise_is_chosen_once_on_its_clearest_channel(runs, monkeypatch):
    """The channels share one temperature sensor: its noise is chosen once, on the channel whose drift stands
    out most from its noise (here a gyro, not the accelerometer), and every channel's job carries it."""
    config = TrainConfig(method="linear", inputs=parse_inputs("temp,lags@10..3000/7,play@2:300"), fit=FitOptions(progress=False))
    chosen_on = []
    real = channels.sensor_noise_c
    monkeypatch.setattr(channels, "sensor_noise_c", lambda runs, config: chosen_on.append(runs) or real(runs, config))
    jobs = channel_jobs("", runs, [], None, Settings(config, [config.inputs]))
    (on,) = chosen_on
    ratios = {name: channels.drift_to_noise([run.channel(name) for run in runs], config.block_s) for name in CHANNELS}
    assert on[0].rate_dph is runs[0].channels[max(ratios, key=ratios.get)]
    assert max(ratios, key=ratios.get).startswith("rate_") and ratios["accel_y_g"] < max(ratios.values())
    noise_c = jobs[0].sensor_noise_c
    assert noise_c is not None and all(job.sensor_noise_c == noise_c for job in jobs)
    assert real(on, config) == noise_c
