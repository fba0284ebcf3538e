"""Domain guard in the joint input space: is a sample near the calibration data, and what to do if not.

A clamp per input (fogd.core.frozen) lets through combinations no calibration run had: hot *and* cooling fast when
calibration only heated at that temperature. The guard keeps the calibration blocks' input rows (at most
`MAX_POINTS`, in the model's scaled units: each input divided by its training std) and a distance threshold.
A sample whose scaled input row is farther than the threshold from every kept block is OUT_OF_DOMAIN: the
compensator flags it and evaluates the fallback model for it instead, the linear (IEEE 952) model fitted to
the same blocks, which cannot run away the way a kernel or a 5th-order polynomial can far from its data.

Threshold: `THRESHOLD_FACTOR` times the `THRESHOLD_QUANTILE` quantile of the distances from the calibration
runs' own samples (inputs as the daemon computes them, sample by sample, noisier than the block means) to
their nearest kept block, and at least that factor times the largest gap between neighbouring blocks. So the
calibration runs themselves are (almost) never out of domain. It is stored in the model file.

Cost: a brute-force distance to every kept block, O(MAX_POINTS * inputs) per sample, vectorised per batch
(a column at a time, so a row's result never depends on the batch it came in: the daemon equals replay).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MAX_POINTS = 400
THRESHOLD_FACTOR = 2.0
THRESHOLD_QUANTILE = 0.999
_CHUNK_ROWS = 4096


def thin(points: np.ndarray, max_points: int = MAX_POINTS) -> np.ndarray:
    """At most `max_points` rows, evenly strided (blocks are in time order, so this keeps the trajectory)."""
    if len(points) <= max_points:
        return points.copy()
    return points[np.linspace(0, len(points) - 1, max_points).round().astype(int)]


def nearest_distance(xs: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Euclidean distance from each row of xs to its nearest row of points, in bounded-memory chunks."""
    out = np.empty(xs.shape[0])
    for start in range(0, xs.shape[0], _CHUNK_ROWS):
        block = xs[start : start + _CHUNK_ROWS]
        squared = np.zeros((block.shape[0], points.shape[0]))
        for column in range(points.shape[1]):
            difference = block[:, column : column + 1] - points[:, column]
            squared += difference * difference
        out[start : start + _CHUNK_ROWS] = np.sqrt(squared.min(axis=1))
    return out


def choose_threshold(points: np.ndarray, samples: np.ndarray | None = None, factor: float = THRESHOLD_FACTOR) -> float:
    """`factor` times the larger of: the largest nearest-neighbour distance among the points, and the
    `THRESHOLD_QUANTILE` quantile of the samples' distances to the points (1.0 if both are 0)."""
    largest = 0.0
    if len(points) >= 2:
        squared = ((points[:, None, :] - points[None, :, :]) ** 2).sum(axis=2)
        np.fill_diagonal(squared, np.inf)
        largest = float(np.sqrt(squared.min(axis=1)).max())
    if samples is not None and len(samples):
        largest = max(largest, float(np.quantile(nearest_distance(samples, points), THRESHOLD_QUANTILE)))
    return factor * largest if largest > 0 else 1.0


@dataclass(frozen=True)
class DomainGuard:
    """Calibration block rows (scaled units), the distance threshold, and the fallback model."""

    points: np.ndarray
    threshold: float
    x_mean: np.ndarray
    x_scale: np.ndarray
    fallback: object  # a fogd.core.frozen.FrozenModel (the linear fit on the same blocks)

    def outside(self, x: np.ndarray) -> np.ndarray:
        """True for raw input rows farther than the threshold from every calibration block."""
        from fogd.core.frozen import unique_rows

        x = np.asarray(x, dtype=np.float64).reshape(-1, self.points.shape[1])
        if len(x) >= 64:  # quantised temperatures repeat: evaluate each distinct row once (exact)
            rows, inverse = unique_rows(x)
            return self._outside(rows)[inverse]
        return self._outside(x)

    def _outside(self, x: np.ndarray) -> np.ndarray:
        distance = nearest_distance((x - self.x_mean) / self.x_scale, self.points)
        return ~(distance <= self.threshold)  # NaN rows count as outside
