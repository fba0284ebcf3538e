"""Block means and the paper's error statistics (RMSE and maximum error of block means, tables 3 and 4)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ErrorStats:
    """RMSE and maximum absolute value of a set of errors, in deg/h."""

    rmse_dph: float
    max_dph: float

    @classmethod
    def of(cls, errors_dph: np.ndarray) -> "ErrorStats":
        errors_dph = np.asarray(errors_dph, dtype=np.float64)
        if errors_dph.size == 0:
            return cls(float("nan"), float("nan"))
        return cls(float(np.sqrt(np.mean(errors_dph**2))), float(np.max(np.abs(errors_dph))))

    @classmethod
    def about_run_means(cls, errors_dph: np.ndarray, runs: np.ndarray) -> "ErrorStats":
        """Statistics of the errors about each run's own mean: the drift, without the run-to-run turn-on bias
        that no temperature model predicts (table 3 on several runs, as table 4 is on one)."""
        return cls.of(centred_within_runs(errors_dph, runs))

    def to_dict(self) -> dict[str, float]:
        return {"rmse_dph": self.rmse_dph, "max_dph": self.max_dph}


def centred_within_runs(values: np.ndarray, runs: np.ndarray | None) -> np.ndarray:
    """A copy of `values` (rows, or rows x columns) with each run's own mean taken off (one run when None)."""
    out = np.array(values, dtype=np.float64, copy=True)
    runs = np.zeros(len(out), dtype=np.int64) if runs is None else np.asarray(runs)
    for run in np.unique(runs):
        rows = runs == run
        out[rows] -= out[rows].mean(axis=0)
    return out


def block_means(values: np.ndarray, use: np.ndarray, block_n: int) -> tuple[np.ndarray, np.ndarray]:
    """Means of `values` over consecutive blocks of `block_n` samples, counting only rows where `use`.

    Returns (means, kept): a trailing partial block is dropped, and so is a block with fewer than half of its
    rows usable. `values` may be (n,) or (n, d).
    """
    blocks = values.shape[0] // block_n
    if blocks == 0:
        return np.empty((0,) + values.shape[1:]), np.empty(0, dtype=bool)
    cut = blocks * block_n
    weights = use[:cut].reshape(blocks, block_n).astype(np.float64)
    counts = weights.sum(axis=1)
    kept = counts >= block_n / 2
    shaped = np.where(use[:cut, None] if values.ndim > 1 else use[:cut], values[:cut], 0.0)
    sums = shaped.reshape((blocks, block_n) + values.shape[1:]).sum(axis=1)
    denominator = counts.reshape((-1,) + (1,) * (values.ndim - 1))
    with np.errstate(invalid="ignore", divide="ignore"):
        means = sums / denominator
    return means[kept], kept


def detrended_stats(block_means_dph: np.ndarray) -> ErrorStats:
    """Table-4 statistics of a run's block means about their own mean (a run's constant bias is not thermal)."""
    return ErrorStats.of(block_means_dph - np.mean(block_means_dph)) if block_means_dph.size else ErrorStats.of([])
