"""Training rows from calibration runs: model inputs and thermal-error targets as block means.

Inputs come from the very code the daemon runs (temperature hold, eq. 16 estimator) in its batch form;
targets are block means of the rate (200 s by default, fogd.core.columns.FIT_BLOCK_S; the paper's 100 s
blocks remain those of every held-out table) minus a reference. Blocks start after
each run's warm-up and never straddle two runs. One deliberate exception: a coarse sensor's dequantised
temperature may be fitted from its offline estimate (`smoothed`, fogd.core.dequantise.smoothed_batch), which
the daemon cannot compute; the causal estimate's pace-dependent lag would otherwise be learnt as physics.

The channels of one IMU run share its temperature, hence its inputs: `run_inputs` computes them once and
`shared_inputs` hands them to every channel's training (fogd.calibration.channels), so that six channels
do not filter the same temperature six times.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from fogd.core.columns import TRUE_ERROR_COLUMN, block_samples
from fogd.core.compensator import hold_temperature, temperature_valid
from fogd.core.errorstats import block_means
from fogd.core.inputs import InputSpec, dequantises, inputs_batch, warmup_samples
from fogd.core.runio import Run
from fogd.errors import InputError

SAMPLE_ROWS_PER_RUN = 5000  # sample-level input rows kept per run (the domain guard's threshold uses them)


@dataclass
class TrainingSet:
    """Block rows from one or more runs, ready for a model fit."""

    x: np.ndarray  # (blocks, inputs) block means of the model inputs
    rate_dph: np.ndarray  # (blocks,) block means of the measured rate
    groups: np.ndarray  # (blocks,) index of the run each block came from
    block_t_s: np.ndarray  # (blocks,) time of each block's centre within its run
    domain_min: np.ndarray  # per-input range seen sample by sample in the warm rows: the calibrated domain
    domain_max: np.ndarray
    true_error_dph: np.ndarray | None = None  # block means of the simulator's truth, when every run has it
    runs: list[dict] = field(default_factory=list)
    x_samples: np.ndarray | None = None  # evenly strided warm sample rows (inputs as served, not block means)


# (an input set, smoothed) -> its (rows from the first valid temperature, inputs)
Inputs = dict[tuple[tuple[InputSpec, ...], bool], np.ndarray]
_SHARED: dict[int, tuple[np.ndarray, Inputs]] = {}  # id(temp_c) -> (that temp_c, its inputs by input set)


def run_inputs(run: Run, sets: list[tuple[InputSpec, ...]], smoothed: bool = False) -> Inputs:
    """The run's inputs for each input set, from its first valid temperature on (the temperature held over
    invalid readings), as training uses them: as served and, with `smoothed`, as fitted."""
    temp_ok = temperature_valid(run.temp_c)
    if not temp_ok.any():
        raise InputError(f"{run.path}: no valid temperature in the whole run")
    first = int(np.argmax(temp_ok))
    temp_c = hold_temperature(run.temp_c[first:], temp_ok[first:])
    keys = [(specs, False) for specs in sets] + [(specs, True) for specs in sets if smoothed and dequantises(specs)]
    return {key: inputs_batch(temp_c, key[0], run.rate_hz, key[1]) for key in dict.fromkeys(keys)}


@contextmanager
def shared_inputs(runs: list[Run], inputs: list[Inputs]) -> Iterator[None]:
    """Within the block, `training_set` takes each run's inputs from `inputs` (`run_inputs` of the same
    temperatures) instead of computing them again: a run is known by its very temp_c array, which every
    channel view of an IMU run (Run.channel) shares."""
    keys = [id(run.temp_c) for run in runs]
    _SHARED.update({key: (run.temp_c, given) for key, run, given in zip(keys, runs, inputs)})
    try:
        yield
    finally:
        for key in keys:
            _SHARED.pop(key, None)


def _inputs(run: Run, temp_c: np.ndarray, specs: tuple[InputSpec, ...], smoothed: bool) -> np.ndarray:
    shared = _SHARED.get(id(run.temp_c))
    if shared is not None and shared[0] is run.temp_c and (specs, smoothed) in shared[1]:
        return shared[1][specs, smoothed]
    return inputs_batch(temp_c, specs, run.rate_hz, smoothed)


def training_set(runs: list[Run], specs: tuple[InputSpec, ...], block_s: float, min_warmup_s: float = 0.0,
                 smoothed: bool = False) -> TrainingSet:  # fmt: skip
    """Build the block rows of all runs; raises InputError if a run is too short to give any.

    `min_warmup_s` starts the blocks at least that late in each run, so that input sets with different
    estimator windows get the very same blocks and targets (`--method auto` compares them on those).
    `smoothed` fits a dequantised temperature's inputs from its offline estimate (fogd.core.dequantise.
    smoothed_batch); the calibrated domain and the sample rows stay as the daemon computes them."""
    parts = [_run_blocks(run, index, specs, block_s, min_warmup_s, smoothed) for index, run in enumerate(runs)]
    with_truth = all(part["truth"] is not None for part in parts)
    return TrainingSet(
        x=np.concatenate([part["x"] for part in parts]),
        rate_dph=np.concatenate([part["rate"] for part in parts]),
        groups=np.concatenate([np.full(len(part["rate"]), index) for index, part in enumerate(parts)]),
        block_t_s=np.concatenate([part["t"] for part in parts]),
        domain_min=np.min([part["low"] for part in parts], axis=0),
        domain_max=np.max([part["high"] for part in parts], axis=0),
        true_error_dph=np.concatenate([part["truth"] for part in parts]) if with_truth else None,
        runs=[part["info"] for part in parts],
        x_samples=np.concatenate([part["samples"] for part in parts]),
    )


def _run_blocks(run: Run, index: int, specs: tuple[InputSpec, ...], block_s: float, min_warmup_s: float,
                smoothed: bool) -> dict:  # fmt: skip
    warmup = max(warmup_samples(specs, run.rate_hz), int(round(min_warmup_s * run.rate_hz)))
    block_n = block_samples(block_s, run.rate_hz)
    temp_ok = temperature_valid(run.temp_c)
    if not temp_ok.any():
        raise InputError(f"{run.path}: no valid temperature in the whole run")
    first = int(np.argmax(temp_ok))
    temp_c = hold_temperature(run.temp_c[first:], temp_ok[first:])
    usable_rows = temp_c.size - warmup
    if usable_rows < block_n:
        raise InputError(
            f"{run.path}: {run.rows} rows at {run.rate_hz:.6g} Hz is too short: the estimator window needs "
            f"{warmup + 1} rows and one {block_s:g} s block {block_n} more"
        )
    x = _inputs(run, temp_c, specs, False)[warmup:]
    fitted = _inputs(run, temp_c, specs, True)[warmup:] if smoothed and dequantises(specs) else x
    rate = run.rate_dph[first + warmup :]
    use = temp_ok[first + warmup :] & np.isfinite(rate)
    x_blocks, kept = block_means(fitted, use, block_n)
    rate_blocks, _ = block_means(rate, use, block_n)
    if not kept.any():
        raise InputError(f"{run.path}: no {block_s:g} s block has at least half of its rows valid")
    centres = run.t_s[first + warmup + block_n // 2 :: block_n][: kept.size][kept]
    truth = run.extra.get(TRUE_ERROR_COLUMN)
    truth_blocks = None if truth is None else block_means(truth[first + warmup :], use, block_n)[0]
    return {
        "x": x_blocks,
        "rate": rate_blocks,
        "t": centres - run.t_s[0],
        "low": x[use].min(axis=0),
        "high": x[use].max(axis=0),
        "truth": truth_blocks,
        "samples": x[use][:: max(1, int(use.sum()) // SAMPLE_ROWS_PER_RUN)],
        "info": {
            "name": run.name,
            "sha256": run.sha256,
            "rows": run.rows,
            "nan_rows": run.nan_rows,
            "rate_hz": run.rate_hz,
            "blocks": int(kept.sum()),
            "index": index,
        },
    }
