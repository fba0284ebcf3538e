"""Domain guard: is a sample near the calibration data, and what to do if not.

Two kinds (`GUARD_KINDS`), stored in the model file:
- "range" (fogd-train's for a model with a lag bank, a dequantised estimate or a play operator among its
  inputs): a sample is OUT_OF_DOMAIN when any input leaves the calibration blocks' range by more than the
  margin `threshold` (in scaled units). The temperatures (the sensor's and its lags) share one range, the
  calibrated temperature range: a slow lag covers less of it in calibration than the sensor does (it never
  reaches the end of a soak) and is no less a temperature. A lag of a temperature inside that range stays
  inside it, so a run inside the calibrated temperature range (and, for
  an eq. 16 rate input, its rates) is served by the model whatever its history; one that goes beyond it
  (hotter, colder, faster) takes the fallback. The joint distance below cannot serve such inputs: the
  calibration runs are a few trajectories through a bank of nine inputs, and every other temperature
  history is far from all of them (63.5 % of the accuracy table's held-out samples fell back, most of them
  inside the calibrated range).
- "joint" (the paper's inputs, temperature and eq. 16 rates, and every file without a `kind`): the nearest
  calibration block in the joint input space.

Joint: a clamp per input (fogd.core.frozen) lets through combinations no calibration run had: hot *and* cooling fast when
calibration only heated at that temperature. The guard keeps the calibration blocks' input rows (at most
`MAX_POINTS`, in the model's scaled units: each input divided by its training std) and a distance threshold.
A sample whose scaled input row is farther than the threshold from every kept block is OUT_OF_DOMAIN: the
compensator flags it and evaluates the fallback model for it instead, the linear (IEEE 952) model fitted to
the same blocks, which cannot run away the way a kernel or a 5th-order polynomial can far from its data.

Threshold: `THRESHOLD_FACTOR` times the `THRESHOLD_QUANTILE` quantile of the distances from the calibration
runs' own samples (inputs as the daemon computes them, sample by sample, noisier than the block means) to
their nearest kept block, and at least that factor times the largest gap between neighbouring blocks. So the
calibration runs themselves are (almost) never out of domain. It is stored in the model file.

Range: the margin is `THRESHOLD_FACTOR` times the `THRESHOLD_QUANTILE` quantile of the calibration samples'
excursions beyond the blocks' range (in scaled units, the largest over the inputs), and at least
`MIN_RANGE_MARGIN` (a tenth of each input's calibration std).

Cost: a brute-force distance to every kept block, O(MAX_POINTS * inputs) per sample, vectorised per batch
(a column at a time, so a row's result never depends on the batch it came in: the daemon equals replay).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

MAX_POINTS = 400
THRESHOLD_FACTOR = 2.0
THRESHOLD_QUANTILE = 0.999
GUARD_KINDS = ("joint", "range")
MIN_RANGE_MARGIN = 0.1
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


def range_excursion(xs: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """How far each row of xs leaves the box [low, high], in the largest of its columns (0 inside; NaN
    rows give NaN)."""
    return np.maximum(np.maximum(xs - high, low - xs).max(axis=1), 0.0)  # NaN propagates


def range_box(points: np.ndarray, x_mean: np.ndarray, x_scale: np.ndarray, shared: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """The points' smallest and largest value per input (scaled units), the `shared` inputs (the
    temperatures) all given the union of their ranges in raw units."""
    low, high = points.min(axis=0) * x_scale + x_mean, points.max(axis=0) * x_scale + x_mean
    if shared:
        columns = list(shared)
        low[columns], high[columns] = low[columns].min(), high[columns].max()
    return (low - x_mean) / x_scale, (high - x_mean) / x_scale


def choose_range_margin(low: np.ndarray, high: np.ndarray, samples: np.ndarray | None = None,
                        factor: float = THRESHOLD_FACTOR) -> float:  # fmt: skip
    """`factor` times the `THRESHOLD_QUANTILE` quantile of the samples' excursions beyond [low, high] (scaled
    units), and at least `MIN_RANGE_MARGIN`."""
    largest = 0.0
    if samples is not None and len(samples):
        excursion = range_excursion(samples, low, high)
        finite = excursion[np.isfinite(excursion)]
        largest = float(np.quantile(finite, THRESHOLD_QUANTILE)) if finite.size else 0.0
    return max(factor * largest, MIN_RANGE_MARGIN)


@dataclass(frozen=True)
class DomainGuard:
    """Calibration block rows (scaled units), the threshold (a distance or a margin), the fallback model and
    the guard's kind."""

    points: np.ndarray
    threshold: float
    x_mean: np.ndarray
    x_scale: np.ndarray
    fallback: object  # a fogd.core.frozen.FrozenModel (the linear fit on the same blocks)
    kind: str = "joint"
    shared: tuple[int, ...] = ()  # range: the inputs that share one range (the temperatures)

    def outside(self, x: np.ndarray) -> np.ndarray:
        """True for raw input rows beyond the threshold: from every calibration block (joint), or beyond
        the blocks' range (range)."""
        from fogd.core.frozen import unique_rows

        x = np.asarray(x, dtype=np.float64).reshape(-1, self.points.shape[1])
        if self.kind == "range":
            low, high = self._box
            excursion = range_excursion((x - self.x_mean) / self.x_scale, low, high)
            return ~(excursion <= self.threshold)  # NaN rows count as outside
        if len(x) >= 64:  # quantised temperatures repeat: evaluate each distinct row once (exact)
            rows, inverse = unique_rows(x)
            return self._outside(rows)[inverse]
        return self._outside(x)

    def outside_one(self, x: tuple[float, ...]) -> bool:
        """`outside` of one raw input row (the daemon's row path): the same answer; a range guard in Python
        floats, the very operations of `range_excursion` (the margin is positive, so no column beyond it is
        the same as the largest excursion within it), without a numpy call per row."""
        if self.kind != "range":
            return bool(self.outside(np.array(x))[0])
        threshold = self.threshold
        for value, mean, scale, low, high in zip(x, *self._range_columns):
            scaled = (value - mean) / scale
            if not (scaled - high <= threshold and low - scaled <= threshold):  # NaN is outside
                return True
        return False

    @cached_property
    def _box(self) -> tuple[np.ndarray, np.ndarray]:
        return range_box(self.points, self.x_mean, self.x_scale, self.shared)

    @cached_property
    def _range_columns(self) -> tuple[list[float], ...]:
        """Per input as Python floats: mean, scale and the box's low and high (scaled units)."""
        low, high = self._box
        return self.x_mean.tolist(), self.x_scale.tolist(), low.tolist(), high.tolist()

    def _outside(self, x: np.ndarray) -> np.ndarray:
        distance = nearest_distance((x - self.x_mean) / self.x_scale, self.points)
        return ~(distance <= self.threshold)  # NaN rows count as outside
