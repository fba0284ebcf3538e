"""tools/accuracy_table.py --imu, shrunk (two calibration runs, one held out, 1 Hz, a tiny swarm): its z gyro is the
single-axis table's gyro, its ladder climbed and replayed to the same figure and the same choice; every channel gets its table, the
accelerometers' in g."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np
import pytest

from fogd.calibration.channels import Settings, channel_jobs
from fogd.calibration.models import FitOptions
from fogd.calibration.replay import replay, replay_table
from fogd.calibration.ladder import climb
from fogd.calibration.training import TrainConfig
from fogd.core.columns import CHANNELS
from fogd.core.inputs import DEFAULT_INPUTS_TEXT, parse_inputs
from fogd.simulation.simulator import params_for

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tools"))
import accuracy_table  # noqa: E402

TINY = {"particles": 3, "iterations": 2}


@pytest.fixture
def shrunk(monkeypatch):
    """The tool with short runs and a tiny swarm, whatever --quick asks for."""
    monkeypatch.setattr(accuracy_table, "CALIBRATION", ("fast-ramp", "cool-40-to-0"))
    monkeypatch.setattr(accuracy_table, "HELD_OUT", ("fast-cycle",))
    monkeypatch.setattr(accuracy_table, "FitOptions", lambda **kw: FitOptions(**{**kw, **TINY}))
    return argparse.Namespace(rate_hz=1.0, seed=1, jobs=1, quick=True, hysteresis_dph=None, hysteresis_deadband_c=None,
                              default_inputs=None, fit_temperature="smoothed", coil_mix="auto", rate_prior="smooth",
                              physics=None, calibration=None)


def test_the_imu_z_gyro_is_the_single_axis_gyro():
    params = params_for("navigation")
    imu = accuracy_table.simulated_imu_run("fast-ramp", 3, 1.0, params).channel("rate_z_dph")
    single = accuracy_table.simulated_run("fast-ramp", 3, 1.0, params)
    for name in ("t_s", "rate_dph", "temp_c"):
        np.testing.assert_array_equal(getattr(imu, name), getattr(single, name), err_msg=name)
    np.testing.assert_array_equal(imu.extra["true_error_dph"], single.extra["true_error_dph"])


def test_every_channel_is_tabled_and_z_as_the_single_axis_table_trains_it(shrunk, capsys):
    rows = accuracy_table.evaluate_imu(shrunk, "lumped", 0.0625, 4.0)
    assert list(rows) == list(CHANNELS)
    params = params_for("navigation", "lumped", sensor_resolution_c=0.0625, sensor_rate_hz=4.0)
    runs = [accuracy_table.simulated_run(name, 1 + i, 1.0, params) for i, name in enumerate(accuracy_table.CALIBRATION)]
    held_out = accuracy_table.simulated_run("fast-cycle", 101, 1.0, params)
    config = TrainConfig(method="ladder", inputs=parse_inputs(DEFAULT_INPUTS_TEXT),
                         fit=FitOptions(seed=1, progress=False, patience=10, **TINY))  # fmt: skip
    # the unit's fine-sensor noise, chosen once for all its channels (fogd.calibration.channels), as z trains with it
    imu_runs = [accuracy_table.simulated_imu_run(name, 1 + i, 1.0, params) for i, name in enumerate(accuracy_table.CALIBRATION)]
    (noise_c,) = {job.sensor_noise_c for job in channel_jobs("", imu_runs, [], None, Settings(config, [config.inputs]))}
    ladder = climb(runs, dataclasses.replace(config, sensor_noise_c=noise_c))
    alone = replay_table(held_out, replay(ladder.trained.model, held_out), 100.0)
    (ratio, _), = rows["rate_z_dph"][accuracy_table.LADDER]
    assert ratio == pytest.approx(alone.after.rmse_dph / alone.best.rmse_dph, rel=1e-9)
    assert rows["rate_z_dph"]["_ladder_choice"] == [ladder.chosen.rung.name]
    for channel in CHANNELS:  # the accelerometers' floors are in g (micro-g), the gyros' in deg/h (milli-deg/h)
        (floor,) = rows[channel]["_floor"]
        assert (1e-7 < floor < 1e-4) if channel.endswith("_g") else (1e-4 < floor < 1e-2), (channel, floor)
    accuracy_table.print_channel_tables("t", rows, 1.3)
    printed = capsys.readouterr().out
    assert "| Noise floor, g |" in printed and printed.count("| Noise floor, deg/h |") == 3
    assert printed.count("| Noise floor, g |") == 3 and "within 1.3x" in printed
    assert printed.count("fogd-train's default: the ladder** chose") == len(CHANNELS)


def test_one_job_or_two_give_the_same_tables(shrunk):
    """The channels fitted in parallel (--jobs 2) are the channels fitted one after another."""
    one = accuracy_table.evaluate_imu(shrunk, "lumped", 0.0625, 4.0)
    two = accuracy_table.evaluate_imu(argparse.Namespace(**{**vars(shrunk), "jobs": 2}), "lumped", 0.0625, 4.0)
    assert one == two
