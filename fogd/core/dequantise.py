"""A coarse temperature sensor's readings turned back into a continuous temperature, causally.

A sensor that reports whole degrees (a KVH) gives a staircase. The staircase's level is known only to half a
step, but each step is exact: when the reading changes from r to r', the sensor's temperature was crossing
(r + r') / 2 at that moment. The estimate runs from the last crossing, never leaving the reading's own band
(r +- resolution / 2), at one of two paces (`PACES`):
- "linear": along the slope between the last two crossings: on a steady ramp it is the ramp itself;
- "quadratic" (fogd-train's default since model files store it): along the parabola through the last three
  crossings of distinct levels (its pace and acceleration at the last one, from their divided differences),
  held at its turning point. A housing that slows down into a soak or turns round with a cycle makes the
  crossings ever further apart; the linear pace runs on past the turn, the parabola slows into it. On
  tools/accuracy_table.py's simulated whole-degree runs it halves the estimate's RMS error on the soak after
  a ramp, takes two fifths off it on the fast cycle and lowers the held-out drift of every run (seeds 1 and
  2, both coils; tools/dequantise_error.py, docs/how-it-works.md). Old files keep "linear": they were trained with it.
When the next crossing is overdue (the pace would have reached the next level), the temperature has slowed
down: the rate can be at most a step per elapsed time, and the estimate relaxes back towards the middle of
the band. A reading that steps back across the level just crossed (noise at a threshold, or a reversal) is
again an exact point in time: the estimate follows from it at the last pace, in the new direction. Before
the second crossing there is no pace and the estimate is the reading. Lags of the estimate (fogd.inputs)
then carry the coil's thermal state without the staircase's steps, which a model fitted on the staircase
reads as temperature rates.

Streaming (`Dequantiser.update`, any chunk size, O(1) per sample) and batch (`dequantise_batch`) run the
same per-sample recurrence in Python floats, so both give the same floats bit for bit whatever the chunking.

`smoothed_batch` is for fitting only, never served: the mean of the estimate run forwards and run backwards
in time. The causal estimate lags every ramp by a pace-dependent amount; fitted on it, a model learns the
calibration ramps' lag and misreads every faster history (errors in the variables). Backwards, the estimate
leads by much the same, so their mean sits close to the sensor's temperature on a ramp, and the fit sees
the temperature's own dynamics (tools/dequantise_error.py --fit smoothed).
"""

from __future__ import annotations

import numpy as np

# Sensors at least this coarse are dequantised by fogd-train's default: a KVH's whole degrees. A fine sensor
# (a DS18B20's 1/16 C) flickers between two readings at every threshold with its own noise, which breaks the
# crossings into bursts; its staircase is fine enough for the lags as it is.
COARSE_RESOLUTION_C = 0.5
# How the estimate runs between crossings: "linear", along the pace between the last two crossings (what
# version-4 model files without `dequantise_pace` were trained with), or "quadratic", along a parabola through
# the last three (fogd-train's default: it follows a ramp that speeds up or slows down, and turns round with a
# cycle; tools/dequantise_error.py).
PACES = ("linear", "quadratic")
DEFAULT_PACE = "quadratic"
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

    def __init__(self, resolution_c: float, rate_hz: float, pace: str = "linear") -> None:
        if not (resolution_c > 0 and rate_hz > 0):
            raise ValueError(f"resolution and data rate must be positive, got {resolution_c} C at {rate_hz} Hz")
        if pace not in PACES:
            raise ValueError(f"unknown dequantiser pace {pace!r}; known: {', '.join(PACES)}")
        self.resolution_c = float(resolution_c)
        self.rate_hz = float(rate_hz)
        self.pace = pace
        if pace == "quadratic":
            self.update_one = self._update_quadratic  # type: ignore[method-assign]
        self.reset()

    def reset(self) -> None:
        self._count = 0
        self._reading_c: float | None = None
        self._cross_t_s: float | None = None  # the last crossing's time and level
        self._cross_c = 0.0
        self._slope_cps = 0.0  # between the last two crossings of different levels
        # quadratic: the last three crossings (time, level) of distinct levels, oldest first, and the parabola's
        # pace and acceleration at the last of them
        self._points: list[tuple[float, float]] = []
        self._accel_cps2 = 0.0

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


    def _fit_parabola(self) -> None:
        """The pace and acceleration at the last crossing of the parabola through the last three (a line
        through two), from their divided differences."""
        points = self._points
        if len(points) < 2:
            self._slope_cps = self._accel_cps2 = 0.0
            return
        (t1, c1), (t2, c2) = points[-2], points[-1]
        slope2 = (c2 - c1) / (t2 - t1)
        if len(points) < 3:
            self._slope_cps, self._accel_cps2 = slope2, 0.0
            return
        t0, c0 = points[-3]
        accel = 2.0 * (slope2 - (c1 - c0) / (t1 - t0)) / (t2 - t0)
        self._slope_cps = slope2 + 0.5 * accel * (t2 - t1)
        self._accel_cps2 = accel

    def _update_quadratic(self, temp_c: float) -> float:
        t_s = self._count / self.rate_hz
        self._count += 1
        if self._reading_c is None:
            self._reading_c = temp_c
        elif temp_c != self._reading_c:
            level_c = 0.5 * (temp_c + self._reading_c)
            if self._points and abs(level_c - self._points[-1][1]) <= _SAME_LEVEL_C:
                # back across the level just crossed (noise at a threshold, or a reversal): the temperature is at
                # that level now, and runs on from it at the same pace in the reading's direction
                self._points[-1] = (t_s, level_c)
                self._fit_parabola()
                self._slope_cps = abs(self._slope_cps) * (1.0 if temp_c > level_c else -1.0)
                self._accel_cps2 = 0.0
            else:
                self._points = (self._points + [(t_s, level_c)])[-3:]
                self._fit_parabola()
            self._reading_c = temp_c
        if len(self._points) < 2:
            return temp_c
        cross_t_s, cross_c = self._points[-1]
        side = 1.0 if temp_c > cross_c else -1.0
        if self._slope_cps * side <= 0.0:
            return temp_c
        elapsed_s = t_s - cross_t_s
        if self._accel_cps2 * self._slope_cps < 0.0:  # slowing down: held at the parabola's turning point
            elapsed_s = min(elapsed_s, -self._slope_cps / self._accel_cps2)
        moved_c = side * (self._slope_cps * elapsed_s + 0.5 * self._accel_cps2 * elapsed_s * elapsed_s)
        progress = max(moved_c, 0.0) / self.resolution_c  # in steps
        share = progress if progress <= 1.0 else 0.5 + 0.5 / progress
        half_c = 0.5 * self.resolution_c
        return min(max(cross_c + side * self.resolution_c * share, temp_c - half_c), temp_c + half_c)


def dequantise_batch(temp_c: np.ndarray, resolution_c: float, rate_hz: float, pace: str = "linear") -> np.ndarray:
    """The estimate over a whole run (the streaming form fed in one chunk)."""
    return Dequantiser(resolution_c, rate_hz, pace).update(temp_c)


def smoothed_batch(temp_c: np.ndarray, resolution_c: float, rate_hz: float, pace: str = "linear") -> np.ndarray:
    """Offline, for fitting: the mean of the estimate forwards and the estimate backwards in time."""
    temp_c = np.asarray(temp_c, dtype=np.float64)
    forwards = dequantise_batch(temp_c, resolution_c, rate_hz, pace)
    backwards = dequantise_batch(temp_c[::-1], resolution_c, rate_hz, pace)[::-1]
    return 0.5 * (forwards + backwards)
