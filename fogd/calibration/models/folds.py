"""Held-out folds for calibration blocks and the pooled held-out RMSE every method is judged by.

Blocks of one run are neighbours in time, so shuffled folds would let a model be tested on rows sitting
between its training rows. With three runs or more each run is held out in turn (leave-one-run-out); with
one or two, every run is cut into contiguous stretches of time and the k-th stretch of each is held out
together (with two runs, leaving one out would judge a model fitted on a heating run alone by a cooling
run's history, which says more about the runs than about the model). Every row is tested exactly once.

The score is the error users care about: the drift about each run's own mean (as table 4 and the Allan
deviation measure it), so a held-out run's constant turn-on bias, which no temperature model can predict,
does not drown the differences between models.
"""

from __future__ import annotations

import inspect
from typing import Callable

import numpy as np
from sklearn.base import clone

from fogd.core.errorstats import centred_within_runs
from fogd.errors import InputError

Split = tuple[np.ndarray, np.ndarray]


MIN_RUNS_LEFT_OUT = 3  # with fewer runs, a model fitted on one run would be judged on the other's history


def folds(groups: np.ndarray, n_folds: int) -> list[Split]:
    """(train_idx, test_idx) pairs: leave-one-run-out with >= MIN_RUNS_LEFT_OUT distinct groups, else `n_folds`
    contiguous stretches of time cut from every run alike (fold k holds out the k-th stretch of each run)."""
    groups = np.asarray(groups)
    runs = np.unique(groups)
    if runs.size < MIN_RUNS_LEFT_OUT and n_folds >= 2:
        for run in runs:
            rows_in_run = int(np.count_nonzero(groups == run))
            if rows_in_run < 2 * n_folds:
                raise InputError(
                    f"{rows_in_run} block rows in a run are too few for {n_folds} time folds: record more or longer "
                    "runs, use a smaller --block-s or fewer --folds"
                )
    return time_folds(groups, n_folds, gap_rows=0)


def time_folds(groups: np.ndarray, n_folds: int, gap_rows: int, min_runs: int = MIN_RUNS_LEFT_OUT) -> list[Split]:
    """Leave-one-run-out with `min_runs` runs or more; with fewer, `n_folds` contiguous stretches of every run
    (the k-th of each held out together), each held out with `gap_rows` rows on either side of it dropped from
    the training rows of its run, so that no training block shares the held-out stretch's thermal history (a lag
    of tau s remembers about tau s; `gap_rows` covers the longest)."""
    groups = np.asarray(groups)
    rows = np.arange(groups.size)
    runs = np.unique(groups)
    if runs.size >= min_runs:
        return [(rows[groups != run], rows[groups == run]) for run in runs]
    if n_folds < 2:
        raise InputError(f"held-out folds need at least {min_runs} runs or --folds >= 2 (have {n_folds}): add a run or raise --folds")
    fold_of = np.full(groups.size, -1)
    near = np.zeros((n_folds, groups.size), dtype=bool)  # rows within gap_rows of fold k's stretch of their run
    for run in runs:
        in_run = rows[groups == run]
        if in_run.size < n_folds:
            raise InputError(f"{in_run.size} block rows in a run are too few for {n_folds} time folds: record a longer run")
        for fold, stretch in enumerate(np.array_split(in_run, n_folds)):
            fold_of[stretch] = fold
            near[fold, in_run[(in_run >= stretch[0] - gap_rows) & (in_run <= stretch[-1] + gap_rows)]] = True
    return [(rows[~near[fold]], rows[fold_of == fold]) for fold in range(n_folds)]


def held_out_stretches(groups: np.ndarray, splits: list[Split]) -> np.ndarray:
    """A label for each row naming its held-out stretch: the fold that tests it and its run. With
    leave-one-run-out a stretch is a whole run; with time folds, a stretch of one run. Scoring residuals
    about each stretch's own mean judges a stretch as if it were a run of its own (`drift_rmse`)."""
    groups = np.asarray(groups)
    _, run = np.unique(groups, return_inverse=True)
    fold = np.full(groups.size, -1)
    for k, (_, test) in enumerate(splits):
        fold[test] = k
    return fold * (int(run.max(initial=0)) + 1) + run


def stretch_folds(groups: np.ndarray, n_folds: int, gap_rows: int, min_runs: int = MIN_RUNS_LEFT_OUT) -> list[Split]:
    """The ladder's outer folds (fogd.calibration.ladder): leave-one-run-out with `min_runs` runs or more; with
    fewer, each run cut into `n_folds` contiguous stretches held out one at a time (one stretch of one run per
    fold), its run's rows within `gap_rows` of it dropped from the training rows (as `time_folds`) and every
    other run trained on whole, as the model that is served is trained on every run."""
    groups = np.asarray(groups)
    rows = np.arange(groups.size)
    runs = np.unique(groups)
    if runs.size >= min_runs:
        return time_folds(groups, n_folds, gap_rows, min_runs)
    if n_folds < 2:
        raise InputError(f"held-out folds need at least {min_runs} runs or --folds >= 2 (have {n_folds}): add a run or raise --folds")
    splits = []
    for run in runs:
        in_run = rows[groups == run]
        if in_run.size < n_folds:
            raise InputError(f"{in_run.size} block rows in a run are too few for {n_folds} time folds: record a longer run")
        for stretch in np.array_split(in_run, n_folds):
            near = (groups == run) & (rows >= stretch[0] - gap_rows) & (rows <= stretch[-1] + gap_rows)
            splits.append((rows[~near], stretch))
    return splits


def fit_in_runs(estimator, xs: np.ndarray, ys: np.ndarray, groups: np.ndarray | None):
    """`estimator.fit`, with the rows' runs for estimators that fit one offset per run."""
    if groups is not None and "groups" in inspect.signature(estimator.fit).parameters:
        return estimator.fit(xs, ys, groups=groups)
    return estimator.fit(xs, ys)


def run_levels(train_residual: np.ndarray, train_groups: np.ndarray | None, test_groups: np.ndarray | None) -> np.ndarray:
    """For each test row, its run's mean residual over that run's training rows (0 for a run not trained on).

    With time folds a held-out stretch's run also has training stretches, whose offset the fit estimated; the
    stretch is predicted with that offset, as a model's level on a run it was calibrated on. With
    leave-one-run-out nothing is known of the held-out run's offset, and its drift is scored about its mean."""
    if train_groups is None or test_groups is None:
        return np.zeros(len(test_groups) if test_groups is not None else 0)
    levels = np.zeros(len(test_groups))
    for run in np.unique(test_groups):
        trained = train_groups == run
        if trained.any():
            levels[test_groups == run] = train_residual[trained].mean()
    return levels


def drift_rmse(residual: np.ndarray, groups: np.ndarray | None) -> float:
    """RMSE of residuals about each run's own mean residual."""
    return float(np.sqrt(np.mean(centred_within_runs(residual, groups) ** 2)))


Clamp = Callable[[np.ndarray, np.ndarray], np.ndarray]  # (test rows, training rows) -> test rows as served


def held_out_rmse(estimator, xs: np.ndarray, ys: np.ndarray, splits: list[Split], groups: np.ndarray | None = None,
                  clamp: Clamp | None = None) -> float:  # fmt: skip
    """Drift RMSE (scaled units, about each run's mean) of a fresh clone of `estimator` fitted on each training
    fold, pooled over the test rows (clamped to the training rows' domain by `clamp`, as the daemon clamps)."""
    residual = np.empty_like(ys)
    for train, test in splits:
        model = fit_in_runs(clone(estimator), xs[train], ys[train], None if groups is None else groups[train])
        x_test = xs[test] if clamp is None else clamp(xs[test], xs[train])
        residual[test] = model.predict(x_test) - ys[test]
        if groups is not None:
            levels = run_levels(ys[train] - model.predict(xs[train]), groups[train], groups[test])
            residual[test] += levels
    return drift_rmse(residual, groups)
