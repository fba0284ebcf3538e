"""tools/trend_diagnostic.py: its trend fits with fogd-train's rate prior only when asked; its +deq temperatures and its cases."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fogd.core.inputs import inputs_batch, parse_inputs

TOOL = Path(__file__).resolve().parent.parent / "tools" / "trend_diagnostic.py"
sys.path.insert(0, str(TOOL.parent))
import trend_diagnostic  # noqa: E402

SPECS = parse_inputs("temp,lags@10..3000/7")


def _blocks(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two noisy ramps' lag-bank rows (1 Hz) and a thermal error of a lagged temperature and its rate."""
    rng = np.random.default_rng(seed)
    xs, ys, groups = [], [], []
    for run, (pace_cps, start_c) in enumerate(((0.006, -10.0), (-0.005, 40.0))):
        t_s = np.arange(20000.0)
        temp_c = start_c + pace_cps * np.clip(t_s - 1800.0, 0.0, 12000.0)
        x = inputs_batch(temp_c, SPECS, 1.0)
        coil_c = x[:, 5]
        y = 1e-3 * coil_c + 2.0 * np.gradient(coil_c) + rng.normal(0.0, 5e-3, t_s.size)
        xs.append(x[::100])
        ys.append(y.reshape(-1, 100).mean(axis=1))
        groups.append(np.full(ys[-1].size, run))
    return np.vstack(xs), np.concatenate(ys), np.concatenate(groups)


def test_the_prior_reaches_the_fit_only_when_asked() -> None:
    xs, ys, groups = _blocks(1)
    plain = trend_diagnostic.Trend(xs, ys, groups, SPECS)
    smooth = trend_diagnostic.Trend(xs, ys, groups, SPECS, rate_prior="smooth")
    assert plain.terms.penalty_rows is None and plain.terms.prior_strength is None
    assert smooth.terms.penalty_rows is not None and smooth.terms.prior_strength is not None
    assert not np.allclose(plain.coef, smooth.coef)
    # the penalised fit leaves at least the plain fit's residual on the rows it was fitted to
    assert smooth.fit_rmse_dph >= plain.fit_rmse_dph * (1 - 1e-9)


def _ramp_run() -> trend_diagnostic.SimRun:
    """A noise-free 1 Hz run: a soak, a 20 C/h ramp over 4 C, a soak; readings in 1/16 C steps."""
    run = trend_diagnostic.SimRun.__new__(trend_diagnostic.SimRun)
    run.t_s = np.arange(6000.0)
    run.true_c = 10.0 + np.clip(run.t_s - 1000.0, 0.0, 720.0) * (20.0 / 3600.0)
    run.rate_hz, run.sensor_hz, run.resolution_c, run.noise_c, run.seed = 1.0, 1.0, 0.0625, 0.0, 1
    run.read_c = np.round(run.true_c / run.resolution_c) * run.resolution_c
    return run


def test_deq_takes_the_staircase_off_the_readings() -> None:
    run = _ramp_run()
    ramp = slice(1100, 1700)  # on the ramp, past the estimate's first crossings
    errors = {spec: float(np.sqrt(np.mean((trend_diagnostic.temperature(run, spec) - run.true_c)[ramp] ** 2)))
              for spec in ("quant", "quant+deq", "quant+deqfb")}  # fmt: skip
    # the staircase's error is LSB / sqrt(12) on a ramp; the causal estimate lags the ramp by less than a step,
    # and its forwards-and-backwards mean cancels most of that lag
    assert errors["quant"] > 0.015
    assert errors["quant+deq"] < errors["quant"] / 2
    assert errors["quant+deqfb"] < errors["quant+deq"]


def test_an_unknown_temperature_suffix_is_refused() -> None:
    with pytest.raises(SystemExit, match="unknown temperature"):
        trend_diagnostic.temperature(_ramp_run(), "quant+deqx")


def test_a_case_with_an_unknown_target_is_refused() -> None:
    result = subprocess.run([sys.executable, str(TOOL), "--case", "read/read/rates"], capture_output=True, text=True)
    assert result.returncode == 2
    assert "FIT/SERVE/TARGET" in result.stderr
