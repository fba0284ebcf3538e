"""The lag filter: the streaming form equals the batch form bit for bit for any chunking; it is a lag."""

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from fogd.core.lag import LagFilter, lag_batch


def chunked(values: np.ndarray, sizes: list[int], tau_s: float, rate_hz: float) -> np.ndarray:
    lag, parts, start = LagFilter(tau_s, rate_hz), [], 0
    for size in [*sizes, values.size]:
        parts.append(lag.update(values[start : start + size]))
        start += size
        if start >= values.size:
            break
    return np.concatenate(parts)


@settings(max_examples=200, deadline=None)
@given(
    temps=st.lists(st.floats(-50, 120, allow_nan=False), min_size=1, max_size=300),
    sizes=st.lists(st.integers(0, 40), max_size=30),
    tau_s=st.floats(0.01, 3600.0),
    rate_hz=st.sampled_from([1.0, 10.0, 200.0, 5000.0]),
)
def test_streaming_equals_batch_bit_for_bit_for_any_chunking(temps, sizes, tau_s, rate_hz):
    values = np.array(temps)
    assert np.array_equal(chunked(values, sizes, tau_s, rate_hz), lag_batch(values, tau_s, rate_hz))


def test_one_sample_at_a_time_on_a_long_run_equals_batch():
    rng = np.random.default_rng(3)
    temps = 20 + np.round(np.cumsum(rng.normal(0, 0.01, 20_000)), 2)
    lag = LagFilter(60.0, 50.0)
    streamed = np.concatenate([lag.update(temps[i : i + 1]) for i in range(temps.size)])
    assert np.array_equal(streamed, lag_batch(temps, 60.0, 50.0))


def test_python_floats_and_lfilter_chunks_interleaved_equal_batch():
    """Chunks below PYTHON_CHUNK (the daemon's: Python floats) and above it (replay's: scipy's lfilter), in any
    order, carry the same state and give lfilter's floats over the whole run."""
    from fogd.core.lag import PYTHON_CHUNK

    rng = np.random.default_rng(4)
    temps = 20 + np.round(np.cumsum(rng.normal(0, 0.05, 30_000)))
    sizes = [1, PYTHON_CHUNK + 7, 16, 17, PYTHON_CHUNK, 3 * PYTHON_CHUNK, 5]
    assert np.array_equal(chunked(temps, sizes, 300.0, 10.0), lag_batch(temps, 300.0, 10.0))
    assert np.array_equal(chunked(temps, [5, 100, 3000], 300.0, 10.0), lag_batch(temps, 300.0, 10.0))


def test_steady_start_and_first_order_step_response():
    rate_hz, tau_s = 10.0, 30.0
    temps = np.r_[np.full(10, 20.0), np.full(3000, 30.0)]
    out = lag_batch(temps, tau_s, rate_hz)
    np.testing.assert_allclose(out[:10], 20.0, rtol=0, atol=1e-12)
    t_s = np.arange(1, 3001) / rate_hz  # the first step sample is filtered once: one sample period of lag
    np.testing.assert_allclose(out[10:], 30.0 - 10.0 * np.exp(-t_s / tau_s), rtol=0, atol=1e-9)


def test_ramp_lags_by_tau():
    rate_hz, tau_s = 5.0, 100.0
    t_s = np.arange(0, 3000, 1 / rate_hz)
    out = lag_batch(20 + 0.01 * t_s, tau_s, rate_hz)
    lag_c = (20 + 0.01 * t_s[-1]) - out[-1]
    assert math.isclose(lag_c, 0.01 * tau_s, rel_tol=1e-2)


def test_reset_starts_again_in_steady_state():
    lag = LagFilter(10.0, 1.0)
    lag.update(np.array([0.0, 5.0, 9.0]))
    lag.reset()
    assert abs(lag.update(np.array([42.0]))[0] - 42.0) < 1e-12
