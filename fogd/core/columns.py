"""Names and sizes that the daemon, replay, recording and calibration must agree on, defined once.

The run CSV's columns (what `fogd-record` writes and every command reads), the compensated-output CSV's
columns and their number formats (the daemon's `csv` output and `fogd-replay` write the same rows), the
simulator's truth column, and the block length of the paper's tables (100 s means, table 4).
"""

from __future__ import annotations

RUN_COLUMNS = ("t_s", "rate_dph", "temp_c")
TRUE_ERROR_COLUMN = "true_error_dph"  # written by fogd-sim; used for diagnostics only, never for fitting
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
