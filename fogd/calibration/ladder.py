"""`fogd-train`'s default: the model chosen on the user's own runs from a ladder that starts at IEEE 952 linear.

The rungs, simplest first (`RUNGS`): no compensation at all (rung 0: the reading passed through, stored as a
linear model whose coefficients are zero, `training.no_compensation`); IEEE 952's linear model in the temperature
and its 50 s rate; the same
with the static curve (the coil trend's powers 2 and 3 of the temperature); the coil trend over the lag bank
and play operator (fogd's thermal state, no kernel); with three runs or more, the same over a bank reaching
10,000 s (`LONG_INPUTS_TEXT`: a coil whose slowest path outlasts the housing's hour, as on sensor_on=baseplate);
and the default bank's trend under the PSO-tuned SVR (fogd's richest model). Each rung is scored on folds that respect time (`fogd.calibration.models.folds.stretch_folds`:
leave-one-run-out with three runs or more; with one or two, each run cut into stretches held out one at a time,
with a gap of the longest lag on either side, or as much of one as leaves a third of the run to train on, every
other run trained on whole), every fold predicted by a model tuned and fitted without it
(`selection.nested_residual`), its rows beyond the fold's range served as the model will be served there
(`--outside-range`, the trend by default; `selection.served`).

The score is what a user sees on a run (and tools/accuracy_table.py measures): the drift, the RMSE of block
means about the run's own mean (the fit's blocks, 200 s by default: fogd.core.columns.FIT_BLOCK_S). A held-out
stretch is judged the same way, as a run of its own, about its own mean (`held_out_stretches`): its level against the other stretches is a constant that no model can know
and a bias calibration removes. Scored about their runs' means instead, the quick start's stretches (README:
heating and cooling runs, 10 Hz, seed 1) gave 0.012 deg/h pooled where each fold's own drift was 0.001-0.004:
offsets between stretches, the same for every rung, that hid the rungs' differences.

The choice is the one-standard-error rule on paired ratios: of the rungs that improve on every simpler rung, the
simplest whose drift is within one standard error of the best rung's. Rungs are compared fold by fold, by the
logarithm of their drift (`fold_log_ratio`): every rung is scored on the very same folds and the folds differ
from one another far more than the rungs do within a fold, so only the per-fold comparison says which is better;
and a drift is a multiple (of the noise floor, of another model's), so a fold where a rung halves the drift counts
as much on an easy run as on a hard one. Ranked by pooled drift and judged by the spread of their per-fold
differences, the hardest fold decided both: with a whole-degree sensor (tools/accuracy_table.py --quick,
lumped coil, seeds 4 and 5) the lag bank left 0.0021 / 0.0045 / 0.0072 deg/h on the three left-out runs where
the static curve left 0.0052 / 0.0096 / 0.0057; the differences' error (0.0020) took the static curve, 18-21x
the noise floor on the held-out fast-cycle run where the lag bank leaves 7.5-8.9x. By ratio (0.39 / 0.47 / 1.26,
mean of the logarithms -0.49, its error 0.36) the lag bank is taken. Over seeds 1-5 of both coils, both sensors
and three physics (60 ladders; every rung replayed on the five held-out runs) the worst held-out run was on
average 1.05x the best rung's (1.12x before), at most 1.49x (2.44x before). On housing_tau_s=3000 with whole
degrees the static curve is still kept on 8 of 10 (10.9-19.7x the floor where the lag bank leaves 8.1-13.6x):
there the lag bank loses on one left-out run of three, and three folds cannot tell that from noise. A rung no
better than a simpler one is left out first: a per-pair spread could otherwise take a rung as good as linear whose
differences from the best are merely noisier.

On `tools/accuracy_table.py --quick --physics housing_tau_s=3000` (lumped coil, fine sensor, seed 1,
leave-one-run-out on three runs) the lag bank beat the static curve on every run (9.5e-4 / 1.74e-2 / 1.59e-3
deg/h against 3.3e-3 / 1.97e-2 / 9.6e-3); the best rung's own spread over its folds (5.3e-3, 60 % of its drift
of 8.9e-3), the rule before the paired one, kept the static curve, 1.7-11.3x the noise floor on the held-out runs;
paired, the ladder takes the top rung, 1.00-1.08x. Only the chosen rung is refitted on all the runs.

Rung 0, no compensation, is scored on the same folds and every rung must improve on it to be taken: a channel
whose held-out drift no model reduces (the IMU guide's 2 Hz run: on rate_y_dph linear 4.13e-2, static curve
3.77e-2, lag bank 3.72e-2 deg/h against 3.32e-2 uncompensated) is served as it comes rather than refused, and its
neighbours keep their models; the refusal to write a model worse than none (channels.worse_than_nothing) then
only meets a model the user named with --method. Rung 0 is taken only when no rung's pooled held-out drift is
below its own, never as "within one standard error" of a better rung, nor by the mean logarithm of its folds: on
folds where nothing moves (a run's flat first hour) a model adds a little noise to a tiny drift, a large ratio
that outweighed, fold by fold, what it removed on the ramp (bench_train.py --quick, the day's first 2 h at 1 Hz
trained on one run: no compensation 4.12e-3 deg/h pooled, linear 3.3e-3, yet rung 0 ranked first and the
held-out day was left at 18.3x the noise floor where linear leaves 1.7x). Scored about each stretch's own level
rung 0 is forgiven the drift between
stretches, which is thermal (the guide's rate_x_dph: 2.89e-2 about the stretches' levels, 6.9e-2 about the
levels the run's other stretches give), and a single run's stretches cannot show what a model gains on another
history. With the margin, that run's rate_x_dph (linear 2.60e-2, error of the paired differences 3.0e-3) and
accel_y_g (static curve 1.97e-4 against 2.29e-4, error 6.0e-5) went uncompensated: 3.24e-2 deg/h and 2.63e-4 g on
the held-out paper-test run (seed 3, floor 2.41e-2 and 1.8e-6) where the rungs now taken, linear and the static
curve, leave 2.44e-2 and 2.6e-5.

The paired rule climbs more readily, and it climbs wrongly where the folds cannot see the loss: on the 200 Hz
quick start (tactical noise, bench_train.py, seed 1) the lag bank scored 2.42e-2 deg/h against the static curve's
2.50e-2 (paired error 4.5e-4; the best rung's own spread, 1.1e-3, would have kept the static curve) and left
3.02e-2 on paper-test where the static curve leaves 2.47e-2 and linear 2.52e-2 (floor 2.38e-2); seed 11 kept the
static curve (2.25e-2 against 2.32e-2; paper-test 2.80e-2, the lag bank 3.27e-2). The lag bank's error there is
a slope in temperature (+0.031 deg/h at 0 C to -0.043 at 28 C) that stretches of the same monotone runs, where
temperature stands for time, do not show. The trade measured: 1.27x the floor against 1.03x there, 1.08x against
11.25x on housing_tau_s=3000. Holding out each of the two runs whole does not reveal it either: the lag bank
still scores best (seed 1: linear 4.15e-2, static curve 3.88e-2, lag bank 3.55e-2 deg/h), and two folds' paired
error (8.5e-3 against linear) only sends the rule back to linear; on the 10 Hz quick start (navigation noise),
where the lag bank leaves 1.02x the floor on paper-test and the static curve 3.51x, whole runs rank the static
curve first (1.84e-2 against 2.37e-2). Three runs or more are held out whole (leave-one-run-out).

Why one stretch of one run per fold: the served model is fitted on every run; a fold should lack as little
of them as it can. Holding out the k-th stretch of every run together removed the same phase of each run at
once: on the quick start's mirrored heating and cooling runs the last fold held out both ends of the
temperature range (36-48 C heating and 4 to -7 C cooling), where the lag bank, fitted on neither, scored
6.4e-3 / 9.3e-3 / 2.1e-2 deg/h (seeds 1 / 11 / 21; its other folds 0.9-4.8e-3), and the ladder chose the static
curve, 2.7-2.9e-3 deg/h on the held-out paper-test run where the lag bank leaves 8.2e-4-1.1e-3 (noise floor
7.9e-4-9.7e-4). One stretch at a time the lag bank scores 1.04e-3 / 1.05e-3 / 1.05e-3 and is chosen on each
seed (static curve 2.6-2.7e-3, linear 8.6-8.7e-3). Leaving one of two runs out is worse still: a model of the
lag bank fitted on the heating run alone has never seen the play operator turn nor its rates change sign.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from fogd.calibration.models.folds import (
    MIN_RUNS_LEFT_OUT,
    Split,
    drift_rmse,
    held_out_stretches,
    run_levels,
    stretch_folds,
)
from fogd.calibration.selection import fit_family, nested_residual
from fogd.calibration.training import TrainConfig, Trained, for_sensor, no_compensation, options_for_inputs, prepare
from fogd.core.inputs import DEFAULT_INPUTS_TEXT, LONG_INPUTS_TEXT, InputSpec, describe_inputs, parse_inputs, shifted_columns
from fogd.errors import InputError

PAPER_INPUTS_TEXT = "temp,rate@50"  # IEEE 952's T and dT/dt (the paper's eq. 16 rate over 50 s)
NONE = "none"  # rung 0's method: nothing fitted, the reading passed through (training.no_compensation)
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
    """One model of the ladder: a family on an input set (`search=False`: pso-svr's trend alone, no kernel;
    method `NONE`: no compensation, its input the temperature only, for the CLAMPED flag)."""

    name: str
    method: str
    inputs_text: str
    search: bool = True
    min_runs: int = 1  # offered only on at least this many runs (`climb`)


RUNGS = (
    Rung("no compensation", NONE, "temp"),
    Rung("linear", "linear", PAPER_INPUTS_TEXT),
    Rung("static curve", "pso-svr", PAPER_INPUTS_TEXT, search=False),
    Rung("lag bank", "pso-svr", DEFAULT_INPUTS_TEXT, search=False),
    Rung("long lag bank", "pso-svr", LONG_INPUTS_TEXT, search=False, min_runs=MIN_RUNS_LEFT_OUT),
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

    @property
    def log_drift(self) -> float:
        """The mean of the logarithms of its per-fold figures: what the rule ranks rungs by (module docstring)."""
        return float(np.mean(fold_logs(self)))

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
        lines = [f"Model ladder ({self.folds}; the simplest rung within one standard error of the best, compared fold "
                 "by fold by the ratio of their drifts):", "",
                 f"| Rung | Model | Held-out drift ({unit}) | Standard error | Geometric mean of the folds ({unit}) | |",
                 "|---|---|---:|---:|---:|---|"]  # fmt: skip
        lines += [f"| {s.rung.name} | {'-' if s.rung.method == NONE else f'{s.rung.method} `{describe_inputs(s.inputs)}`'} | {s.drift_rmse_dph:.3e} | "
                  f"{s.spread_dph:.2e} | {math.exp(s.log_drift):.3e} | {'chosen' if s is self.chosen else ''} |" for s in self.scored]  # fmt: skip
        return lines

    def line(self, unit: str = "deg/h") -> str:
        """What was chosen and why, with every rung's held-out figure, in one line."""
        best = min(self.scored, key=lambda s: s.log_drift)
        figures = "; ".join(f"{s.rung.name} {s.drift_rmse_dph:.3g} ± {s.spread_dph:.2g}" for s in self.scored)
        if self.chosen.rung.method == NONE:
            return (f"ladder: chose no compensation (the readings pass through unchanged): no rung's held-out drift "
                    f"is below the uncompensated {self.chosen.drift_rmse_dph:.3g} {unit}; held-out drift ({unit}, "
                    f"{self.folds}): {figures}")  # fmt: skip
        ratio, error = fold_log_ratio(self.chosen, best)
        why = ("the best held-out drift, fold by fold" if self.chosen is best else
               f"the simplest within one standard error of the best ({best.rung.name}): per fold {math.exp(ratio):.3g}x "
               f"its drift, the standard error of that ratio x{math.exp(error):.3g}")  # fmt: skip
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
    """The held-out drift of no compensation on the same folds, scored as the rungs are (each held-out stretch
    about its own mean), so that "worse than nothing" compares like with like."""
    return drift_rmse(error_dph, held_out_stretches(groups, splits))


def unpredicted(error_dph: np.ndarray, groups: np.ndarray, splits: list[Split]) -> np.ndarray:
    """Rung 0's held-out residuals: nothing predicted, each held-out stretch at the level its run's training rows
    give (`run_levels`), as a fitted rung's (`selection.nested_residual`)."""
    residual = np.full_like(error_dph, np.nan)
    for train, test in splits:
        residual[test] = run_levels(error_dph[train], groups[train], groups[test]) - error_dph[test]
    return residual


def score(residual: np.ndarray, groups: np.ndarray, splits: list[Split]) -> tuple[float, float, list[float]]:
    """A rung's held-out figures from its residuals: the drift with each held-out stretch about its own mean
    (`held_out_stretches`), the standard error of its per-fold figures and those figures (a fold: its runs'
    stretches, each about its own mean)."""
    per_fold = [drift_rmse(residual[test], groups[test]) for _, test in splits]
    spread = float(np.std(per_fold, ddof=1) / math.sqrt(len(per_fold))) if len(per_fold) > 1 else 0.0
    return drift_rmse(residual, held_out_stretches(groups, splits)), spread, per_fold


def fold_logs(rung: Scored) -> np.ndarray:
    """The logarithms of a rung's per-fold figures (a fold with no drift at all: the smallest positive float's)."""
    return np.log(np.maximum(rung.fold_rmse_dph, np.finfo(float).tiny))


def fold_log_ratio(rung: Scored, best: Scored) -> tuple[float, float]:
    """The mean of the logarithms of the per-fold ratios of two rungs' drifts, scored on the same folds, and its
    standard error (`choose`)."""
    logs = fold_logs(rung) - fold_logs(best)
    error = float(np.std(logs, ddof=1) / math.sqrt(logs.size)) if logs.size > 1 else 0.0
    return float(np.mean(logs)), error


def choose(scored: list[Scored]) -> Scored:
    """The one-standard-error rule on paired ratios: of the rungs that improve on every simpler rung (a richer
    rung no better than a simpler one is never worth its complexity), ranked by the mean logarithm of their
    per-fold drifts, the first whose mean log ratio to the best rung's is within one standard error of it. No
    compensation (rung 0, first when present) is judged by the pooled drift instead: a modelling rung stays in
    the running only when its pooled held-out drift is below rung 0's, and rung 0 is chosen only when none is
    (module docstring)."""
    if scored[0].rung.method == NONE:
        nothing = scored[0]
        scored = [s for s in scored[1:] if s.drift_rmse_dph < nothing.drift_rmse_dph]
        if not scored:
            return nothing
    front = [s for i, s in enumerate(scored) if all(s.log_drift < t.log_drift for t in scored[:i])]
    best = front[-1]

    def within(rung: Scored) -> bool:
        ratio, error = fold_log_ratio(rung, best)
        return ratio <= error

    return next(s for s in front if s is best or within(s))


def climb(runs, config: TrainConfig, rungs: tuple[Rung, ...] = RUNGS, log: Callable[[str], None] | None = None,
          unit: str = "deg/h", average_s: float = 0.5, step_s: float = 0.0) -> Ladder:  # fmt: skip
    """Score every rung on the runs' time-respecting folds, choose by the one-standard-error rule and fit the
    chosen rung on all the runs (`average_s`, `step_s`: the eq. 16 estimator's, for a rung's rate input; a rung
    whose `min_runs` exceeds the runs' number is not offered)."""
    rungs = tuple(rung for rung in rungs if len(runs) >= rung.min_runs)
    # once per input set (two rungs share the lag bank, whose play's lag and sensor estimate for_sensor chooses
    # on the runs); each set's config keeps what was chosen
    configs = {text: for_sensor(runs, dataclasses.replace(config, inputs=parse_inputs(text, average_s, step_s)))
               for text in dict.fromkeys(rung.inputs_text for rung in rungs)}  # fmt: skip
    sets = {text: chosen.inputs for text, chosen in configs.items()}
    common_s = max((spec.estimator.window_s for specs in sets.values() for spec in specs if spec.estimator is not None),
                   default=0.0)  # fmt: skip
    gap = max(gap_rows(specs, config.block_s) for specs in sets.values())
    scored: list[Scored] = []
    splits: list[Split] | None = None
    groups = None
    for rung in rungs:
        specs = sets[rung.inputs_text]
        options = options_for_inputs(dataclasses.replace(config.fit, search=rung.search), specs)
        rung_config = dataclasses.replace(configs[rung.inputs_text], method=rung.method, fit=options)
        started = time.perf_counter()
        try:
            prepared = prepare(runs, rung_config, min_warmup_s=common_s)
            data, reference = prepared
            if splits is None:
                gap = min(gap, affordable_gap(data.groups, config.fit.folds))
                splits, groups = stretch_folds(data.groups, config.fit.folds, gap), data.groups
                nothing_dph = uncompensated(data.rate_dph - reference, groups, splits)
            elif not np.array_equal(groups, data.groups):
                raise AssertionError("every rung must be scored on the very same blocks")
            if rung.method == NONE:
                residual = unpredicted(data.rate_dph - reference, groups, splits)
            else:
                scoring = dataclasses.replace(options, particles=min(options.particles, SCORE_PARTICLES), folds=SCORE_FOLDS,
                                              patience=min(options.patience or SCORE_PATIENCE, SCORE_PATIENCE))  # fmt: skip
                residual = nested_residual(rung.method, data, data.rate_dph - reference, scoring, shifted_columns(specs),
                                           splits, config.outside)  # as the model will be served beyond its range
        except InputError as error:  # too few rows for this rung: say so, climb on
            if log:
                log(f"ladder: {rung.name} skipped: {error}")
            continue
        drift, spread, per_fold = score(residual, groups, splits)
        scored.append(Scored(rung, specs, drift, spread, per_fold, time.perf_counter() - started, prepared))
        if log:
            log(f"ladder: {rung.name}: held-out drift {scored[-1].drift_rmse_dph:.4e} ± {spread:.2e} {unit} "
                f"({scored[-1].seconds:.1f} s); per fold {' '.join(f'{v:.3g}' for v in per_fold)}")  # fmt: skip
    if not scored:
        raise InputError("ladder: no model could be scored on these runs; record more or longer runs")
    chosen = choose(scored)
    rung = chosen.rung
    options = options_for_inputs(dataclasses.replace(config.fit, search=rung.search), chosen.inputs)
    final = dataclasses.replace(configs[rung.inputs_text], method=rung.method, fit=options)
    trained = (no_compensation(runs, final, chosen.prepared) if rung.method == NONE else
               fit_family(runs, final, chosen.prepared, rung.method))  # fmt: skip
    n_runs = len(np.unique(groups))
    folds = (f"leave-one-run-out, {n_runs} runs" if n_runs >= MIN_RUNS_LEFT_OUT else
             f"{len(splits)} time folds ({config.fit.folds} stretches of each run, one at a time), {gap} blocks apart" if n_runs > 1 else
             f"{len(splits)} time folds of the run, {gap} blocks apart")  # fmt: skip
    return Ladder(scored, chosen, folds, trained, nothing_dph)
