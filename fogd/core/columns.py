"""Names and sizes that the daemon, replay, recording and calibration must agree on, defined once.

The run CSV's columns (what `fogd-record` writes and every command reads), the compensated-output CSV's
columns and their number formats (the daemon's `csv` output and `fogd-replay` write the same rows), the
simulator's truth column, and the block length of the paper's tables (100 s means, table 4).
"""

from __future__ import annotations

RUN_COLUMNS = ("t_s", "rate_dph", "temp_c")  # a single-axis run
TRUE_ERROR_COLUMN = "true_error_dph"  # written by fogd-sim; used for diagnostics only, never for fitting
SINGLE_CHANNEL = "rate_dph"  # the one channel of a single-axis run
GYRO_CHANNELS = ("rate_x_dph", "rate_y_dph", "rate_z_dph")
ACCEL_CHANNELS = ("accel_x_g", "accel_y_g", "accel_z_g")
CHANNELS = GYRO_CHANNELS + ACCEL_CHANNELS  # a multi-channel run: t_s, those the unit has, temp_c
OUTPUT_FORMATS = {  # the compensated-output CSV: column -> printf format
    "t_s": "%.6f",
    "rate_dph": "%.9g",
    "temp_c": "%.9g",
    "temp_rate_cps": "%.9g",
    "comp_dph": "%.9g",
    "rate_comp_dph": "%.9g",
    "flags": "%d",
}
BLOCK_S = 100.0  # block length of the targets and of table 4, as in the paper


def block_samples(block_s: float, rate_hz: float) -> int:
    """Samples in one block of `block_s` seconds at `rate_hz` (at least one)."""
    return max(1, int(round(block_s * rate_hz)))


def channel_unit(channel: str | None) -> str:
    """The unit a channel's readings, compensations and errors are in: g for an accelerometer, deg/h for a
    gyro (and a single-axis run's rate_dph)."""
    return "g" if channel in ACCEL_CHANNELS else "deg/h"


def truth_column(channel: str) -> str:
    """The simulator's true thermal error of `channel`: true_error_dph for a single-axis run, else
    true_error_<channel> (true_error_rate_x_dph, true_error_accel_z_g)."""
    return TRUE_ERROR_COLUMN if channel == SINGLE_CHANNEL else f"true_error_{channel}"
