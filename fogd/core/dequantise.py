"""A coarse temperature sensor's readings turned back into a continuous temperature, causally.

A sensor that reports whole degrees (a KVH) gives a staircase. The staircase's level is known only to half a
step, but each step is exact: when the reading changes from r to r', the sensor's temperature was crossing
(r + r') / 2 at that moment. The estimate runs through the last crossing level along the slope between the
last two crossings, never leaving the reading's own band (r +- resolution / 2): on a steady ramp it is the
ramp itself. When the next crossing is overdue (later than the last interval), the temperature has slowed
down: the rate can be at most a step per elapsed time, and the estimate relaxes back towards the middle of
the band. A reading that steps back across the level just crossed (noise at a threshold, or a reversal) is
again an exact point in time: the estimate follows from it at the last pace, in the new direction. Before
the second crossing there is no pace and the estimate is the reading. Lags of the estimate (fogd.inputs) then carry the coil's thermal
state without the staircase's steps, which a model fitted on the staircase reads as temperature rates.

Streaming (`Dequantiser.update`, any chunk size, O(1) per sample) and batch (`dequantise_batch`) run the
same per-sample recurrence in Python floats, so both give the same floats bit for bit whatever the chunking.
"""

from __future__ import annotations

import numpy as np

# Sensors at least this coarse are dequantised by fogd-train's default: a KVH's whole degrees. A fine sensor
# (a DS18B20's 1/16 C) flickers between two readings at every threshold with its own noise, which breaks the
# crossings into bursts; its staircase is fine enough for the lags as it is.
COARSE_RESOLUTION_C = 0.5
_SAME_LEVEL_C = 1e-9
_QUANTILE = 5.0  # percent of the smallest nonzero steps: one odd small step does not set the resolution


def detect_resolution_c(runs_temp_c: list[np.ndarray]) -> float:
    """The sensor's resolution seen in calibration runs: the size of its smallest common step (5th percentile
    of the nonzero changes between successive finite readings), 0 if the readings never change."""
    steps = []
    for temp_c in runs_temp_c:
        temp_c = np.asarray(temp_c, dtype=np.float64)
        temp_c = temp_c[np.isfinite(temp_c)]
        change = np.abs(np.diff(temp_c))
        steps.append(change[change > _SAME_LEVEL_C])
    steps_c = np.concatenate(steps) if steps else np.empty(0)
    return float(np.percentile(steps_c, _QUANTILE)) if steps_c.size else 0.0


class Dequantiser:
    """The estimate, streaming: feed finite temperature readings (held at the data rate) in chunks."""

    def __init__(self, resolution_c: float, rate_hz: float) -> None:
        if not (resolution_c > 0 and rate_hz > 0):
            raise ValueError(f"resolution and data rate must be positive, got {resolution_c} C at {rate_hz} Hz")
        self.resolution_c = float(resolution_c)
        self.rate_hz = float(rate_hz)
        self.reset()

    def reset(self) -> None:
        self._count = 0
        self._reading_c: float | None = None
        self._cross_t_s: float | None = None  # the last crossing's time and level
        self._cross_c = 0.0
        self._slope_cps = 0.0  # between the last two crossings of different levels

    def update(self, temp_c: np.ndarray) -> np.ndarray:
        temp_c = np.atleast_1d(np.asarray(temp_c, dtype=np.float64))
        return np.array([self.update_one(value) for value in temp_c.tolist()], dtype=np.float64)

    def update_one(self, temp_c: float) -> float:
        """Feed one reading; the estimate, the same float `update` gives."""
        t_s = self._count / self.rate_hz
        self._count += 1
        if self._reading_c is None:
            self._reading_c = temp_c
        elif temp_c != self._reading_c:
            level_c = 0.5 * (temp_c + self._reading_c)
            if self._cross_t_s is not None and abs(level_c - self._cross_c) > _SAME_LEVEL_C:
                self._slope_cps = (level_c - self._cross_c) / (t_s - self._cross_t_s)
            elif self._cross_t_s is not None:  # back across the same level: it turned round, at the same pace
                self._slope_cps = abs(self._slope_cps) * (1.0 if temp_c > level_c else -1.0)
            self._cross_t_s, self._cross_c = t_s, level_c
            self._reading_c = temp_c
        if self._cross_t_s is None:
            return temp_c
        side = 1.0 if temp_c > self._cross_c else -1.0
        if self._slope_cps * side <= 0.0:
            return temp_c
        progress = abs(self._slope_cps) * (t_s - self._cross_t_s) / self.resolution_c  # in steps
        share = progress if progress <= 1.0 else 0.5 + 0.5 / progress
        estimate_c = self._cross_c + side * self.resolution_c * share
        half_c = 0.5 * self.resolution_c  # a reading that skipped a level: its own band still holds
        return min(max(estimate_c, temp_c - half_c), temp_c + half_c)


def dequantise_batch(temp_c: np.ndarray, resolution_c: float, rate_hz: float) -> np.ndarray:
    """The estimate over a whole run (the streaming form fed in one chunk)."""
    return Dequantiser(resolution_c, rate_hz).update(temp_c)
