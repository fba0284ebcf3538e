"""Simulated IMU runs for the multi-channel tests: each channel a single-axis simulated gyro of its own
(distinct thermal coefficients and noise), all under one chamber profile, with one temperature column."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fogd.core.columns import ACCEL_CHANNELS, CHANNELS, truth_column
from fogd.simulation.profiles import builtin
from fogd.simulation.simulator import params_for, simulate

G_PER_DPH = 1e-3  # an accelerometer's thermal error is the simulated gyro's, scaled to g
COEFFICIENTS = {
    "rate_x_dph": {"static_dph": (0.06, 0.04, 0.05), "shupe_rate_dph_per_cps": 6.0},
    "rate_y_dph": {"static_dph": (-0.05, 0.02, 0.03), "shupe_rate_dph_per_cps": -4.0},
    "rate_z_dph": {"static_dph": (0.02, -0.06, 0.01), "shupe_rate_dph_per_cps": 9.0},
    "accel_x_g": {"static_dph": (0.08, 0.01, -0.02), "shupe_rate_dph_per_cps": 3.0},
    "accel_y_g": {"static_dph": (-0.03, 0.05, 0.02), "shupe_rate_dph_per_cps": -7.0},
    "accel_z_g": {"static_dph": (0.04, -0.02, 0.04), "shupe_rate_dph_per_cps": 5.0},
}


def imu_columns(profile: str, seed: int, rate_hz: float = 1.0, channels: tuple[str, ...] = CHANNELS) -> dict[str, np.ndarray]:
    """t_s, the channels, temp_c and each channel's true thermal error."""
    columns: dict[str, np.ndarray] = {}
    truths: dict[str, np.ndarray] = {}
    for index, channel in enumerate(channels):
        run = simulate(builtin(profile), rate_hz, 100 * seed + index, params_for(**COEFFICIENTS[channel]))
        scale = G_PER_DPH if channel in ACCEL_CHANNELS else 1.0
        gravity = 1.0 if channel == "accel_z_g" else 0.0
        if not columns:
            columns["t_s"] = run.t_s
            temp_c = run.temp_c
        columns[channel] = scale * run.rate_dph + gravity
        truths[truth_column(channel)] = scale * run.true_error_dph
    return {**columns, "temp_c": temp_c, **truths}


def write_imu_run(path: Path, profile: str, seed: int, rate_hz: float = 1.0, channels: tuple[str, ...] = CHANNELS) -> Path:
    columns = imu_columns(profile, seed, rate_hz, channels)
    np.savetxt(path, np.column_stack(list(columns.values())), delimiter=",", header=",".join(columns), comments="", fmt="%.9g")
    return path


def write_channel_run(path: Path, imu: Path, channel: str) -> Path:
    """The IMU run's `channel` as a single-axis run CSV (t_s,rate_dph,temp_c,true_error_dph)."""
    with open(imu) as stream:
        names = stream.readline().strip().split(",")
    table = np.loadtxt(imu, delimiter=",", skiprows=1)
    pick = [names.index(name) for name in ("t_s", channel, "temp_c", truth_column(channel))]
    np.savetxt(path, table[:, pick], delimiter=",", header="t_s,rate_dph,temp_c,true_error_dph", comments="", fmt="%.9g")
    return path
