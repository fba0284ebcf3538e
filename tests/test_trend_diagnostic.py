"""tools/trend_diagnostic.py --rate-prior: its trend fits with fogd-train's rate prior when asked, and only then."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from fogd.core.inputs import inputs_batch, parse_inputs

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tools"))
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
