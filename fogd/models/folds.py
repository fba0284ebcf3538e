"""Held-out folds for calibration blocks and the pooled held-out RMSE every method is judged by.

Blocks of one run are neighbours in time, so shuffled folds would let a model be tested on rows sitting
between its training rows. With several runs each run is held out in turn (leave-one-run-out); with one run
the run is cut into contiguous stretches of time. Every row is tested exactly once.
"""

from __future__ import annotations

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


def held_out_rmse(estimator, xs: np.ndarray, ys: np.ndarray, splits: list[Split]) -> float:
    """RMSE (scaled units) of a fresh clone of `estimator` fitted on each training fold, pooled over test rows."""
    residual = np.empty_like(ys)
    for train, test in splits:
        model = clone(estimator).fit(xs[train], ys[train])
        residual[test] = model.predict(xs[test]) - ys[test]
    return float(np.sqrt(np.mean(residual**2)))
