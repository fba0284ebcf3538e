"""The multi-data-window temperature-rate estimator (paper eq. 16, section 3.1), streaming and batch.

For sample i the window holds the last N samples; the rate is the mean of its newest m samples minus the mean
of its oldest m samples, divided by the time between the two averages, (N - m) / f. The paper writes the sums
with m + 1 terms but divides by m; we use m terms each, which is what its text describes. With a step l > 1
the estimate is recomputed every l samples and held in between (section 3.2).

Both forms work on temperatures quantised to `TEMP_LSB_C` (2**-24 C, far below any sensor's resolution) and
on prefix sums of those integers in wrapping int64 arithmetic. A window sum is a difference of two prefix
sums, exact whatever wrapped, so the streaming form never drifts: after any number of updates it returns the
very same floats as the batch form on the same window, bit for bit.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

TEMP_LSB_C = 2.0**-24
_INT64_WRAP = 1 << 64
_INT64_HALF = 1 << 63
TEMP_LIMIT_C = 1000.0  # |T| above this is not a temperature; callers flag it before it gets here
SCALAR_CHUNK = 16  # chunks up to this size go through `update_one`, which gives the same floats faster


@dataclass(frozen=True)
class EstimatorSettings:
    """Eq. 16 parameters in seconds, as stored in a model file; `samples()` turns them into N, m, l."""

    window_s: float = 50.0
    average_s: float = 0.5
    step_s: float = 0.0

    def samples(self, rate_hz: float) -> tuple[int, int, int]:
        """(N, m, l) at `rate_hz`: window, averaging window and step in samples (m and l at least 1)."""
        if not rate_hz > 0:
            raise ValueError(f"data rate must be positive, got {rate_hz} Hz")
        window = int(round(self.window_s * rate_hz))
        average = max(1, int(round(self.average_s * rate_hz)))
        step = max(1, int(round(self.step_s * rate_hz)))
        if window < 2 * average:
            raise ValueError(
                f"estimator window {self.window_s} s is {window} samples at {rate_hz:g} Hz; it must hold "
                f"at least two averaging windows of {average} samples ({self.average_s} s)"
            )
        return window, average, step

    def to_dict(self) -> dict[str, float]:
        return {key: float(value) for key, value in asdict(self).items()}


def quantise(temp_c: np.ndarray) -> np.ndarray:
    """Temperatures (finite, |T| <= TEMP_LIMIT_C) as int64 multiples of TEMP_LSB_C."""
    return np.rint(np.asarray(temp_c, dtype=np.float64) / TEMP_LSB_C).astype(np.int64)


def _scale(rate_hz: float, window: int, average: int) -> float:
    """Turns (newest sum - oldest sum) in LSB into C/s: eq. 16's 1/m * f/(N - m)."""
    return TEMP_LSB_C * rate_hz / (average * (window - average))


def _anchor(index: np.ndarray, window: int, step: int) -> np.ndarray:
    """The sample whose window is used for sample `index`: itself, or the last one on the step grid."""
    if step == 1:
        return index
    return index - (index - (window - 1)) % step


def temp_rate_batch(temp_c: np.ndarray, settings: EstimatorSettings, rate_hz: float) -> np.ndarray:
    """Eq. 16 over a whole run; samples before the window is full (warm-up) get 0.0 C/s."""
    window, average, step = settings.samples(rate_hz)
    q = quantise(temp_c)
    prefix = np.zeros(q.size + 1, dtype=np.int64)
    np.cumsum(q, out=prefix[1:])  # wraps on overflow; differences stay exact
    rate = np.zeros(q.size, dtype=np.float64)
    if q.size < window:
        return rate
    i = _anchor(np.arange(window - 1, q.size), window, step)
    newest = prefix[i + 1] - prefix[i + 1 - average]
    oldest = prefix[i - window + 1 + average] - prefix[i - window + 1]
    rate[window - 1 :] = (newest - oldest).astype(np.float64) * _scale(rate_hz, window, average)
    return rate


class TempRateEstimator:
    """Eq. 16, streaming: O(1) work and memory per sample, fed chunks of any size (1 included).

    Keeps the last N + l prefix sums in a ring buffer; each new sample adds one prefix sum and reads four.
    """

    def __init__(self, settings: EstimatorSettings, rate_hz: float) -> None:
        self.settings = settings
        self.rate_hz = float(rate_hz)
        self.window, self.average, self.step = settings.samples(rate_hz)
        self._scale = _scale(rate_hz, self.window, self.average)
        self._ring = np.zeros(self.window + self.step + 1, dtype=np.int64)  # prefix[j] at j % size
        self._size = self._ring.size
        self._last_prefix = np.zeros(1, dtype=np.int64)  # prefix[count]; an array so sums wrap silently
        self.count = 0  # samples seen

    @property
    def warm(self) -> bool:
        """True once the window is full and estimates are real."""
        return self.count >= self.window

    def reset(self) -> None:
        """Forget all history (a new run, or a gap the caller will not bridge)."""
        self._ring[:] = 0
        self._last_prefix[:] = 0
        self.count = 0

    def update(self, temp_c: np.ndarray) -> np.ndarray:
        """Feed the next samples; returns their rates in C/s (0.0 where the window is not yet full)."""
        temp_c = np.atleast_1d(temp_c)
        if temp_c.size <= SCALAR_CHUNK:  # a few samples (the daemon's usual batch): numpy's overhead would dominate
            values = np.asarray(temp_c, dtype=np.float64).ravel().tolist()
            if all(-TEMP_LIMIT_C <= value <= TEMP_LIMIT_C for value in values):  # (NaN is not)
                return np.array([self.update_one(value) for value in values], dtype=np.float64)
        q = quantise(temp_c)
        k = q.size
        first = self.count  # index of the first new sample
        new_prefix = np.cumsum(q) + self._last_prefix[0]  # prefix[first + 1 .. first + k]
        rate = np.zeros(k, dtype=np.float64)
        start = max(self.window - 1 - first, 0)  # first position in the chunk that is warm
        if start < k:
            i = _anchor(np.arange(first + start, first + k), self.window, self.step)
            newest = self._prefix_at(i + 1, first, new_prefix) - self._prefix_at(
                i + 1 - self.average, first, new_prefix
            )
            oldest = self._prefix_at(i - self.window + 1 + self.average, first, new_prefix) - self._prefix_at(
                i - self.window + 1, first, new_prefix
            )
            rate[start:] = (newest - oldest).astype(np.float64) * self._scale
        size = self._ring.size
        keep = min(k, size)
        self._ring[np.arange(first + k - keep + 1, first + k + 1) % size] = new_prefix[k - keep :]
        if k:
            self._last_prefix[0] = new_prefix[-1]
        self.count += k
        return rate

    def _prefix_at(self, j: np.ndarray, first: int, new_prefix: np.ndarray) -> np.ndarray:
        """prefix[j] from the ring (j <= first) or from this chunk's new prefix sums (j > first)."""
        old = j <= first
        out = np.empty(j.shape, dtype=np.int64)
        out[old] = self._ring[j[old] % self._ring.size]
        out[~old] = new_prefix[j[~old] - first - 1]
        return out

    def update_one(self, temp_c: float) -> float:
        """Feed one sample; its rate in C/s. The same float as `update` gives for a 1-element chunk, bit for bit
        (the same integer sums, in Python ints wrapped to int64), without numpy's per-call overhead."""
        q = round(temp_c / TEMP_LSB_C)  # the division is exact and round() is half-to-even, as np.rint
        first = self.count
        prefix = (self._last_prefix.item(0) + q + _INT64_HALF) % _INT64_WRAP - _INT64_HALF
        ring, size = self._ring, self._size
        ring[(first + 1) % size] = prefix
        self._last_prefix[0] = prefix
        self.count = first + 1
        window = self.window
        if first < window - 1:
            return 0.0
        i = first if self.step == 1 else first - (first - (window - 1)) % self.step
        average = self.average
        at = ring.item
        difference = (at((i + 1) % size) - at((i + 1 - average) % size)) - (
            at((i - window + 1 + average) % size) - at((i - window + 1) % size)
        )
        difference = (difference + _INT64_HALF) % _INT64_WRAP - _INT64_HALF  # the int64 the batch form ends with
        return float(difference) * self._scale
