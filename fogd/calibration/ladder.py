"""`fogd-train`'s default: the model chosen on the user's own runs from a ladder that starts at IEEE 952 linear.

The rungs, simplest first (`RUNGS`): IEEE 952's linear model in the temperature and its 50 s rate; the same
with the static curve (the coil trend's powers 2 and 3 of the temperature); the coil trend over the lag bank
and play operator (fogd's thermal state, no kernel); and that trend under the PSO-tuned SVR (fogd's richest
model). Each rung is scored by held-out drift (RMSE of 100 s blocks about each run's mean) on folds that respect
time (`fogd.calibration.models.folds.time_folds`: leave-one-run-out with three runs or more; with one or two,
the k-th stretch of every run held out together, with a gap of the longest lag on either side, or as much of
one as leaves a third of each run to train on), every fold predicted by a model tuned and
fitted without it (`selection.nested_residual`), its inputs clamped as the daemon clamps them.

The choice is the one-standard-error rule: the simplest rung whose held-out drift is within one standard error
(the spread of its per-fold figures over the square root of their number) of the best rung's. A richer model
is taken only when it wins by more than the folds can tell apart; on a real IMU the lag bank under the SVR
removed less drift than IEEE 952's linear fit (issue 33), and on simulated physics it removed several times
more: the user's own runs decide. Only the chosen rung is refitted on all the runs.

Why not leave one of two runs out: on the quick-start's heating and cooling runs (README) a model of the lag
bank fitted on the heating run alone has never seen the play operator turn nor its rates change sign, and
leave-one-run-out scored every rung alike (0.023-0.027 deg/h) and chose the static curve, which left 2.85e-3
deg/h on the held-out paper-test run; the time folds a lag apart chose the lag bank, 8.28e-4 (the noise floor
there is 8.12e-4; linear 1.30e-2). Measured at 10 Hz, navigation noise, seeds 1-3.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from fogd.calibration.models.folds import MIN_RUNS_LEFT_OUT, Split, drift_rmse, run_levels, time_folds
from fogd.calibration.selection import fit_family, nested_residual
from fogd.calibration.training import TrainConfig, Trained, for_sensor, options_for_inputs, prepare
from fogd.core.inputs import DEFAULT_INPUTS_TEXT, InputSpec, describe_inputs, parse_inputs, shifted_columns
from fogd.errors import InputError

PAPER_INPUTS_TEXT = "temp,rate@50"  # IEEE 952's T and dT/dt (the paper's eq. 16 rate over 50 s)
# Scoring the SVR rung tunes a swarm inside every held-out fold: a small one (SCORE_PARTICLES, stopping after
# SCORE_PATIENCE still iterations, on SCORE_FOLDS inner folds), or the rung alone costs minutes on a day's run
# (24 h at 1 Hz: 330 s of CPU with 20 particles, patience 10 and 5 inner folds). The chosen model is then fitted
# with the full default swarm. A rung tuned more cheaply can only score worse, and the rule takes the simpler
# rung on a tie: the cost is an SVR passed over, never a worse model taken.
SCORE_PARTICLES = 10
SCORE_PATIENCE = 5
SCORE_FOLDS = 3


@dataclass(frozen=True)
class Rung:
    """One model of the ladder: a family on an input set (`search=False`: pso-svr's trend alone, no kernel)."""

    name: str
    method: str
    inputs_text: str
    search: bool = True


RUNGS = (
    Rung("linear", "linear", PAPER_INPUTS_TEXT),
    Rung("static curve", "pso-svr", PAPER_INPUTS_TEXT, search=False),
    Rung("lag bank", "pso-svr", DEFAULT_INPUTS_TEXT, search=False),
    Rung("lag bank + SVR", "pso-svr", DEFAULT_INPUTS_TEXT),
)


@dataclass
class Scored:
    """A rung's held-out figures: pooled drift RMSE, its standard error and each fold's RMSE (deg/h, or g)."""

    rung: Rung
    inputs: tuple[InputSpec, ...]
    drift_rmse_dph: float
    spread_dph: float
    fold_rmse_dph: list[float]
    seconds: float
    prepared: tuple = field(repr=False, default=())

    def row(self) -> dict:
        return {"name": self.rung.name, "method": self.rung.method, "inputs": describe_inputs(self.inputs),
                "drift_rmse_dph": self.drift_rmse_dph, "spread_dph": self.spread_dph,
                "fold_rmse_dph": self.fold_rmse_dph, "seconds": round(self.seconds, 2)}  # fmt: skip


@dataclass
class Ladder:
    """The scored rungs, the chosen one and its model fitted on all the runs."""

    scored: list[Scored]
    chosen: Scored
    folds: str
    trained: Trained
    uncompensated_dph: float  # no compensation at all, scored on the same folds (`uncompensated`)

    def held_out(self) -> dict:
        """The model file's `metrics.held_out` (fogd.core.modelfile.held_out)."""
        return {"drift_rmse_dph": self.chosen.drift_rmse_dph, "spread_dph": self.chosen.spread_dph,
                "folds": self.folds, "rung": self.chosen.rung.name}  # fmt: skip

    def table(self, unit: str = "deg/h") -> list[str]:
        """The rungs as a markdown table, for the report."""
        lines = [f"Model ladder ({self.folds}; the simplest rung within one standard error of the best):", "",
                 f"| Rung | Model | Held-out drift ({unit}) | Standard error | |", "|---|---|---:|---:|---|"]  # fmt: skip
        lines += [f"| {s.rung.name} | {s.rung.method} `{describe_inputs(s.inputs)}` | {s.drift_rmse_dph:.3e} | "
                  f"{s.spread_dph:.2e} | {'chosen' if s is self.chosen else ''} |" for s in self.scored]  # fmt: skip
        return lines

    def line(self, unit: str = "deg/h") -> str:
        """What was chosen and why, with every rung's held-out figure, in one line."""
        best = min(self.scored, key=lambda s: s.drift_rmse_dph)
        why = ("the best held-out drift" if self.chosen is best else
               f"the simplest within one standard error of the best ({best.rung.name})")  # fmt: skip
        figures = "; ".join(f"{s.rung.name} {s.drift_rmse_dph:.3g} ± {s.spread_dph:.2g}" for s in self.scored)
        return (f"ladder: chose {self.chosen.rung.name} ({self.chosen.rung.method} [{describe_inputs(self.chosen.inputs)}]), "
                f"{why}; held-out drift ({unit}, {self.folds}): {figures}")  # fmt: skip


def gap_rows(specs: tuple[InputSpec, ...], block_s: float) -> int:
    """Blocks between a held-out stretch and its training rows: the longest lag or estimator window, in blocks."""
    longest_s = max([spec.tau_s or 0.0 for spec in specs]
                    + [spec.estimator.window_s for spec in specs if spec.estimator is not None] + [0.0])  # fmt: skip
    return math.ceil(longest_s / block_s)


def affordable_gap(groups: np.ndarray, n_folds: int) -> int:
    """The largest gap that leaves every time fold at least a third of the shortest run's rows to train on
    (a 2 h run has 80 blocks: with 5 folds and the lag bank's 30 blocks on either side, none; its gap is 19)."""
    rows = int(np.min(np.unique(groups, return_counts=True)[1]))
    return max(0, (rows - math.ceil(rows / max(n_folds, 1)) - math.ceil(rows / 3)) // 2)


def uncompensated(error_dph: np.ndarray, groups: np.ndarray, splits: list[Split]) -> float:
    """The held-out drift of no compensation on the same folds: each held-out stretch at its run's level on the
    training rows (what the rungs' residuals are scored about), so that "worse than nothing" compares like
    with like; the calibration blocks' own spread is smaller wherever the folds make a level hard to know."""
    residual = np.full_like(error_dph, np.nan)
    for train, test in splits:
        residual[test] = run_levels(error_dph[train], groups[train], groups[test]) - error_dph[test]
    return drift_rmse(residual, groups)


def choose(scored: list[Scored]) -> Scored:
    """The one-standard-error rule: the first (simplest) rung whose drift is within one standard error of the
    best rung's."""
    best = min(scored, key=lambda s: s.drift_rmse_dph)
    limit = best.drift_rmse_dph + best.spread_dph
    return next(s for s in scored if s.drift_rmse_dph <= limit)


def climb(runs, config: TrainConfig, rungs: tuple[Rung, ...] = RUNGS, log: Callable[[str], None] | None = None,
          unit: str = "deg/h", average_s: float = 0.5, step_s: float = 0.0) -> Ladder:  # fmt: skip
    """Score every rung on the runs' time-respecting folds, choose by the one-standard-error rule and fit the
    chosen rung on all the runs (`average_s`, `step_s`: the eq. 16 estimator's, for a rung's rate input)."""
    sets = {rung.inputs_text: for_sensor(runs, dataclasses.replace(config, inputs=parse_inputs(rung.inputs_text, average_s, step_s))).inputs
            for rung in rungs}  # fmt: skip
    common_s = max((spec.estimator.window_s for specs in sets.values() for spec in specs if spec.estimator is not None),
                   default=0.0)  # fmt: skip
    gap = max(gap_rows(specs, config.block_s) for specs in sets.values())
    scored: list[Scored] = []
    splits: list[Split] | None = None
    groups = None
    for rung in rungs:
        specs = sets[rung.inputs_text]
        options = options_for_inputs(dataclasses.replace(config.fit, search=rung.search), specs)
        rung_config = dataclasses.replace(config, method=rung.method, inputs=specs, fit=options)
        started = time.perf_counter()
        try:
            prepared = prepare(runs, rung_config, min_warmup_s=common_s)
            data, reference = prepared
            if splits is None:
                gap = min(gap, affordable_gap(data.groups, config.fit.folds))
                splits, groups = time_folds(data.groups, config.fit.folds, gap), data.groups
                nothing_dph = uncompensated(data.rate_dph - reference, groups, splits)
            elif not np.array_equal(groups, data.groups):
                raise AssertionError("every rung must be scored on the very same blocks")
            scoring = dataclasses.replace(options, particles=min(options.particles, SCORE_PARTICLES), folds=SCORE_FOLDS,
                                          patience=min(options.patience or SCORE_PATIENCE, SCORE_PATIENCE))  # fmt: skip
            residual = nested_residual(rung.method, data, data.rate_dph - reference, scoring, shifted_columns(specs), splits)
        except InputError as error:  # too few rows for this rung: say so, climb on
            if log:
                log(f"ladder: {rung.name} skipped: {error}")
            continue
        per_fold = [drift_rmse(residual[test], data.groups[test]) for _, test in splits]
        spread = float(np.std(per_fold, ddof=1) / math.sqrt(len(per_fold))) if len(per_fold) > 1 else 0.0
        scored.append(Scored(rung, specs, drift_rmse(residual, data.groups), spread, per_fold,
                             time.perf_counter() - started, prepared))  # fmt: skip
        if log:
            log(f"ladder: {rung.name}: held-out drift {scored[-1].drift_rmse_dph:.4e} ± {spread:.2e} {unit} "
                f"({scored[-1].seconds:.1f} s)")  # fmt: skip
    if not scored:
        raise InputError("ladder: no model could be scored on these runs; record more or longer runs")
    chosen = choose(scored)
    rung = chosen.rung
    options = options_for_inputs(dataclasses.replace(config.fit, search=rung.search), chosen.inputs)
    final = dataclasses.replace(config, method=rung.method, inputs=chosen.inputs, fit=options)
    trained = fit_family(runs, final, chosen.prepared, rung.method)
    n_runs = len(np.unique(groups))
    folds = (f"leave-one-run-out, {n_runs} runs" if n_runs >= MIN_RUNS_LEFT_OUT else
             f"{len(splits)} time folds of {'each run' if n_runs > 1 else 'the run'}, {gap} blocks apart")  # fmt: skip
    return Ladder(scored, chosen, folds, trained, nothing_dph)
