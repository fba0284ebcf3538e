"""The coil-temperature trend: its frozen form is the same function, and variable projection finds the
mix of temperatures that carries the static curve, whatever each run's offset."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fogd.calibration.models import FitOptions
from fogd.calibration.models.coil import (
    MIX_FLOOR,
    SIGNED_MIX_BOUND,
    CoilTerms,
    fit_mix,
    fit_rate_prior,
    rate_prior_rows,
)
from fogd.calibration.models.least_squares import RunOffsetLeastSquares
from fogd.core.frozen import Svr
from fogd.errors import UsageError

unit = st.floats(0.0, 1.0, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(weights=st.lists(unit, min_size=3, max_size=3).filter(lambda w: sum(w) > 0.1),
       coef=st.lists(st.floats(-5.0, 5.0), min_size=6, max_size=6), degree=st.integers(2, 3),
       seed=st.integers(0, 2**16))  # fmt: skip
def test_the_frozen_mix_form_is_the_same_function(weights: list[float], coef: list[float], degree: int, seed: int) -> None:
    """The trend as the model file stores it (the mix, monomials over the inputs and q) is the fitted one, on
    the array path and one row at a time alike."""
    mix = np.array(weights + [0.0]) / sum(weights)  # the fourth input (a rate) is never in the mix
    terms = CoilTerms(mix, degree)
    coef_ = np.array(coef[: terms.columns])  # four inputs, then q**2 .. q**degree
    xs = np.random.default_rng(seed).normal(0.0, 2.0, (50, 4))
    powers = terms.mix_form()
    assert powers.shape == (terms.columns, 5)
    svr = Svr(np.empty((0, 4)), np.empty(0), 1.0, coef_, 0.25, powers, None, mix)
    want = terms(xs) @ coef_ + 0.25
    np.testing.assert_allclose(svr(xs), want, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose([svr.point(row) for row in xs.tolist()], want, rtol=1e-9, atol=1e-9)


def test_fit_mix_recovers_the_coil_temperature_despite_run_offsets() -> None:
    rng = np.random.default_rng(7)
    n, runs = 600, 3
    groups = np.repeat(np.arange(runs), n // runs)
    base = np.cumsum(rng.normal(0.0, 0.2, n))
    xs = np.c_[base + rng.normal(0.0, 0.3, n), base + rng.normal(0.0, 0.3, n), base + rng.normal(0.0, 0.3, n)]
    xs = (xs - xs.mean(axis=0)) / xs.std(axis=0)
    coil = 0.7 * xs[:, 1] + 0.3 * xs[:, 2]
    offsets = np.array([5.0, -3.0, 40.0])[groups]  # turn-on bias: nothing to do with temperature
    ys = 0.2 * xs[:, 0] - 0.1 * coil**2 + 0.05 * coil**3 + offsets + rng.normal(0.0, 1e-3, n)
    terms = fit_mix(xs, ys, groups, (0, 1, 2), degree=3)
    assert np.isclose(terms.mix.sum(), 1.0)
    assert np.all((terms.mix == 0.0) | (terms.mix >= MIX_FLOOR))
    np.testing.assert_allclose(terms.mix, [0.0, 0.7, 0.3], atol=0.02)


def test_a_single_temperature_is_its_own_coil_temperature() -> None:
    xs = np.random.default_rng(1).normal(size=(40, 2))
    terms = fit_mix(xs, xs[:, 0] ** 3, None, (0,), degree=3)
    np.testing.assert_array_equal(terms.mix, [1.0, 0.0])


def _lag(values: np.ndarray, tau: float) -> np.ndarray:
    """A first-order lag of `tau` samples, started at the first value."""
    out, state = np.empty_like(values), float(values[0])
    for k, value in enumerate(values.tolist()):
        state += (value - state) / tau
        out[k] = state
    return out


def _chain_rows() -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
    """Rows (the temperature, its lags of tau_a and tau_b samples) and a static cubic of a layer behind both lags."""
    rng = np.random.default_rng(3)
    n, runs, tau_a, tau_b = 3000, 3, 60.0, 20.0
    temperature = np.cumsum(rng.normal(0.0, 1.0, n))
    xs = np.c_[temperature, _lag(temperature, tau_a), _lag(temperature, tau_b)]
    inner = _lag(xs[:, 2], tau_a)  # the layer: the temperature through tau_b, then through tau_a
    xs, inner = (xs - 10.0) / 30.0, (inner - 10.0) / 30.0
    groups = np.repeat(np.arange(runs), n // runs)
    ys = 0.3 * inner**2 + 0.8 * inner**3 + np.array([1.0, -2.0, 0.5])[groups] + rng.normal(0.0, 1e-4, n)
    return xs, ys, groups, tau_a, tau_b


def test_a_coil_layer_behind_a_chain_of_lags_gets_a_signed_mix() -> None:
    """A layer that follows through two lags in a row is, over a bank of first-order lags, the partial-fraction
    mix (tau_a lag_a - tau_b lag_b) / (tau_a - tau_b): a negative weight that no weighted mean can give."""
    xs, ys, groups, tau_a, tau_b = _chain_rows()
    terms = fit_mix(xs, ys, groups, (0, 1, 2), degree=3)
    assert np.isclose(terms.mix.sum(), 1.0)
    assert terms.mix.min() < 0.0
    # the first-order lags' discrete-time partial fractions are close to the continuous ones (tau >> 1 sample)
    np.testing.assert_allclose(terms.mix, [0.0, tau_a / (tau_a - tau_b), -tau_b / (tau_a - tau_b)], atol=0.1)
    assert np.all(np.abs(terms.mix[1:]) <= SIGNED_MIX_BOUND + 1.0)


def test_the_mix_can_be_forced_either_way() -> None:
    """`mix="mean"` keeps the weighted mean where the signed mix fits better, `mix="signed"` gives the signed one;
    any other choice is refused, by fit_mix and by FitOptions alike."""
    xs, ys, groups, _, _ = _chain_rows()
    mean = fit_mix(xs, ys, groups, (0, 1, 2), degree=3, mix="mean")
    assert np.isclose(mean.mix.sum(), 1.0) and mean.mix.min() >= 0.0
    signed = fit_mix(xs, ys, groups, (0, 1, 2), degree=3, mix="signed")
    assert signed.mix.min() < 0.0
    with pytest.raises(ValueError, match="coil mix"):
        fit_mix(xs, ys, groups, (0, 1, 2), mix="negative")
    with pytest.raises(UsageError, match="coil mix"):
        FitOptions(coil_mix="negative")


def _bank_rows(seed: int, rate_coef: np.ndarray, noise: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Scaled rows of a temperature and its lags (TAUS samples), a target that is the lagged rates times
    `rate_coef` plus a static cubic, three run offsets and `noise`; and each lag column's tau / scale."""
    rng = np.random.default_rng(seed)
    n = 3000
    temperature = np.cumsum(rng.normal(0.0, 1.0, n))
    lags = np.column_stack([_lag(temperature, tau) for tau in TAUS])
    rates = (temperature[:, None] - lags) / TAUS  # a lag's rate of change, d lag/dt = (T - lag) / tau
    raw = np.column_stack((temperature, lags))
    mean, scale = raw.mean(axis=0), raw.std(axis=0)
    xs = (raw - mean) / scale
    groups = np.repeat(np.arange(3), n // 3)
    ys = rates @ rate_coef + 0.2 * xs[:, 0] ** 3 + np.array([1.0, -2.0, 0.5])[groups] + rng.normal(0.0, noise, n)
    return xs, ys, groups, np.r_[0.0, TAUS] / scale


TAUS = np.array([4.0, 10.0, 25.0, 60.0, 150.0])


def _rate_coef(coef: np.ndarray, lag_rates: np.ndarray) -> np.ndarray:
    """The fitted trend's lag coefficients on the lagged rates (rate_prior_rows' docstring)."""
    columns = np.flatnonzero(lag_rates)
    return -coef[columns] * lag_rates[columns]


def test_the_rate_prior_sees_only_curvature_along_the_bank() -> None:
    """Coefficients whose lagged-rate form is a straight line along the bank are not penalised at all; a bend
    is; a bank of two lags has nothing to smooth."""
    terms = CoilTerms(np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.0]), 3)
    lag_rates = np.array([0.0, 2.0, 5.0, 11.0, 30.0, 70.0])
    rows = rate_prior_rows(terms, lag_rates)
    assert rows.shape == (3, terms.columns)
    straight = np.zeros(terms.columns)
    straight[1:6] = -(0.5 + 0.25 * np.arange(5)) / lag_rates[1:]  # rate coefficients 0.5, 0.75, .. 1.5
    straight[[0, 6, 7]] = (3.0, -1.0, 2.0)  # the temperature and the static curve: not the prior's business
    np.testing.assert_allclose(rows @ straight, 0.0, atol=1e-12)
    bent = straight.copy()
    bent[3] -= 1.0 / lag_rates[3]
    assert np.linalg.norm(rows @ bent) > 0.5
    assert rate_prior_rows(terms, np.array([0.0, 2.0, 5.0, 0.0, 0.0, 0.0])).shape == (0, terms.columns)


def test_the_rate_prior_pulls_noisy_rate_coefficients_towards_a_smooth_truth() -> None:
    """With noisy targets, the prior's fit is closer than plain least squares to the truth's lagged-rate
    coefficients on every seed, whether the truth is a straight line along the bank (what the prior does not
    penalise: about half the error on average) or a gentle arch."""
    for truth in (np.array([1.0, 1.5, 2.0, 2.5, 3.0]), np.array([2.0, 3.0, 3.5, 3.0, 2.0])):
        ratios = []
        for seed in range(4):
            xs, ys, groups, lag_rates = _bank_rows(seed, truth, noise=0.5)
            plain = fit_mix(xs, ys, groups, (0,), degree=3)
            prior = fit_rate_prior(plain, xs, ys, groups, lag_rates)
            assert prior.penalty_rows is not None and prior.penalty_rows.shape == (3, plain.columns)
            plain_error, prior_error = (
                np.linalg.norm(_rate_coef(RunOffsetLeastSquares(terms).fit(xs, ys, groups).coef_, lag_rates) - truth)
                for terms in (plain, prior))  # fmt: skip
            assert prior_error < plain_error, (truth, seed)
            ratios.append(prior_error / plain_error)
        if truth[0] == 1.0:
            assert np.mean(ratios) < 0.6, ratios


def test_the_rate_prior_leaves_a_bend_the_data_pin_down() -> None:
    """A truth far from smooth along the bank, measured with little noise: the strength chosen is weak enough
    to keep it, and far weaker than for a smooth truth measured with much noise."""
    truth = np.array([4.0, -3.0, 5.0, -2.0, 3.0])
    xs, ys, groups, lag_rates = _bank_rows(11, truth, noise=1e-3)
    plain = fit_mix(xs, ys, groups, (0,), degree=3)
    prior = fit_rate_prior(plain, xs, ys, groups, lag_rates)
    fitted = _rate_coef(RunOffsetLeastSquares(prior).fit(xs, ys, groups).coef_, lag_rates)
    np.testing.assert_allclose(fitted, truth, atol=0.3)
    xs, ys, groups, lag_rates = _bank_rows(11, np.array([1.0, 1.5, 2.0, 2.5, 3.0]), noise=0.5)
    smooth = fit_rate_prior(fit_mix(xs, ys, groups, (0,), degree=3), xs, ys, groups, lag_rates)
    assert prior.prior_strength is not None and smooth.prior_strength is not None
    assert prior.prior_strength * 1e4 <= smooth.prior_strength  # the strength follows the data, not a constant


def test_the_rate_prior_survives_a_flat_input_and_too_few_rows() -> None:
    """An input that never moves in the rows (a play operator that never slid, in a short fold) is left out of
    the choice, not a singular matrix; with fewer rows than terms the trend is left as it was."""
    xs, ys, groups, lag_rates = _bank_rows(5, np.array([1.0, 1.5, 2.0, 2.5, 3.0]), noise=0.5)
    xs = np.column_stack((xs, np.zeros(len(xs))))  # a seventh input, flat
    lag_rates = np.r_[lag_rates, 0.0]
    plain = fit_mix(xs, ys, groups, (0,), degree=3)
    prior = fit_rate_prior(plain, xs, ys, groups, lag_rates)
    assert prior.prior_strength is not None
    assert np.all(np.isfinite(RunOffsetLeastSquares(prior).fit(xs, ys, groups).coef_))
    few = fit_rate_prior(plain, xs[:6], ys[:6], groups[:6], lag_rates)
    assert few.penalty_rows is None and few.prior_strength is None


def test_the_rate_prior_is_an_option() -> None:
    with pytest.raises(UsageError, match="rate prior"):
        FitOptions(rate_prior="ridge")
    assert FitOptions().rate_prior == "smooth"
