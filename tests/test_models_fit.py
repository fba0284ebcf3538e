"""Fitting: frozen params reproduce scikit-learn, least squares recover known models, folds are honest,
cv fitness generalises where the paper's training fitness memorises noise, and too few rows are refused."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fogd.calibration.models import METHODS, FitOptions, Fitted, fit, folds
from fogd.core.frozen import build_evaluator
from fogd.errors import InputError, UsageError

QUICK = FitOptions(particles=10, iterations=10, progress=False)


def chamber_rows(n: int, seed: int, runs: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Block rows of `runs` chamber sweeps: temperature C, rate C/s, a nonlinear error in deg/h with noise."""
    rng = np.random.default_rng(seed)
    temp_c = rng.uniform(-15.0, 50.0, n)
    rate_cps = rng.uniform(-0.02, 0.02, n)
    error_dph = 0.05 * np.sin(temp_c / 10.0) + 2.0 * rate_cps + rng.normal(0.0, 0.002, n)
    return np.c_[temp_c, rate_cps], error_dph, np.sort(rng.integers(0, runs, n))


def predict_dph(fitted: Fitted, x: np.ndarray) -> np.ndarray:
    return fitted.y_mean + fitted.y_scale * build_evaluator(fitted.method, fitted.params)((x - fitted.x_mean) / fitted.x_scale)


@pytest.mark.parametrize("method", METHODS)
def test_frozen_params_reproduce_the_estimator(method: str) -> None:
    x, y, groups = chamber_rows(90, seed=1)
    fitted = fit(method, x, y, groups, QUICK)
    assert json.loads(json.dumps(fitted.params)) == fitted.params  # plain lists and floats only
    xs = np.random.default_rng(2).uniform(-4.0, 4.0, (500, 2))  # inside and well outside the training range
    frozen = build_evaluator(method, fitted.params)(xs)
    np.testing.assert_allclose(frozen, fitted.estimator.predict(xs), rtol=0, atol=1e-9)
    assert fitted.cv_rmse_dph is not None and np.isfinite(fitted.cv_rmse_dph)


@pytest.mark.parametrize("trend", ["coil", "poly", "linear"])
def test_frozen_svr_with_its_trend_reproduces_the_estimator(trend: str) -> None:
    """The model file's trend (monomials and coefficients, the coil trend's mix, offsets per run folded into the intercept) gives the
    scikit-learn estimator's predictions."""
    x, y, groups = chamber_rows(80, seed=12, runs=3)
    x = np.c_[x, x[:, 0] + np.random.default_rng(4).normal(0.0, 3.0, len(x))]  # a second temperature input
    options = FitOptions(particles=6, iterations=4, trend=trend, static_columns=(0,), temperature_columns=(0, 2),
                         progress=False)  # fmt: skip
    fitted = fit("pso-svr", x, y, groups, options)
    assert ("trend_powers" in fitted.params) == (trend in ("coil", "poly"))
    assert ("trend_mix" in fitted.params) == (trend == "coil")  # the coil trend as fitted: q's powers, not expanded
    if trend == "coil":
        assert len(fitted.params["trend_coef"]) == x.shape[1] + 2
    assert fitted.hyperparameters["trend"] == trend
    xs = (x - fitted.x_mean) / fitted.x_scale
    np.testing.assert_allclose(build_evaluator("pso-svr", fitted.params)(xs), fitted.estimator.predict(xs), rtol=1e-9, atol=1e-9)


def test_ls_poly_recovers_a_known_polynomial() -> None:
    rng = np.random.default_rng(3)
    x = np.c_[rng.uniform(-15.0, 50.0, 60), rng.uniform(-0.02, 0.02, 60)]
    truth = lambda x: 0.3 + 0.01 * x[:, 0] - 4e-4 * x[:, 0] ** 2 + 2e-6 * x[:, 0] ** 3 + 3.0 * x[:, 1] - 0.5 * x[:, 0] * x[:, 1]  # noqa: E731
    fitted = fit("ls-poly", x, truth(x), np.zeros(60, int), FitOptions(degree=3, progress=False))
    assert fitted.hyperparameters == {"degree": 3, "terms": "full"}
    assert len(fitted.params["powers"]) == 9 and all(1 <= sum(p) <= 3 for p in fitted.params["powers"])
    fresh = np.c_[rng.uniform(-15.0, 50.0, 200), rng.uniform(-0.02, 0.02, 200)]
    np.testing.assert_allclose(predict_dph(fitted, fresh), truth(fresh), rtol=0, atol=1e-10)
    # exact model: out of sample only the clamp to each fold's training range (as the daemon clamps) errs
    assert fitted.cv_rmse_dph < 0.1 * np.std(truth(x))


def test_temperature_terms_recover_a_polynomial_static_term_plus_linear_rates() -> None:
    """--poly-terms temp: T, T^2, T^3 of each temperature input (here temp and a lag) and the rate linear; no
    cross terms, so a model with one fits exactly only with 'full' terms."""
    rng = np.random.default_rng(5)
    x = np.c_[rng.uniform(-15.0, 50.0, 80), rng.uniform(-0.02, 0.02, 80), rng.uniform(-15.0, 50.0, 80)]
    truth = lambda x: 0.3 + 0.01 * x[:, 0] - 4e-4 * x[:, 0] ** 2 + 2e-6 * x[:, 0] ** 3 + 3.0 * x[:, 1] + 1e-3 * x[:, 2] ** 2  # noqa: E731
    options = FitOptions(degree=3, poly_terms="temp", temperature_columns=(0, 2), progress=False)
    fitted = fit("ls-poly", x, truth(x), np.zeros(80, int), options)
    assert fitted.hyperparameters == {"degree": 3, "terms": "temp"}
    assert fitted.params["powers"] == [[1, 0, 0], [2, 0, 0], [3, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0, 2], [0, 0, 3]]
    fresh = np.c_[rng.uniform(-15.0, 50.0, 200), rng.uniform(-0.02, 0.02, 200), rng.uniform(-15.0, 50.0, 200)]
    np.testing.assert_allclose(predict_dph(fitted, fresh), truth(fresh), rtol=0, atol=1e-10)
    xs = rng.uniform(-4.0, 4.0, (300, 3))
    np.testing.assert_allclose(build_evaluator("ls-poly", fitted.params)(xs), fitted.estimator.predict(xs), rtol=0, atol=1e-9)
    crossed = lambda x: truth(x) + 0.05 * x[:, 0] * x[:, 1]  # noqa: E731
    assert fit("ls-poly", x, crossed(x), np.zeros(80, int), options).cv_rmse_dph > 1e-4
    with pytest.raises(UsageError, match="polynomial terms"):
        fit("ls-poly", x, truth(x), np.zeros(80, int), FitOptions(poly_terms="some", progress=False))


def test_linear_recovers_known_coefficients() -> None:
    rng = np.random.default_rng(4)
    x = np.c_[rng.uniform(-15.0, 50.0, 40), rng.uniform(-0.02, 0.02, 40)]
    fitted = fit("linear", x, 0.3 + 0.02 * x[:, 0] - 4.0 * x[:, 1], np.zeros(40, int), QUICK)
    raw_slope = np.array(fitted.params["coef"]) * fitted.y_scale / fitted.x_scale
    np.testing.assert_allclose(raw_slope, [0.02, -4.0], rtol=1e-10)
    np.testing.assert_allclose(predict_dph(fitted, np.array([[0.0, 0.0]])), [0.3], atol=1e-12)


def test_cv_rmse_is_leave_one_run_out_drift_with_run_offsets() -> None:
    """Each held-out run is predicted by a fit with one offset per training run (dummy columns), its inputs
    clamped to the training runs' range as the daemon clamps, and scored by the drift about its own mean."""
    x, y, groups = chamber_rows(80, seed=5, runs=3)
    squared = []
    for run in range(3):
        train, test = groups != run, groups == run
        dummies = (groups[train][:, None] == np.unique(groups[train])).astype(float)
        beta = np.linalg.lstsq(np.c_[dummies, x[train]], y[train], rcond=None)[0]
        x_test = np.clip(x[test], x[train].min(axis=0), x[train].max(axis=0))
        residual = x_test @ beta[dummies.shape[1]:] - y[test]
        squared.append((residual - residual.mean()) ** 2)
    expected = np.sqrt(np.mean(np.concatenate(squared)))
    assert fit("linear", x, y, groups, QUICK).cv_rmse_dph == pytest.approx(expected, rel=1e-9)


def test_cv_with_two_runs_predicts_a_held_out_stretch_at_its_runs_level() -> None:
    """Two runs with very different turn-on biases: time folds hold out a stretch of each, predicted with
    that run's offset from its other stretches, so the figure is the drift, not the bias difference."""
    x, y, groups = chamber_rows(80, seed=6, runs=2)
    biased = y + np.where(groups == 0, -5.0, 5.0)
    assert fit("linear", x, biased, groups, QUICK).cv_rmse_dph == pytest.approx(fit("linear", x, y, groups, QUICK).cv_rmse_dph, rel=1e-6)


def test_run_offsets_do_not_leak_into_temperature_coefficients() -> None:
    """Two runs over the same temperatures with different turn-on biases: the slope stays the true one (a
    fit without offsets would tilt it towards the biases' difference)."""
    rng = np.random.default_rng(8)
    temp = np.r_[np.linspace(0.0, 30.0, 40), np.linspace(10.0, 40.0, 40)]
    groups = np.repeat([0, 1], 40)
    y = 0.01 * temp + np.where(groups == 0, -0.2, 0.2) + rng.normal(0.0, 1e-4, 80)
    x = np.c_[temp, rng.normal(0.0, 1e-3, 80)]
    fitted = fit("linear", x, y, groups, QUICK)
    slope = fitted.params["coef"][0] * fitted.y_scale / fitted.x_scale[0]
    assert slope == pytest.approx(0.01, rel=1e-2)
    pooled = np.linalg.lstsq(np.c_[np.ones(80), x], y, rcond=None)[0][1]
    assert abs(pooled - 0.01) > 0.005  # the leak the offsets prevent


def test_folds_with_two_runs_hold_out_the_same_stretch_of_each() -> None:
    groups = np.repeat([0, 1], [10, 6])
    splits = folds(groups, 2)
    assert [test.tolist() for _, test in splits] == [[0, 1, 2, 3, 4, 10, 11, 12], [5, 6, 7, 8, 9, 13, 14, 15]]
    assert sorted(np.concatenate([test for _, test in splits])) == list(range(16))


def test_folds_leave_one_run_out() -> None:
    groups = np.array([0, 0, 0, 2, 2, 5, 5, 5, 5])
    splits = folds(groups, 5)
    assert [sorted(set(groups[test])) for _, test in splits] == [[0], [2], [5]]
    for train, test in splits:
        assert set(groups[train]).isdisjoint(groups[test])
        assert sorted(np.concatenate([train, test])) == list(range(9))
    assert sorted(np.concatenate([test for _, test in splits])) == list(range(9))  # each row tested once


def test_folds_contiguous_in_time_for_one_run() -> None:
    splits = folds(np.zeros(23, int), 4)
    assert len(splits) == 4
    tested = np.concatenate([test for _, test in splits])
    assert list(tested) == list(range(23))  # in time order, each row once
    for train, test in splits:
        assert list(test) == list(range(test[0], test[-1] + 1))
        assert sorted(np.concatenate([train, test])) == list(range(23))


@pytest.mark.parametrize("n_folds, rows", [(1, 50), (5, 8)])
def test_folds_refuse_too_few(n_folds: int, rows: int) -> None:
    with pytest.raises(InputError, match="folds"):
        folds(np.zeros(rows, int), n_folds)


def test_too_few_rows_for_the_polynomial() -> None:
    x, y, groups = chamber_rows(24, seed=6)  # folds train on ~12 rows; degree 5 in 2 inputs has 20 terms
    with pytest.raises(InputError, match="--degree"):
        fit("ls-poly", x, y, groups, QUICK)
    assert fit("ls-poly", x, y, groups, FitOptions(degree=2, progress=False)).params["powers"]


def test_too_few_rows_for_pso_svr() -> None:
    x, y, _ = chamber_rows(6, seed=7)
    with pytest.raises(InputError, match="block-s"):
        fit("pso-svr", x, y, np.array([0, 0, 0, 0, 0, 1]), QUICK)


def truth_dph(x: np.ndarray) -> np.ndarray:
    return np.sin(x[:, 0] / 8.0) + 0.3 * np.cos(40.0 * x[:, 1])


def noisy_toy(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    x = np.c_[rng.uniform(-15.0, 50.0, n), rng.uniform(-0.05, 0.05, n)]
    return x, truth_dph(x) + rng.normal(0.0, 0.2, n), rng.integers(0, 4, n)


def test_cv_fitness_generalises_where_train_fitness_memorises() -> None:
    x, y, groups = noisy_toy(120, seed=0)
    fresh, _, _ = noisy_toy(500, seed=99)
    options = {f: FitOptions(particles=10, iterations=10, fitness=f, trend="linear", progress=False) for f in ("train", "cv")}
    by_fitness = {f: fit("pso-svr", x, y, groups, options[f]) for f in ("train", "cv")}
    test_rmse = {f: np.sqrt(np.mean((predict_dph(m, fresh) - truth_dph(fresh)) ** 2)) for f, m in by_fitness.items()}
    assert test_rmse["cv"] < 0.5 * test_rmse["train"]
    assert by_fitness["cv"].hyperparameters["sigma"] > 10 * by_fitness["train"].hyperparameters["sigma"]
    assert by_fitness["train"].fitness_history[-1] < 0.05 < by_fitness["cv"].fitness_history[-1]  # noise sd is 0.2
    assert by_fitness["cv"].cv_rmse_dph == pytest.approx(by_fitness["cv"].fitness_history[-1], rel=1e-9)


def test_pso_svr_hyperparameters_are_consistent() -> None:
    x, y, groups = chamber_rows(60, seed=8)
    fitted = fit("pso-svr", x, y, groups, QUICK)
    hyper = fitted.hyperparameters
    assert hyper["gamma"] == pytest.approx(1.0 / (2.0 * hyper["sigma"] ** 2)) == fitted.params["gamma"]
    assert hyper["epsilon_dph"] == pytest.approx(hyper["epsilon"] * np.std(y))
    assert len(fitted.fitness_history) == 10 and np.all(np.diff(fitted.fitness_history) <= 0)
    assert 1e-2 <= hyper["C"] <= 1e4 and 1e-4 <= hyper["epsilon"] <= 1 and 1e-2 <= hyper["sigma"] <= 1e2


def test_a_constant_input_gets_unit_scale() -> None:
    x, y, groups = chamber_rows(40, seed=9)
    x = np.c_[x, np.full(40, 5.0)]
    fitted = fit("linear", x, y, groups, QUICK)
    assert fitted.x_scale[2] == 1.0 and fitted.x_scale[0] == pytest.approx(np.std(x[:, 0]))
    assert np.all(np.isfinite(predict_dph(fitted, x)))


def test_paper_svr_has_no_trend_and_equals_plain_sklearn_svr() -> None:
    from sklearn.svm import SVR

    x, y, groups = chamber_rows(90, seed=5)
    fitted = fit("pso-svr", x, y, groups, FitOptions(particles=6, iterations=4, trend=False, progress=False))
    assert fitted.params["trend_coef"] == [0.0, 0.0] and fitted.hyperparameters["trend"] == "none"
    h = fitted.hyperparameters
    xs, ys = (x - fitted.x_mean) / fitted.x_scale, (y - fitted.y_mean) / fitted.y_scale
    plain = SVR(kernel="rbf", C=h["C"], epsilon=h["epsilon"], gamma=h["gamma"]).fit(xs, ys)
    grid = np.random.default_rng(6).uniform(-3.0, 3.0, (300, 2))
    np.testing.assert_allclose(build_evaluator("pso-svr", fitted.params)(grid), plain.predict(grid), rtol=0, atol=1e-9)


def test_trend_carries_a_linear_error_beyond_the_data_where_plain_svr_decays() -> None:
    from fogd.calibration.models.svr import TrendSvr

    rng = np.random.default_rng(7)
    xs = rng.uniform(-1.0, 1.0, (80, 2))
    ys = 0.8 * xs[:, 0] - 0.5 * xs[:, 1] + 0.1 * np.sin(3 * xs[:, 0])
    far = np.array([[1.0, 5.0]])  # five times beyond the calibrated range of the second input
    truth = 0.8 - 2.5 + 0.1 * np.sin(3.0)
    error = {trend: abs(TrendSvr(10.0, 0.01, 0.5, trend).fit(xs, ys).predict(far)[0] - truth) for trend in (True, False)}
    assert error[True] < 0.1
    assert error[False] > 1.0  # the kernel has decayed to its intercept


def test_convergence_warnings_are_counted_not_printed(recwarn, monkeypatch) -> None:
    """Lasso stopped after one iteration warns on every fit: the warnings become a count on the fit (one
    summary line in fogd-train) and none reaches the terminal."""
    from sklearn.exceptions import ConvergenceWarning

    import fogd.calibration.models.rbf as rbf

    monkeypatch.setattr(rbf, "_LASSO_MAX_ITER", 1)
    x, y, groups = chamber_rows(80, seed=13)
    fitted = fit("rbf-nn", x, y, groups, QUICK)
    assert fitted.unconverged_fits > 0
    assert not [w for w in recwarn if issubclass(w.category, ConvergenceWarning)]
    assert fit("linear", x, y, groups, QUICK).unconverged_fits == 0


@pytest.mark.parametrize("unit", ["deg/h", "g"])
def test_a_fitted_polynomial_that_extrapolates_wildly_is_refused_in_one_line(unit) -> None:
    """A 5th-order polynomial in six lagged temperatures reaches millions of deg/h at corners of the calibrated
    box no run visited: fogd-train says so and what to use, not that the model it just fitted is hostile; in
    the channel's own unit (an accelerometer's g)."""
    from fogd.calibration.training import TrainConfig, train
    from fogd.core.inputs import parse_inputs
    from fogd.core.runio import Run

    rng = np.random.default_rng(0)
    runs = []
    for k in range(3):
        t_s = np.arange(0.0, 6000.0)
        temp_c = 20.0 + 25.0 * np.sin(t_s / (700.0 + 200.0 * k) + k) + rng.normal(0.0, 0.05, t_s.size)
        runs.append(Run(f"r{k}.csv", t_s, 0.01 * temp_c + rng.normal(0.0, 0.01, t_s.size), temp_c, 1.0, str(k), {}))
    config = TrainConfig(method="ls-poly", inputs=parse_inputs("temp,lags@30..3000/5"), block_s=4.0,
                         fit=FitOptions(progress=False), unit=unit)  # fmt: skip
    with pytest.raises(InputError, match=rf"ls-poly model reaches \S+ {unit} within its calibrated input range.*--degree"):
        train(runs, config)


def test_the_coil_trend_without_a_temperature_input_is_the_linear_trend() -> None:
    """--inputs rate@50 with the default coil trend: no temperature to mix, so the trend is linear (it raised
    a numpy error from an empty mix before)."""
    x, y, groups = chamber_rows(90, seed=4, runs=3)
    options = FitOptions(particles=4, iterations=2, trend="coil", temperature_columns=(), static_columns=(),
                         progress=False)  # fmt: skip
    fitted = fit("pso-svr", x[:, 1:], y, groups, options)
    assert fitted.hyperparameters["trend"] == "linear" and "trend_powers" not in fitted.params


def test_the_kernel_is_dropped_when_the_trend_alone_scores_as_well() -> None:
    """An error the linear trend explains (plus noise): the swarm's kernel would only fit noise, so the model is
    the trend alone, with no support vectors, and its frozen form still reproduces the estimator."""
    rng = np.random.default_rng(7)
    temp_c, rate_cps = rng.uniform(-15.0, 50.0, 120), rng.uniform(-0.02, 0.02, 120)
    x, groups = np.c_[temp_c, rate_cps], np.sort(rng.integers(0, 3, 120))
    y = 0.002 * temp_c + 2.0 * rate_cps + rng.normal(0.0, 0.002, 120)
    fitted = fit("pso-svr", x, y, groups, FitOptions(particles=6, iterations=4, trend="linear", progress=False))
    assert fitted.hyperparameters["kernel"].startswith("none")
    assert fitted.params["support_vectors"] == [] and fitted.hyperparameters["support_vectors"] == 0
    assert fitted.hyperparameters["trend_alone_dph"] <= min(fitted.fitness_history) * 1.02
    xs = rng.uniform(-4.0, 4.0, (200, 2))
    np.testing.assert_allclose(build_evaluator("pso-svr", fitted.params)(xs), fitted.estimator.predict(xs), rtol=0, atol=1e-12)


def test_the_kernel_is_kept_where_it_beats_the_trend() -> None:
    """A curve in temperature that the linear trend cannot follow: the kernel earns its place."""
    x, y, groups = chamber_rows(120, seed=3, runs=3)
    fitted = fit("pso-svr", x, y, groups, FitOptions(particles=6, iterations=4, trend="linear", progress=False))
    assert fitted.hyperparameters["kernel"] == "rbf" and fitted.hyperparameters["support_vectors"] > 0
    assert fitted.hyperparameters["trend_alone_dph"] > min(fitted.fitness_history) * 1.02


def test_the_papers_recipe_keeps_its_kernel_unjudged() -> None:
    x, y, groups = chamber_rows(90, seed=1)
    fitted = fit("pso-svr", x, y, groups, FitOptions(particles=4, iterations=2, trend="none", fitness="train", progress=False))
    assert "kernel" not in fitted.hyperparameters and fitted.hyperparameters["support_vectors"] > 0


@pytest.mark.parametrize(("inputs", "read"), [("temp,lags@30..3000/5", [0]), ("lags@30..3000/3", [0]), ("temp,rate@50", None)])
def test_over_a_lag_bank_the_kernel_reads_the_temperature_alone(inputs: str, read: list[int] | None) -> None:
    """fogd-train over dynamic inputs: the kernel reads the sensor's temperature (or the fastest lag), the trend
    every input; over the paper's inputs, the kernel reads them all (no kernel_columns in the file)."""
    from fogd.calibration.training import TrainConfig, train
    from fogd.core.inputs import parse_inputs
    from fogd.core.runio import Run

    rng = np.random.default_rng(5)
    runs = []
    for k in range(3):
        t_s = np.arange(0.0, 8000.0, 2.0)
        temp_c = 20.0 + 25.0 * np.sin(t_s / (900.0 + 300.0 * k) + k)
        rate = 0.01 * temp_c + 2e-4 * (temp_c - 20.0) ** 2 + rng.normal(0.0, 0.01, t_s.size)
        runs.append(Run(f"r{k}.csv", t_s, rate, temp_c + rng.normal(0.0, 0.01, t_s.size), 0.5, str(k), {}))
    config = TrainConfig(inputs=parse_inputs(inputs), block_s=20.0,
                         fit=FitOptions(particles=4, iterations=3, progress=False))  # fmt: skip
    params = train(runs, config).fitted.params
    assert params.get("kernel_columns") == read
    width = len(parse_inputs(inputs)) if read is None else len(read)
    assert all(len(sv) == width for sv in params["support_vectors"])
