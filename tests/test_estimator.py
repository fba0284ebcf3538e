"""The eq. 16 rate estimator: against a direct float reference, streaming = batch, no drift, rates 1 Hz-5 kHz."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fogd.core.estimator import (
    TEMP_LSB_C,
    EstimatorSettings,
    TempRateEstimator,
    temp_rate_batch,
)


def reference_rate(temp_c: np.ndarray, window: int, average: int, rate_hz: float) -> np.ndarray:
    """Eq. 16 written out directly, one window at a time, in plain float arithmetic."""
    out = np.zeros(temp_c.size)
    for i in range(window - 1, temp_c.size):
        newest = temp_c[i - average + 1 : i + 1].mean()
        oldest = temp_c[i - window + 1 : i - window + 1 + average].mean()
        out[i] = (newest - oldest) * rate_hz / (window - average)
    return out


def stream(estimator: TempRateEstimator, temp_c: np.ndarray, chunks: list[int]) -> np.ndarray:
    out, start = [], 0
    for size in chunks:
        out.append(estimator.update(temp_c[start : start + size]))
        start += size
    out.append(estimator.update(temp_c[start:]))
    return np.concatenate(out)


def test_matches_direct_formula_on_a_ramp():
    rate_hz, slope_cps = 10.0, 0.01
    temp_c = 20 + slope_cps * np.arange(600) / rate_hz
    got = temp_rate_batch(temp_c, EstimatorSettings(window_s=20, average_s=2), rate_hz)
    assert np.all(got[:199] == 0)  # warm-up
    np.testing.assert_allclose(got[199:], slope_cps, rtol=1e-6)


@given(
    temp=st.lists(st.floats(-40, 90, allow_nan=False), min_size=30, max_size=300),
    window=st.integers(4, 30),
    average=st.integers(1, 10),
)
def test_batch_equals_direct_formula(temp, window, average):
    average = min(average, window // 2)
    rate_hz = 7.0
    temp_c = np.array(temp)
    got = temp_rate_batch(temp_c, EstimatorSettings(window / rate_hz, average / rate_hz), rate_hz)
    # quantisation to 2^-24 C bounds the difference from exact float arithmetic
    tolerance = TEMP_LSB_C * rate_hz / (window - average) + 1e-9
    np.testing.assert_allclose(got, reference_rate(temp_c, window, average, rate_hz), rtol=0, atol=tolerance)


@settings(max_examples=60)
@given(
    chunks=st.lists(st.integers(0, 400), max_size=12),
    step_s=st.sampled_from([0.0, 0.1, 0.35]),
    seed=st.integers(0, 2**31),
)
def test_streaming_equals_batch_for_any_chunking(chunks, step_s, seed):
    rng = np.random.default_rng(seed)
    temp_c = 25 + np.cumsum(rng.normal(0, 0.05, 2000))
    settings_ = EstimatorSettings(window_s=5.0, average_s=0.5, step_s=step_s)
    batch = temp_rate_batch(temp_c, settings_, 20.0)
    streamed = stream(TempRateEstimator(settings_, 20.0), temp_c, chunks)
    assert np.array_equal(streamed, batch)


def test_streaming_equals_batch_on_a_million_samples():
    rng = np.random.default_rng(1)
    temp_c = 20 + np.cumsum(rng.normal(0, 1e-3, 1_000_000)) + rng.normal(0, 0.01, 1_000_000)
    settings_ = EstimatorSettings()
    batch = temp_rate_batch(temp_c, settings_, 200.0)
    chunks = list(rng.integers(1, 5000, 400))
    streamed = stream(TempRateEstimator(settings_, 200.0), temp_c, chunks)
    assert np.max(np.abs(streamed - batch)) <= 1e-9


def test_sample_by_sample_equals_batch():
    temp_c = np.round(20 + 0.002 * np.arange(3000) + np.sin(np.arange(3000) / 50))
    settings_ = EstimatorSettings(window_s=10, average_s=1, step_s=0.3)
    estimator = TempRateEstimator(settings_, 50.0)
    streamed = np.array([estimator.update(value)[0] for value in temp_c])
    assert np.array_equal(streamed, temp_rate_batch(temp_c, settings_, 50.0))


def test_no_drift_after_1e8_updates():
    """10^8 samples in large chunks; then the streaming output equals the batch form on the last window."""
    rate_hz = 5000.0
    settings_ = EstimatorSettings(window_s=1.0, average_s=0.1)
    estimator = TempRateEstimator(settings_, rate_hz)
    rng = np.random.default_rng(2)
    chunk = 1_000_000
    # whole-degree readings around 80 C, as a KVH sensor gives; prefix sums reach about 1.3e17 LSB
    base = np.round(80 + 3 * np.sin(np.arange(chunk) / 9000.0))
    for index in range(100):
        last = estimator.update(np.roll(base, index * 7919))
    assert estimator.count == 100 * chunk
    tail = np.roll(base, 99 * 7919)
    expected = temp_rate_batch(tail, settings_, rate_hz)
    window = settings_.samples(rate_hz)[0]
    assert np.array_equal(last[window:], expected[window:])
    assert np.count_nonzero(expected) > 0


def test_prefix_sums_wrapping_past_int64_change_nothing():
    """Days at 5 kHz overflow int64 prefix sums; start them just below the limit and compare with batch."""
    rng = np.random.default_rng(3)
    temp_c = 90 + np.cumsum(rng.normal(0, 0.01, 50_000))
    settings_ = EstimatorSettings(window_s=2.0, average_s=0.2)
    estimator = TempRateEstimator(settings_, 1000.0)
    offset = np.int64(2**63 - 10**12)  # as if earlier samples had already summed to this
    estimator._ring += offset
    estimator._last_prefix += offset
    with np.errstate(over="ignore"):
        streamed = stream(estimator, temp_c, [17, 4000, 1, 9000])
    assert estimator._last_prefix[0] < 0  # it did wrap
    assert np.array_equal(streamed, temp_rate_batch(temp_c, settings_, 1000.0))


@pytest.mark.parametrize("rate_hz", [1.0, 5000.0])
def test_works_at_1hz_and_5khz(rate_hz):
    slope_cps = 0.005
    n = int(200 * rate_hz)
    temp_c = np.round((10 + slope_cps * np.arange(n) / rate_hz) / 0.0625) * 0.0625  # 1/16 C sensor
    settings_ = EstimatorSettings()
    got = temp_rate_batch(temp_c, settings_, rate_hz)
    window = settings_.samples(rate_hz)[0]
    assert window == round(50 * rate_hz)
    # a quantised ramp: the estimate stays within one LSB over the window of the true slope
    assert np.all(np.abs(got[window:] - slope_cps) <= 0.0625 / (50 - 0.5) + 1e-12)
    assert np.array_equal(stream(TempRateEstimator(settings_, rate_hz), temp_c, [n // 3]), got)


def test_whole_degree_sensor_still_gives_a_rate():
    """The case eq. 16 exists for: long runs of identical whole-degree readings."""
    rate_hz = 200.0
    temp_c = np.floor(20 + 0.01 * np.arange(200_000) / rate_hz)
    got = temp_rate_batch(temp_c, EstimatorSettings(), rate_hz)
    naive = np.diff(temp_c) * rate_hz
    assert np.mean(naive == 0) > 0.99
    assert abs(np.mean(got[20_000:]) - 0.01) < 0.002


def test_step_holds_the_estimate_between_updates():
    temp_c = 20 + 0.01 * np.arange(400) ** 1.5 / 100
    settings_ = EstimatorSettings(window_s=10, average_s=1, step_s=0.5)
    got = temp_rate_batch(temp_c, settings_, 10.0)
    held = got[99:].reshape(-1)[: (got.size - 99) // 5 * 5].reshape(-1, 5)
    assert np.all(held == held[:, :1])
    assert np.unique(held[:, 0]).size == held.shape[0]


@pytest.mark.parametrize("window_s, average_s", [(1.0, 0.6), (0.001, 0.0005)])
def test_rejects_windows_that_cannot_hold_two_averages(window_s, average_s):
    with pytest.raises(ValueError, match="two averaging windows"):
        EstimatorSettings(window_s, average_s).samples(100.0)
