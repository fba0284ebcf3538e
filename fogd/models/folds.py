"""Held-out folds for calibration blocks and the pooled held-out RMSE every method is judged by.

Blocks of one run are neighbours in time, so shuffled folds would let a model be tested on rows sitting
between its training rows. With several runs each run is held out in turn (leave-one-run-out); with one run
the run is cut into contiguous stretches of time. Every row is tested exactly once.

The score is the error users care about: the drift about each run's own mean (as table 4 and the Allan
deviation measure it), so a held-out run's constant turn-on bias, which no temperature model can predict,
does not drown the differences between models.
"""

from __future__ import annotations

import inspect

import numpy as np
from sklearn.base import clone

from fogd.errors import InputError

Split = tuple[np.ndarray, np.ndarray]


def folds(groups: np.ndarray, n_folds: int) -> list[Split]:
    """(train_idx, test_idx) pairs: leave-one-run-out with >= 2 distinct groups, else `n_folds` time blocks."""
    groups = np.asarray(groups)
    rows = np.arange(groups.size)
    runs = np.unique(groups)
    if runs.size >= 2:
        return [(rows[groups != run], rows[groups == run]) for run in runs]
    if n_folds < 2:
        raise InputError(f"held-out folds need at least 2 runs or --folds >= 2 (have {n_folds}): add a run or raise --folds")
    if groups.size < 2 * n_folds:
        raise InputError(
            f"{groups.size} block rows are too few for {n_folds} time folds: record more or longer runs, "
            "use a smaller --block-s or fewer --folds"
        )
    return [(np.setdiff1d(rows, test), test) for test in np.array_split(rows, n_folds)]


def fit_in_runs(estimator, xs: np.ndarray, ys: np.ndarray, groups: np.ndarray | None):
    """`estimator.fit`, with the rows' runs for estimators that fit one offset per run."""
    if groups is not None and "groups" in inspect.signature(estimator.fit).parameters:
        return estimator.fit(xs, ys, groups=groups)
    return estimator.fit(xs, ys)


def drift_rmse(residual: np.ndarray, groups: np.ndarray | None) -> float:
    """RMSE of residuals about each run's own mean residual."""
    residual = np.asarray(residual, dtype=np.float64).copy()
    groups = np.zeros(residual.size, dtype=np.int64) if groups is None else np.asarray(groups)
    for group in np.unique(groups):
        rows = groups == group
        residual[rows] -= residual[rows].mean()
    return float(np.sqrt(np.mean(residual**2)))


def held_out_rmse(estimator, xs: np.ndarray, ys: np.ndarray, splits: list[Split], groups: np.ndarray | None = None) -> float:
    """Drift RMSE (scaled units, about each run's mean) of a fresh clone of `estimator` fitted on each training
    fold, pooled over the test rows."""
    residual = np.empty_like(ys)
    for train, test in splits:
        model = fit_in_runs(clone(estimator), xs[train], ys[train], None if groups is None else groups[train])
        residual[test] = model.predict(xs[test]) - ys[test]
    return drift_rmse(residual, groups)
