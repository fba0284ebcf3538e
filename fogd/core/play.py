"""The play (backlash) operator of the temperature: a gyro's heating/cooling hysteresis as a model input.

    p[n] = min(max(p[n-1], x[n] - w), x[n] + w),   output (x[n] - p[n]) / w

in [-1, 1]: +1 once the temperature has risen by twice the width w since it last turned (by w from rest), -1
once it has fallen as far, linearly in between. A gyro whose bias carries a hysteresis (one level after heating,
another after cooling, the step spread over a few degrees) needs it: no lag bank (a linear filter) can hold
the direction of the last move after the temperature has come to rest. The operator starts at rest
(p[-1] = x[0], output 0), and a sensor's noise or staircase narrower than w moves it little.

Streaming (`PlayFilter.update`, any chunk size, O(1) per sample) and batch (`play_batch`) run the same
per-sample recurrence in Python floats, so both give the same floats bit for bit whatever the chunking.

A gyro's hysteresis follows its coil, not its sensor: where the sensor leads the coil by a long way (on a
baseplate that follows the air), the play of the reading turns long before the coil's does. `LaggedPlay` is the
operator of a first-order lag of the temperature (fogd.core.lag), the lag standing in for the coil;
fogd.calibration.training.with_play_lag chooses its time constant on the calibration runs.
"""

from __future__ import annotations

import numpy as np

from fogd.core.lag import LagFilter

MAX_WIDTH_C = 50.0


class PlayFilter:
    """The operator, streaming: feed finite temperatures in chunks of any size."""

    def __init__(self, width_c: float) -> None:
        if not 0 < width_c <= MAX_WIDTH_C:
            raise ValueError(f"play width must be in (0, {MAX_WIDTH_C:g}] C, got {width_c}")
        self.width_c = float(width_c)
        self._position_c: float | None = None

    def reset(self) -> None:
        self._position_c = None

    def update(self, temp_c: np.ndarray) -> np.ndarray:
        temp_c = np.atleast_1d(np.asarray(temp_c, dtype=np.float64))
        if temp_c.size == 0:
            return np.empty(0)
        values = temp_c.tolist()
        width_c = self.width_c
        position_c = values[0] if self._position_c is None else self._position_c
        out = []
        append = out.append
        for value in values:  # update_one's arithmetic inline: the same floats, without a call per sample
            low_c = value - width_c
            if position_c < low_c:
                position_c = low_c
            else:
                high_c = value + width_c
                if position_c > high_c:  # noqa: PLR1730 (min() costs a call per sample)
                    position_c = high_c
            append((value - position_c) / width_c)
        self._position_c = position_c
        return np.array(out, dtype=np.float64)

    def update_one(self, temp_c: float) -> float:
        """Feed one sample; the operator's output, the same float `update` gives."""
        width_c = self.width_c
        position_c = temp_c if self._position_c is None else self._position_c
        low_c = temp_c - width_c  # min(max(position, low), high), without the builtins' call cost
        if position_c < low_c:
            position_c = low_c
        else:
            high_c = temp_c + width_c
            if position_c > high_c:  # noqa: PLR1730 (min() costs a call per sample)
                position_c = high_c
        self._position_c = position_c
        return (temp_c - position_c) / width_c


def play_batch(temp_c: np.ndarray, width_c: float) -> np.ndarray:
    """The operator over a whole run (the streaming form fed in one chunk)."""
    return PlayFilter(width_c).update(temp_c)


class LaggedPlay:
    """The operator of a `lag_s` first-order lag of the temperature, streaming (the lag, then the play)."""

    def __init__(self, width_c: float, lag_s: float, rate_hz: float) -> None:
        self.lag = LagFilter(lag_s, rate_hz)
        self.play = PlayFilter(width_c)

    def reset(self) -> None:
        self.lag.reset()
        self.play.reset()

    def update(self, temp_c: np.ndarray) -> np.ndarray:
        return self.play.update(self.lag.update(temp_c))

    def update_one(self, temp_c: float) -> float:
        return self.play.update_one(self.lag.update_one(temp_c))
