"""First-order lagged temperature: a stand-in for the fibre coil's temperature, which lags its housing sensor.

    y[n] = (1 - a) * y[n-1] + a * x[n],   a = 1 - exp(-1 / (tau_s * rate_hz))

(the exact discretisation of dy/dt = (x - y) / tau for a held input). The filter starts in steady state at
its first input (y[-1] = x[0]): a calibration run starts with a soak, and the daemon's first temperature is
the best guess it has. T - lag(T) is then a proxy for the radial gradient IEEE 952 adds and the paper drops.

Both forms, streaming (`LagFilter.update`, any chunk size, O(1) per sample whatever tau) and batch
(`lag_batch`), run the very same recurrence: scipy's `lfilter` with the state carried from chunk to chunk in
`zi`, and for the daemon's chunks of a few samples (`update_one`) lfilter's own two operations in Python
floats (y = z + b0 x, z = (1 - a) y), which give the same floats without its per-call overhead. The
recurrence is computed sample by sample in the same order whatever the chunking, so both forms give the same
floats bit for bit (tests/test_lag.py proves it for arbitrary chunkings). scipy is imported for the first
chunk longer than `PYTHON_CHUNK` samples (replay, training), not with this module nor with a filter: the
daemon's chunks, one frame or a burst, run in Python floats, so the daemon never maps scipy (about 70 MB of
RSS), whatever its model.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from fogd.core.estimator import SCALAR_CHUNK

MAX_TAU_S = 86400.0
# Chunks up to this many samples run the recurrence in Python floats (the same floats as lfilter): the
# daemon's batches, one frame or a burst, never import scipy (about 70 MB of RSS); replay's and training's
# long chunks take lfilter, imported on the first of them.
PYTHON_CHUNK = 4096


def coefficients(tau_s: float, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """lfilter's (b, a) for the lag at `rate_hz`."""
    if not (tau_s > 0 and rate_hz > 0):
        raise ValueError(f"lag time constant and data rate must be positive, got {tau_s} s at {rate_hz} Hz")
    gain = -math.expm1(-1.0 / (tau_s * rate_hz))
    return np.array([gain]), np.array([1.0, -(1.0 - gain)])


class LagFilter:
    """The lag, streaming: feed finite temperatures in chunks of any size."""

    def __init__(self, tau_s: float, rate_hz: float) -> None:
        self._lfilter = None  # scipy's, imported for the first chunk longer than PYTHON_CHUNK
        self.tau_s = float(tau_s)
        self.rate_hz = float(rate_hz)
        self._b, self._a = coefficients(tau_s, rate_hz)
        self._gain, self._keep = self._b.item(0), -self._a.item(1)
        self._state: float | None = None  # lfilter's zi: (1 - a) * y[n-1]

    def reset(self) -> None:
        self._state = None

    def set_value(self, lagged_c: float) -> None:
        """Continue as if the last sample's lagged value had been `lagged_c` (fogd.core.history primes it)."""
        self._state = self._keep * lagged_c

    def update(self, temp_c: np.ndarray) -> np.ndarray:
        temp_c = np.atleast_1d(np.asarray(temp_c, dtype=np.float64))
        if temp_c.size <= SCALAR_CHUNK or (self._lfilter is None and temp_c.size <= PYTHON_CHUNK):
            return np.array(self._run(temp_c.tolist()), dtype=np.float64)
        if self._lfilter is None:
            from scipy.signal import lfilter

            self._lfilter = lfilter
        if self._state is None:
            self._state = self._keep * temp_c.item(0)  # steady state at the first input
        out, state = self._lfilter(self._b, self._a, temp_c, zi=np.array([self._state]))
        self._state = state.item(0)
        return out

    def _run(self, values: list[float]) -> list[float]:
        """`update_one` of each value in turn, inlined (a daemon's batch: a call per sample costs as much as
        its two multiply-adds)."""
        gain, keep, state = self._gain, self._keep, self._state
        out = []
        for value in values:
            lagged = (keep * value if state is None else state) + gain * value
            state = keep * lagged
            out.append(lagged)
        self._state = state
        return out

    def update_one(self, temp_c: float) -> float:
        """Feed one sample; its lagged value, the same float `update` gives."""
        state = self._keep * temp_c if self._state is None else self._state
        lagged = state + self._gain * temp_c
        self._state = self._keep * lagged
        return lagged


def update_lags_one(filters: Sequence[LagFilter], temp_c: float) -> list[float]:
    """`update_one` of each filter with the same sample (an input bank's lags), in one call: the same floats,
    without a Python call per lag (on a dedicated box each frame's calls run cold, fogd.core.inputs)."""
    out = []
    for lag in filters:
        state = lag._state
        lagged = (lag._keep * temp_c if state is None else state) + lag._gain * temp_c
        lag._state = lag._keep * lagged
        out.append(lagged)
    return out


def lag_batch(temp_c: np.ndarray, tau_s: float, rate_hz: float) -> np.ndarray:
    """The lag over a whole run (the streaming form fed in one chunk)."""
    return LagFilter(tau_s, rate_hz).update(temp_c)
