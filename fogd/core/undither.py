"""A fine sensor's readings turned back into its temperature: the noise-dithered staircase, inverted, causally.

A sensor with small steps (a DS18B20's 1/16 C) and a little noise of its own reports a staircase that flickers
between two levels near each threshold. The mix of the two tells where between them the temperature is: the
expected reading is a rounded staircase of the true temperature, E(T) = sum_k k q P(round((T + noise) / q) = k)
for Gaussian noise of `noise_c` and steps of q. Averaged over a few seconds (a first-order lag of `tau_s`,
fogd.core.lag), the readings estimate E(T); its inverse, periodic in q, turns the average back into a
temperature without the staircase's plateaus and jumps, which a lag bank fitted on the readings reads as rates
(docs/results/fine-sensor.md: the weakly dithered staircase is what holds the diffusive coil's held-out drift).

The noise is the sensor's own; fogd-train chooses it on the calibration runs (fogd.calibration.training.
with_undither: the coil trend's residual on the calibration blocks has its least at the sensor's noise, and
the readings themselves stay a candidate). The lag's delay is the same at fit and serve time, so the fit
absorbs it.

Streaming (`Undither.update_one`, `update`, any chunk size, O(1) per sample) and batch (`undither_batch`) give
the same floats bit for bit: the lag runs one recurrence in both forms, and the inverse is a uniform table
read with the same float operations in the same order, in Python floats one sample at a time and in numpy
over an array.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from fogd.core.lag import MAX_TAU_S, LagFilter

# The lag that averages the readings before the inverse: a few sensor samples at a sensor's 1-4 Hz, short
# against the coil's dynamics (tools/trend_diagnostic.py --five-run --rate-prior smooth --seed 1 --thermal
# diffusive --case und:0.01:TAU/und:0.01:TAU, the sensor's noise known, worst held-out run: 1.25x the floor with
# 2.5 s, 1.27x with 5 s, 1.32x with 10 s; 1.45x on the readings).
DEFAULT_TAU_S = 2.5
# The noise a table is built for, in steps: below MIN the inverse of a near-bare staircase amplifies every
# flicker; above MAX the dithered staircase is a straight line and its inverse the identity.
MIN_NOISE_STEPS = 0.02
MIN_RESOLUTION_C = 1e-6  # finer steps are no staircase to undo (and a reading over them would overflow a float)
MAX_NOISE_STEPS = 2.0
TABLE_SIZE = 1024  # intervals of the inverse's uniform table over one step
_FINE_GRID = 8192  # points of E over one step, from which the table is read off


def expected_reading_steps(x_steps: np.ndarray, noise_steps: float) -> np.ndarray:
    """E(T) / q at T = x q (x in steps, within [0, 1] or near it): the mean of round(x + noise)."""
    reach = int(math.ceil(8.0 * noise_steps)) + 2
    out = np.zeros_like(np.asarray(x_steps, dtype=np.float64))
    # E(x) = sum over the thresholds k + 1/2 of P(x + noise > k + 1/2), less those below zero's
    for k in range(-reach, reach + 1):
        z = (np.asarray(x_steps) - (k + 0.5)) / (noise_steps * math.sqrt(2.0))
        above = 0.5 * (1.0 + np.array([math.erf(value) for value in z.ravel()]).reshape(z.shape))
        out += above - (1.0 if k < 0 else 0.0)
    return out


@functools.lru_cache(maxsize=64)
def inverse_table(noise_steps: float) -> tuple[float, ...]:
    """x (in steps, within [0, 1]) at E = j / TABLE_SIZE for j = 0..TABLE_SIZE: the inverse of one period of the
    dithered staircase, read off a fine grid (E rises monotonically from E(0) = 0 to E(1) = 1)."""
    if not MIN_NOISE_STEPS <= noise_steps <= MAX_NOISE_STEPS:
        raise ValueError(f"sensor noise must be {MIN_NOISE_STEPS:g} to {MAX_NOISE_STEPS:g} steps, got {noise_steps}")
    x = np.linspace(0.0, 1.0, _FINE_GRID + 1)
    expected = expected_reading_steps(x, noise_steps)
    expected = (expected - expected[0]) / (expected[-1] - expected[0])  # exactly 0 and 1 at the ends: periodic
    table = np.interp(np.linspace(0.0, 1.0, TABLE_SIZE + 1), expected, x)
    table[0], table[-1] = 0.0, 1.0
    return tuple(table.tolist())


class Undither:
    """The estimate, streaming: feed finite temperature readings (held at the data rate) in chunks."""

    def __init__(self, resolution_c: float, noise_c: float, tau_s: float, rate_hz: float) -> None:
        if not (resolution_c >= MIN_RESOLUTION_C and noise_c > 0 and 0 < tau_s <= MAX_TAU_S and rate_hz > 0):
            raise ValueError(f"undither needs a resolution of at least {MIN_RESOLUTION_C:g} C, a positive noise, "
                             f"a lag up to {MAX_TAU_S:g} s and a positive rate, "
                             f"got {resolution_c} C, {noise_c} C, {tau_s} s at {rate_hz} Hz")  # fmt: skip
        self.resolution_c = float(resolution_c)
        self.noise_c = float(noise_c)
        self.tau_s = float(tau_s)
        self.lag = LagFilter(tau_s, rate_hz)
        self._table = inverse_table(self.noise_c / self.resolution_c)
        self._array = np.array(self._table)

    def reset(self) -> None:
        self.lag.reset()

    def update(self, temp_c: np.ndarray) -> np.ndarray:
        return self.invert(self.lag.update(temp_c))

    def update_one(self, temp_c: float) -> float:
        """Feed one reading; the estimate, the same float `update` gives."""
        return self.invert_one(self.lag.update_one(temp_c))

    def invert_one(self, mean_c: float) -> float:
        """The temperature whose expected reading is `mean_c`."""
        q = self.resolution_c
        steps = mean_c / q
        base = math.floor(steps)
        at = (steps - base) * TABLE_SIZE
        index = min(int(at), TABLE_SIZE - 1)
        low = self._table[index]
        return (base + (low + (at - index) * (self._table[index + 1] - low))) * q

    def invert(self, mean_c: np.ndarray) -> np.ndarray:
        """`invert_one` of each value, over an array: the same float operations in the same order."""
        q = self.resolution_c
        steps = np.asarray(mean_c, dtype=np.float64) / q
        base = np.floor(steps)
        at = (steps - base) * TABLE_SIZE
        index = np.minimum(at.astype(np.int64), TABLE_SIZE - 1)
        low = self._array[index]
        return (base + (low + (at - index) * (self._array[index + 1] - low))) * q


def undither_batch(temp_c: np.ndarray, resolution_c: float, noise_c: float, tau_s: float, rate_hz: float) -> np.ndarray:
    """The estimate over a whole run (the streaming form fed in one chunk)."""
    return Undither(resolution_c, noise_c, tau_s, rate_hz).update(temp_c)
