"""Whether a recorded run can calibrate a gyro: refuses, in one line, a run that cannot (too short for the
estimator's warm-up and one block, or whose temperature hardly moves), before any fitting is spent on it."""

from __future__ import annotations

import numpy as np

from fogd.core.columns import block_samples
from fogd.core.compensator import temperature_valid
from fogd.core.runio import Run
from fogd.errors import InputError

MIN_SPAN_C = 5.0  # below this, the temperature terms are fitted to noise and drift, not to temperature
NEEDS = (
    "a calibration run must move the gyro's temperature over the range it will see in use "
    "(heat, cool, soak at a few temperatures)"
)


def check_calibration_run(run: Run, warmup_s: float, block_s: float) -> None:
    """Raise InputError (one line: what is wrong, what a calibration run needs) unless `run` lasts at least
    the estimator warm-up `warmup_s` plus one `block_s` block and its valid temperatures span `MIN_SPAN_C`."""
    needed_rows = int(round(warmup_s * run.rate_hz)) + block_samples(block_s, run.rate_hz)
    if run.rows < needed_rows:
        raise InputError(
            f"{run.path}: {run.rows / run.rate_hz:.6g} s of data ({run.rows} rows at {run.rate_hz:.6g} Hz) is too "
            f"short: the estimator warm-up ({warmup_s:g} s) and one {block_s:g} s block need "
            f"{needed_rows / run.rate_hz:.6g} s; {NEEDS}, which takes hours"
        )
    valid_c = run.temp_c[temperature_valid(run.temp_c)]
    if valid_c.size == 0:
        raise InputError(f"{run.path}: no valid temperature in the whole run; {NEEDS}")
    span_c = float(np.max(valid_c) - np.min(valid_c))
    if span_c == 0.0:
        raise InputError(f"{run.path}: isothermal run (temperature span 0 C, under {MIN_SPAN_C:g} C): {NEEDS}")
    if span_c < MIN_SPAN_C:
        raise InputError(f"{run.path}: temperature span {_below(span_c)} C is under {MIN_SPAN_C:g} C: {NEEDS}")


def _below(span_c: float) -> str:
    """The span in three digits, or more where three would round it up to the limit ('5 C is under 5 C')."""
    text = f"{span_c:.3g}"
    return text if float(text) < MIN_SPAN_C else f"{span_c:.6g}"
