"""The demo's drift estimate (fogd.cli.demo.DriftMeans): the means of the last 100 s of samples less those of
the first 100 s, and one block per full 100 s for the summary, whatever batches the samples come in."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fogd.cli.demo import DriftMeans

RATE_HZ = 10.0


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), count=st.integers(1, 3500), cuts=st.lists(st.integers(0, 3500), max_size=40))
def test_drift_is_the_last_windows_means_less_the_first_windows(seed, count, cuts):
    rng = np.random.default_rng(seed)
    t_s = np.arange(count) / RATE_HZ
    raw, comp = rng.normal(7.6, 0.03, count), rng.normal(7.6, 0.003, count)
    means = DriftMeans(axis=2)
    bounds = sorted({0, count, *(cut % (count + 1) for cut in cuts)})
    for start, stop in zip(bounds, bounds[1:]):
        means.add(t_s[start:stop].tolist(), raw[start:stop].tolist(), comp[start:stop].tolist())
    seconds = np.floor(t_s).astype(int)
    full = int(seconds[-1]) // 100  # windows of 100 s known complete: a later sample has been seen
    if full == 0:
        assert means.drift() is None and means.blocks == []
        return
    first = raw[seconds < 100].mean(), comp[seconds < 100].mean()
    recent = seconds >= seconds[-1] - 100  # the last 100 whole seconds and the one being filled
    assert means.drift() == pytest.approx((raw[recent].mean() - first[0], comp[recent].mean() - first[1]), abs=1e-9)
    expected = [(raw[(seconds >= 100 * j) & (seconds < 100 * (j + 1))].mean() - first[0],
                 comp[(seconds >= 100 * j) & (seconds < 100 * (j + 1))].mean() - first[1]) for j in range(full)]  # fmt: skip
    assert len(means.blocks) == full
    np.testing.assert_allclose(np.array(means.blocks), np.array(expected), rtol=0, atol=1e-9)


def test_samples_that_are_not_finite_are_left_out():
    means = DriftMeans(axis=2)
    t_s = [i / RATE_HZ for i in range(2500)]
    means.add(t_s, [float("nan") if i % 7 == 0 else 1.0 for i in range(2500)], [0.5] * 2500)
    assert means.drift() == (0.0, 0.0) and len(means.blocks) == 2
