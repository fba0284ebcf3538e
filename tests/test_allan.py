"""Overlapping Allan deviation: white rate noise of known ARW, a bias, a random walk, the direct formula."""

import warnings

import numpy as np
import pytest

from fogd.calibration.allan import (
    allan_deviation,
    analyse,
    octave_taus,
    plot,
    summary_lines,
)


@pytest.mark.parametrize("seed, rate_hz, arw_dpsh", [(1, 100.0, 0.005), (2, 200.0, 0.002), (3, 10.0, 0.05)])
def test_white_noise_recovers_its_arw_within_5_percent(seed, rate_hz, arw_dpsh):
    samples = 1_000_000
    sigma_dph = 60.0 * arw_dpsh * np.sqrt(rate_hz)  # per-sample std of white rate noise with this ARW
    rate = 3.0 + np.random.default_rng(seed).normal(0.0, sigma_dph, samples)
    result = analyse(rate, rate_hz)
    assert abs(result.arw_dpsh / arw_dpsh - 1.0) < 0.05
    # and the whole curve follows N / sqrt(tau) over the octaves with enough clusters
    expected = 60.0 * arw_dpsh / np.sqrt(result.tau_s)
    good = result.tau_s * rate_hz <= samples / 1000
    np.testing.assert_allclose(result.adev_dph[good], expected[good], rtol=0.05)


def test_matches_the_direct_overlapping_formula():
    rng = np.random.default_rng(5)
    rate, rate_hz = rng.normal(0, 1, 500), 4.0
    tau_s, adev = allan_deviation(rate, rate_hz, m=np.array([1, 3, 7, 50]))
    tau0 = 1 / rate_hz
    for tau, value in zip(tau_s, adev):
        m = int(round(tau / tau0))
        means = np.array([rate[k : k + m].mean() for k in range(rate.size - m + 1)])
        direct = np.sqrt(0.5 * np.mean((means[m:] - means[:-m]) ** 2))
        assert value == pytest.approx(direct, rel=1e-9)


def test_constant_bias_has_zero_deviation_and_random_walk_rises():
    assert np.all(allan_deviation(np.full(1000, 7.0), 1.0)[1] < 1e-12)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # fogd-replay's one-line stderr must not get numpy's warning
        assert analyse(np.full(1000, 7.5), 1.0).arw_dpsh == 0.0
    walk = np.cumsum(np.random.default_rng(0).normal(0, 1e-3, 200_000))
    tau_s, adev = allan_deviation(walk, 10.0)
    assert adev[-1] > adev[len(adev) // 2]  # rate random walk: +1/2 slope at long tau


def test_bias_instability_is_the_minimum_over_0664_where_the_curve_turns_up():
    rng = np.random.default_rng(9)
    rate = rng.normal(0, 1.0, 100_000) + np.cumsum(rng.normal(0, 1e-3, 100_000))  # white + rate random walk
    result = analyse(rate, 10.0)
    lowest = int(np.argmin(result.adev_dph))
    assert 0 < lowest < result.tau_s.size - 1  # the minimum is inside the curve
    assert result.bias_instability_dph == pytest.approx(result.adev_dph.min() / 0.664)
    assert result.bias_instability_tau_s == result.tau_s[lowest]
    lines = summary_lines({"before": result})
    assert "ARW" in lines[0] and f"{result.bias_instability_dph:.4g}" in lines[1]
    assert len(lines) == 2 and "not reached" not in "\n".join(lines)
    assert octave_taus(1000, 1.0)[-1] == 64


def test_gauss_markov_bias_has_its_floor_inside_the_curve():
    rng = np.random.default_rng(4)
    rate_hz, samples, correlation_s = 10.0, 400_000, 3000.0  # about the largest tau: the bias drifts like a walk
    phi = np.exp(-1.0 / (rate_hz * correlation_s))
    bias = gauss_markov(rng.normal(0.0, 0.1 * np.sqrt(1 - phi**2), samples), phi)
    result = analyse(rng.normal(0.0, 1.0, samples) + bias, rate_hz)
    assert result.bias_instability_dph is not None
    assert result.tau_s[0] < result.bias_instability_tau_s < result.tau_s[-1]


def test_white_noise_only_is_still_falling_so_bias_instability_is_not_reached(tmp_path):
    result = analyse(np.random.default_rng(3).normal(0.0, 1.0, 200_000), 10.0)
    assert result.bias_instability_dph is None
    assert result.bias_instability_tau_s == result.tau_s[-1] == 1638.4
    lines = summary_lines({"white": result, "also white": result})
    assert "not reached" in lines[1] and "not reached" in lines[2]
    assert lines[3:] == ["bias instability: not reached (curve still falling at tau = 1638 s) for white, also white"]
    plot(str(tmp_path / "adev.png"), {"white": result}, "white noise")  # the legend says 'BI not reached'
    assert (tmp_path / "adev.png").read_bytes()[:4] == b"\x89PNG"


def gauss_markov(noise: np.ndarray, phi: float) -> np.ndarray:
    """x_k = phi * x_{k-1} + noise_k (a first-order Gauss-Markov process), without scipy."""
    out = np.empty_like(noise)
    state = 0.0
    for index, value in enumerate(noise.tolist()):
        state = phi * state + value
        out[index] = state
    return out
