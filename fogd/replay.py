"""Replay: a recorded run through the daemon's compensator, and the paper's table 4 for it."""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from fogd.allan import AllanResult, analyse
from fogd.compensator import Compensated, Compensator
from fogd.errors import InputError
from fogd.features import TRUE_ERROR_COLUMN, block_samples
from fogd.flags import Flag
from fogd.frozen import FrozenModel
from fogd.metrics import ErrorStats, block_means, detrended_stats
from fogd.runio import Run

CHUNK_ROWS = 1 << 18  # replay feeds the compensator in chunks, as the daemon does, to bound memory


def replay(model: FrozenModel, run: Run, *, chunk_rows: int = CHUNK_ROWS) -> Compensated:
    """Compensate a whole run, chunk by chunk, with the daemon's compensator."""
    compensator = Compensator(model, run.rate_hz)
    if run.rows <= compensator.bank.warmup:
        raise InputError(
            f"{run.path}: {run.rows} rows at {run.rate_hz:.6g} Hz is shorter than the model's estimator window "
            f"({compensator.bank.warmup + 1} rows)"
        )
    parts = [
        compensator.process(run.rate_dph[start : start + chunk_rows], run.temp_c[start : start + chunk_rows])
        for start in range(0, run.rows, chunk_rows)
    ]
    return Compensated(*(np.concatenate([getattr(part, name) for part in parts]) for name in (f.name for f in fields(Compensated))))


@dataclass
class ReplayTable:
    """Table 4 of the paper for one run: block-mean error before and after compensation."""

    before: ErrorStats
    after: ErrorStats
    best: ErrorStats | None  # with the simulator's true thermal error removed: the best any model could do
    blocks: int


def replay_table(run: Run, result: Compensated, block_s: float) -> ReplayTable:
    """Statistics of block means about the run's own mean, over warm rows with a valid rate and temperature."""
    block_n = block_samples(block_s, run.rate_hz)
    use = (result.flags & (Flag.WARMUP | Flag.RATE_INVALID | Flag.TEMP_INVALID)) == 0
    before, kept = block_means(run.rate_dph, use, block_n)
    after, _ = block_means(result.rate_comp_dph, use, block_n)
    best = None
    truth = run.extra.get(TRUE_ERROR_COLUMN)
    if truth is not None:
        best = detrended_stats(block_means(run.rate_dph - truth, use, block_n)[0])
    return ReplayTable(detrended_stats(before), detrended_stats(after), best, int(kept.sum()))


def allan_curves(run: Run, result: Compensated) -> dict[str, AllanResult]:
    """Overlapping Allan deviation of the rate before and after compensation (and with the simulator's true
    thermal error removed, when the run has it), over the warm rows with a valid rate and temperature.

    Flagged rows are dropped rather than bridged, so a run with gaps joins its valid stretches end to end."""
    use = (result.flags & (Flag.WARMUP | Flag.RATE_INVALID | Flag.TEMP_INVALID)) == 0
    if use.sum() < 3:
        raise InputError(f"{run.path}: fewer than 3 valid warm rows; no Allan deviation")
    curves = {
        "before compensation": analyse(run.rate_dph[use], run.rate_hz),
        "after compensation": analyse(result.rate_comp_dph[use], run.rate_hz),
    }
    truth = run.extra.get(TRUE_ERROR_COLUMN)
    if truth is not None:
        curves["true error removed"] = analyse((run.rate_dph - truth)[use], run.rate_hz)
    return curves
