"""`fit`: one entry point that scales the block rows, checks there are enough of them, fits a method and
scores it on the same held-out folds whatever the method, so methods can be compared honestly.

Scaling uses the mean and std of all training rows (a zero std becomes 1). It is only a change of units
(the hyper-parameters live in them), so the folds reuse it rather than rescaling per fold.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
from sklearn.exceptions import ConvergenceWarning

from fogd.calibration.models.coil import MIXES, PRIORS, CoilTerms, fit_mix, fit_rate_prior
from fogd.calibration.models.folds import folds, held_out_rmse
from fogd.calibration.models.least_squares import (
    POLY_TERMS,
    fit_linear,
    fit_polynomial,
    polynomial_terms,
    temperature_powers,
)
from fogd.calibration.models.rbf import ROWS_PER_CENTRE, fit_rbf_network
from fogd.calibration.models.svr import TRENDS, fit_pso_svr
from fogd.core.inputs import clamp_rows
from fogd.errors import InputError, UsageError

METHODS = ("linear", "ls-poly", "rbf-nn", "pso-svr")
FITNESSES = ("cv", "train")
_SVR_MIN_ROWS = 5
_RBF_MIN_CENTRES = 2


@dataclass
class FitOptions:
    """How to fit; the PSO defaults are the paper's table 1."""

    degree: int = 5  # ls-poly order (paper section 4.1)
    poly_terms: str = "full"  # ls-poly: "full" (the paper's) or "temp" (fogd.calibration.models.least_squares)
    temperature_columns: tuple[int, ...] = (0,)  # the inputs that are temperatures (for poly_terms "temp")
    static_columns: tuple[int, ...] = (0,)  # the temperatures that follow the coil (powers in the "poly" trend)
    shifted_columns: tuple[int, ...] = ()  # temperatures the domain clamp moves together (fogd.core.inputs.clamp_rows)
    trend_degree: int = 3  # the "coil" and "poly" trends' highest power
    coil_mix: str = "auto"  # the "coil" trend's coil temperature: "auto", "mean" or "signed" (fogd.calibration.models.coil)
    rate_prior: str = "smooth"  # the "coil" trend's prior on its lags' rate coefficients, or "none" (the same module)
    lag_taus_s: tuple[float, ...] = ()  # each input's lag time constant, 0 for inputs that are not lags (same order)
    kernel_columns: tuple[int, ...] | None = None  # pso-svr over a trend: the inputs its kernel reads (None: every one)
    particles: int = 60
    iterations: int = 100
    search: bool = True  # pso-svr: the swarm and its kernel; False: the trend alone (fogd.calibration.ladder's rungs)
    patience: int = 0  # the swarm stops after this many iterations without its best improving (0: never; pso.py)
    c1: float = 2.0
    c2: float = 2.0
    fitness: str = "cv"  # "train": the paper's RMSE on the training rows; "cv": RMSE on held-out folds
    trend: str = "coil"  # pso-svr: the SVR on a "coil", "poly" or "linear" least-squares trend, or "none" (the paper's)
    folds: int = 5  # contiguous time folds when there is only one run
    n_jobs: int = 1
    seed: int = 0
    progress: bool = True


    def __post_init__(self) -> None:
        if isinstance(self.trend, bool):  # the older spelling: True was the linear trend
            self.trend = "linear" if self.trend else "none"
        if self.trend not in TRENDS:
            raise UsageError(f"unknown trend {self.trend!r}: choose one of {', '.join(TRENDS)}")
        if self.coil_mix not in MIXES:
            raise UsageError(f"unknown coil mix {self.coil_mix!r}: choose one of {', '.join(MIXES)}")
        if self.rate_prior not in PRIORS:
            raise UsageError(f"unknown rate prior {self.rate_prior!r}: choose one of {', '.join(PRIORS)}")


@dataclass
class Fitted:
    """A fitted model: scaling, JSON-ready `params` for fogd.core.frozen, and how it was chosen and scored."""

    method: str
    x_mean: np.ndarray
    x_scale: np.ndarray
    y_mean: float
    y_scale: float
    params: dict
    hyperparameters: dict
    fitness_history: list[float] = field(default_factory=list)  # PSO best fitness (deg/h) per iteration
    cv_rmse_dph: float | None = None
    estimator: object = None  # scikit-learn, scaled space; never written to a model file
    unconverged_fits: int = 0  # scikit-learn fits that stopped at their iteration limit (summarised, not warned)


def fit(method: str, X: np.ndarray, y: np.ndarray, groups: np.ndarray, options: FitOptions = FitOptions()) -> Fitted:
    """Fit `method` to block rows X (raw units), targets y (deg/h) and their run index `groups`."""
    if method not in METHODS:
        raise UsageError(f"unknown method {method!r}: choose one of {', '.join(METHODS)}")
    if options.fitness not in FITNESSES:
        raise UsageError(f"unknown fitness {options.fitness!r}: choose one of {', '.join(FITNESSES)}")
    X = np.asarray(X, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    groups = np.asarray(groups)
    if X.ndim != 2 or y.shape != (len(X),) or groups.shape != y.shape:
        raise ValueError(f"X must be (n, d) with y and groups (n,): got {X.shape}, {y.shape}, {groups.shape}")
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(y))):
        raise InputError("the block rows contain NaN or infinite values: check the runs for gaps or bad samples")
    splits = folds(groups, options.folds)
    if options.poly_terms not in POLY_TERMS:
        raise UsageError(f"unknown polynomial terms {options.poly_terms!r}: choose one of {', '.join(POLY_TERMS)}")
    _check_rows(method, min(len(train) for train, _ in splits), X.shape[1], options)

    x_mean, x_std = X.mean(axis=0), X.std(axis=0)
    x_scale = np.where(x_std > 0, x_std, 1.0)
    y_mean, y_scale = float(y.mean()), float(y.std()) or 1.0
    xs, ys = (X - x_mean) / x_scale, (y - y_mean) / y_scale

    def clamp(test: np.ndarray, train: np.ndarray) -> np.ndarray:
        """Scaled test rows clamped to the training rows' range as the daemon clamps raw inputs."""
        raw_train = train * x_scale + x_mean
        raw = clamp_rows(test * x_scale + x_mean, raw_train.min(axis=0), raw_train.max(axis=0), options.shifted_columns)
        return (raw - x_mean) / x_scale

    # scikit-learn warns once per unconverged fit (Lasso, SVR): hundreds of lines in a swarm or a fold loop;
    # they are counted and summarised in one line per family instead (Fitted.unconverged_fits)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ConvergenceWarning)
        if method == "linear":
            result = fit_linear(xs, ys, groups)
        elif method == "ls-poly":
            result = fit_polynomial(xs, ys, options.degree, options.poly_terms, options.temperature_columns, groups)
        elif method == "rbf-nn":
            result = fit_rbf_network(xs, ys, splits, options.seed, groups)
        else:
            result = fit_pso_svr(
                xs, ys, splits, y_scale,
                fitness=options.fitness, trend=options.trend != "none",
                trend_powers=trend_terms(xs, ys, groups, options, x_scale),
                groups=groups, clamp=clamp, kernel_columns=options.kernel_columns if options.trend != "none" else None,
                particles=options.particles, iterations=options.iterations, patience=options.patience,
                search=options.search, c1=options.c1, c2=options.c2, seed=options.seed, n_jobs=options.n_jobs, progress=options.progress,
            )
        cv_rmse_dph = y_scale * held_out_rmse(result.estimator, xs, ys, splits, groups, clamp)
    unconverged = 0
    for warning in caught:
        if issubclass(warning.category, ConvergenceWarning):
            unconverged += 1
        else:
            warnings.warn_explicit(warning.message, warning.category, warning.filename, warning.lineno)
    return Fitted(
        method=method,
        x_mean=x_mean,
        x_scale=x_scale,
        y_mean=y_mean,
        y_scale=y_scale,
        params=result.params,
        hyperparameters=result.hyperparameters,
        fitness_history=result.fitness_history,
        cv_rmse_dph=cv_rmse_dph,
        estimator=result.estimator,
        unconverged_fits=unconverged,
    )


def trend_terms(xs: np.ndarray, ys: np.ndarray, groups: np.ndarray, options: FitOptions,
                x_scale: np.ndarray) -> np.ndarray | CoilTerms | None:  # fmt: skip
    """The pso-svr trend's terms of the scaled rows (`x_scale`: the inputs' scales): the "coil" trend's mix and
    rate prior (fitted once, here, then fixed for every fold and particle), the "poly" trend's monomials (every
    input linear, the static columns up to `trend_degree`), or None (linear; also the coil trend's when no
    input is a temperature)."""
    if options.trend == "coil" and options.temperature_columns:
        terms = fit_mix(xs, ys, groups, options.temperature_columns, options.trend_degree, options.coil_mix)
        if options.rate_prior == "none" or len(options.lag_taus_s) != xs.shape[1]:
            return terms
        return fit_rate_prior(terms, xs, ys, groups, np.asarray(options.lag_taus_s) / x_scale)
    if options.trend == "poly":
        return temperature_powers(xs.shape[1], options.trend_degree, options.static_columns)
    return None


def _check_rows(method: str, train_rows: int, inputs: int, options: FitOptions) -> None:
    """Every training fold must hold enough rows for the method (the full fit has more)."""
    if method == "ls-poly" and options.degree < 1:
        raise UsageError(f"--degree must be at least 1 (got {options.degree})")
    needed = {
        "linear": inputs + 1,
        "ls-poly": polynomial_terms(inputs, options.degree, options.poly_terms, options.temperature_columns) + 1,
        "rbf-nn": ROWS_PER_CENTRE * _RBF_MIN_CENTRES,
        "pso-svr": _SVR_MIN_ROWS,
    }[method]
    if train_rows < needed:
        hint = ", or a lower --degree" if method == "ls-poly" else ""
        raise InputError(
            f"{method} needs at least {needed} block rows in every training fold (the smallest has {train_rows}): "
            f"record more or longer runs, or use a smaller --block-s{hint}"
        )
