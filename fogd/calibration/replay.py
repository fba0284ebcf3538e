"""Replay: a recorded run through the daemon's compensator, and the paper's table 4 for it on the run's one
block grid (the same blocks for every model compared on the run). An IMU run's channels go through the
channel compensator (`replay_channels`), each then tabled as a single-channel run (Run.channel)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields

import numpy as np

from fogd.calibration.allan import AllanResult, analyse
from fogd.core.channels import ChannelCompensator
from fogd.core.columns import TRUE_ERROR_COLUMN, block_samples
from fogd.core.compensator import Compensated, Compensator
from fogd.core.errorstats import ErrorStats, block_means, detrended_stats
from fogd.core.flags import Flag
from fogd.core.frozen import FrozenModel
from fogd.core.runio import Run
from fogd.errors import InputError

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


def replay_channels(models: Mapping[str, FrozenModel], run: Run, *, chunk_rows: int = CHUNK_ROWS) -> dict[str, Compensated]:
    """Compensate every channel of `models` in a whole IMU run, chunk by chunk, with the channel compensator."""
    missing = [channel for channel in models if channel not in run.channels]
    if missing:
        raise InputError(f"{run.path}: the model compensates {', '.join(models)}; the run has no {', '.join(missing)} "
                         f"(it has {', '.join(run.channels)})")  # fmt: skip
    compensator = ChannelCompensator(models, run.rate_hz)
    if run.rows <= compensator.warmup:
        raise InputError(
            f"{run.path}: {run.rows} rows at {run.rate_hz:.6g} Hz is shorter than the model's estimator window "
            f"({compensator.warmup + 1} rows)"
        )
    parts = [
        compensator.process({channel: run.channels[channel][start : start + chunk_rows] for channel in models},
                            run.temp_c[start : start + chunk_rows])
        for start in range(0, run.rows, chunk_rows)
    ]  # fmt: skip
    names = [f.name for f in fields(Compensated)]
    return {
        channel: Compensated(*(np.concatenate([getattr(part[channel], name) for part in parts]) for name in names))
        for channel in models
    }


SETTLE_S = 600.0  # thermal settling at the start of a run that an accuracy comparison skips
_INVALID = Flag.RATE_INVALID | Flag.TEMP_INVALID


@dataclass(frozen=True)
class BlockGrid:
    """The rows table 4 averages for one run: blocks of `block_n` rows from `start` on, counting the rows in
    `rows`. It depends on the run alone (its invalid rates and temperatures), never on the model, so every
    scheme compared on a run is scored on the same blocks; warm-up rows count (they are compensated by the
    warm-up policy)."""

    start: int  # first row of the first block
    block_n: int
    rows: np.ndarray  # bool, one per row of the run: True where a row enters a block mean
    settle_s: float  # the settling skipped: as asked, or 0 when the run is too short for one block after it
    settle_fallback: bool  # True when the asked settling left no block and the grid starts at the first row

    @property
    def blocks(self) -> int:
        return int(block_means(self.rows[self.start :], self.rows[self.start :], self.block_n)[1].sum())

    def means(self, values: np.ndarray) -> np.ndarray:
        """Block means of a per-row series (the rate, the compensated rate, the time) on this grid."""
        return block_means(values[self.start :], self.rows[self.start :], self.block_n)[0]

    def share(self, flags: np.ndarray, flag: Flag) -> float:
        """Fraction of the grid's rows with `flag` set (NaN for an empty grid)."""
        used = int(np.count_nonzero(self.rows))
        return int(np.count_nonzero(flags[self.rows] & flag)) / used if used else float("nan")


def block_grid(run: Run, flags: np.ndarray, block_s: float, settle_s: float = SETTLE_S) -> BlockGrid:
    """Blocks of `block_s` starting `settle_s` after the run's first row, over the rows whose rate and
    temperature are valid (not flagged RATE_INVALID or TEMP_INVALID); `flags` are the compensator's for the run.
    A run too short for one block after `settle_s` is gridded from its first row instead (`settle_fallback`)."""
    block_n = block_samples(block_s, run.rate_hz)
    valid = (flags & _INVALID) == 0  # rows before the first valid temperature are TEMP_INVALID too
    fallback = False
    for start in (int(round(settle_s * run.rate_hz)), 0):
        use = valid[start:]
        kept = block_means(use, use, block_n)[1]
        if kept.any() or start == 0:
            break
        fallback = True
    rows = np.zeros(run.rows, dtype=bool)
    if kept.size:
        in_kept = np.repeat(kept, block_n)
        rows[start : start + in_kept.size] = use[: in_kept.size] & in_kept
    return BlockGrid(start, block_n, rows, 0.0 if fallback else float(settle_s), fallback)


@dataclass
class ReplayTable:
    """Table 4 of the paper for one run: block-mean error before and after compensation, on the run's grid."""

    before: ErrorStats
    after: ErrorStats
    best: ErrorStats | None  # with the simulator's true thermal error removed: the best any model could do
    blocks: int
    settle_s: float  # the settling skipped at the start of the run (0 after a fallback)
    settle_fallback: bool  # the run was too short for one block after the asked settling: blocks start at row 0
    fallback_share: float  # fraction of the grid's rows flagged OUT_OF_DOMAIN (the linear fallback was used)
    clamped_share: float  # fraction of the grid's rows flagged CLAMPED
    grid: BlockGrid = field(repr=False)


def replay_table(run: Run, result: Compensated, block_s: float, *, settle_s: float = SETTLE_S) -> ReplayTable:
    """Statistics of block means about the run's own mean, on the run's block grid (`block_grid`)."""
    grid = block_grid(run, result.flags, block_s, settle_s)
    best = None
    truth = run.extra.get(TRUE_ERROR_COLUMN)
    if truth is not None:
        best = detrended_stats(grid.means(run.rate_dph - truth))
    return ReplayTable(
        before=detrended_stats(grid.means(run.rate_dph)),
        after=detrended_stats(grid.means(result.rate_comp_dph)),
        best=best,
        blocks=grid.blocks,
        settle_s=grid.settle_s,
        settle_fallback=grid.settle_fallback,
        fallback_share=grid.share(result.flags, Flag.OUT_OF_DOMAIN),
        clamped_share=grid.share(result.flags, Flag.CLAMPED),
        grid=grid,
    )


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
