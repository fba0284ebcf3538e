"""`fogd-train --method auto`: choose the model family and the input set by held-out error.

Every candidate (a family from `FAMILIES` on an input set from `DEFAULT_INPUT_SETS` or `--auto-inputs`) is
fitted to the very same blocks and targets (all input sets start their blocks after the longest estimator
window of any of them) and scored by the pooled RMSE on held-out folds: leave-one-run-out with several runs,
blocked time folds with one. Parsimony, because the tuned families' scores are slightly optimistic (their
hyper-parameters were chosen on the same folds) and extra inputs give more room to fit one run's history:
start from `linear` on the first input set; take the best candidate on that set if it beats linear by
`MARGIN` (relative); then take a candidate on a larger input set only if it beats the current choice by
`MARGIN` again. Otherwise the lowest held-out RMSE wins. Regularisation is tuned by
held-out error only: ls-poly's order (1..5), rbf-nn's L1 alpha, pso-svr's C, epsilon, sigma (cv fitness).

Cost: pso-svr runs with a smaller swarm inside auto (`AUTO_PARTICLES` x `AUTO_ITERATIONS`, 20 x 20 unless
`--particles/--iterations` are given explicitly) over `--jobs` workers; the other families take seconds.
The winner is the candidate's own fit (no refit), so its reported held-out RMSE is exactly that model's.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from dataclasses import dataclass

import numpy as np

from fogd.errors import InputError
from fogd.inputs import InputSpec, describe_inputs, parse_inputs
from fogd.models.least_squares import polynomial_terms
from fogd.training import TrainConfig, Trained, prepare, train

FAMILIES = ("linear", "ls-poly", "rbf-nn", "pso-svr")
DEFAULT_INPUT_SETS = ("temp,rate@50", "temp,rate@50,rate@300", "temp,rate@50,lag@600")
AUTO_PARTICLES = 20
AUTO_ITERATIONS = 20
MAX_DEGREE = 5
MARGIN = 0.02


@dataclass
class Candidate:
    method: str
    inputs: tuple[InputSpec, ...]
    held_out_rmse_dph: float
    hyperparameters: dict
    seconds: float
    trained: Trained | None = None

    @property
    def label(self) -> str:
        return f"{self.method} [{describe_inputs(self.inputs)}]"

    def row(self) -> dict:
        return {
            "method": self.method,
            "inputs": describe_inputs(self.inputs),
            "held_out_rmse_dph": self.held_out_rmse_dph,
            "hyperparameters": {k: v for k, v in self.hyperparameters.items() if isinstance(v, (int, float, str))},
            "seconds": round(self.seconds, 2),
        }


def input_sets(texts: list[str] | None, average_s: float, step_s: float) -> list[tuple[InputSpec, ...]]:
    return [parse_inputs(text, average_s, step_s) for text in (texts or DEFAULT_INPUT_SETS)]


def select(runs, config: TrainConfig, sets: list[tuple[InputSpec, ...]], families=FAMILIES,
           log=None) -> tuple[Candidate, list[Candidate]]:  # fmt: skip
    """Fit every candidate, return (the chosen one, all of them in order)."""
    common_s = max(
        (spec.estimator.window_s for specs in sets for spec in specs if spec.estimator is not None), default=0.0
    )
    candidates: list[Candidate] = []
    for specs in sets:
        set_config = dataclasses.replace(config, inputs=specs)
        prepared = prepare(runs, set_config, min_warmup_s=common_s)
        for method in families:
            started = time.perf_counter()
            try:
                trained = _fit_family(runs, set_config, prepared, method)
            except InputError as error:  # too few rows for this family: say so, keep going
                if log:
                    log(f"auto: {method} [{describe_inputs(specs)}] skipped: {error}")
                continue
            candidate = Candidate(method, specs, float(trained.fitted.cv_rmse_dph), trained.fitted.hyperparameters,
                                  time.perf_counter() - started, trained)  # fmt: skip
            candidates.append(candidate)
            if log:
                log(f"auto: {candidate.label}: held-out RMSE {candidate.held_out_rmse_dph:.4e} deg/h "
                    f"({candidate.seconds:.1f} s)")  # fmt: skip
    if not candidates:
        raise InputError("auto: no candidate could be fitted; record more or longer runs")
    return choose(candidates), candidates


def choose(candidates: list[Candidate]) -> Candidate:
    """The parsimonious choice (module docstring): each step up in complexity must win by MARGIN."""
    chosen = candidates[0]
    for inputs in dict.fromkeys(c.inputs for c in candidates):  # input sets in the order given
        best = min((c for c in candidates if c.inputs == inputs), key=lambda c: c.held_out_rmse_dph)
        if best.held_out_rmse_dph < (1.0 - MARGIN) * chosen.held_out_rmse_dph:
            chosen = best
    return chosen


def _fit_family(runs, config: TrainConfig, prepared, method: str) -> Trained:
    config = dataclasses.replace(config, method=method)
    if method != "ls-poly":
        return train(runs, config, prepared)
    # the polynomial's order is its regularisation: the one with the lowest held-out RMSE
    best: Trained | None = None
    for degree in range(1, MAX_DEGREE + 1):
        if polynomial_terms(len(config.inputs), degree) + 1 > _smallest_training_fold(prepared[0].groups):
            break
        trial = train(runs, dataclasses.replace(config, fit=dataclasses.replace(config.fit, degree=degree)), prepared)
        if best is None or trial.fitted.cv_rmse_dph < best.fitted.cv_rmse_dph:
            best = trial
    if best is None:
        raise InputError("too few block rows for a polynomial")
    return best


def _smallest_training_fold(groups: np.ndarray) -> int:
    runs, counts = np.unique(groups, return_counts=True)
    return int(groups.size - counts.max()) if runs.size >= 2 else int(groups.size * 0.8)


def table_lines(candidates: list[Candidate], chosen: Candidate, markdown: bool = False) -> list[str]:
    """The selection table: every candidate's held-out RMSE, relative to linear on the first input set."""
    baseline = candidates[0].held_out_rmse_dph
    if markdown:
        lines = ["| Method | Inputs | Held-out RMSE (deg/h) | vs linear | Hyper-parameters | |", "|---|---|---:|---:|---|---|"]
    else:
        lines = [f"{'Method':<9} {'Inputs':<28} {'held-out RMSE':>14} {'vs linear':>9}  hyper-parameters"]
    for c in candidates:
        hyper = ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in c.hyperparameters.items()
                          if k in ("degree", "alpha", "centres", "C", "epsilon_dph", "sigma"))  # fmt: skip
        mark = "chosen" if c is chosen else ""
        ratio = c.held_out_rmse_dph / baseline
        if markdown:
            lines.append(f"| {c.method} | `{describe_inputs(c.inputs)}` | {c.held_out_rmse_dph:.3e} | {ratio:.3f} | {hyper or '-'} | {mark} |")
        else:
            lines.append(f"{c.method:<9} {describe_inputs(c.inputs):<28} {c.held_out_rmse_dph:>14.3e} {ratio:>9.3f}  {hyper}"
                         + (f"  <- {mark}" if mark else ""))  # fmt: skip
    return lines


def stderr_log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)
