"""PSO-SVR (paper section 2.2): an RBF-kernel SVR whose C, epsilon and sigma a particle swarm chooses.

The swarm searches log10(C), log10(epsilon) and log10(sigma) in the scaled space (y scaled to unit std,
inputs to unit std), inside `LOG10_LOWER`..`LOG10_UPPER`:
    C       1e-2 .. 1e4   (paper table 2 found 51.9)
    epsilon 1e-4 .. 1     (a tube from 1e-4 of the error's spread up to its whole spread)
    sigma   1e-2 .. 1e2   (from far finer than the block spacing to a kernel flatter than the data; from
                           10**0.5 over a polynomial trend, POLY_TREND_LOG10_SIGMA_MIN)
Fitness "train" is the paper's step 2: RMSE on the training rows, which rewards memorising the noise;
fitness "cv" is the RMSE on held-out folds. Both are reported in deg/h.

Over a trend, the kernel must earn its place: when the trend alone (the swarm's best settings with no
kernel at all) scores within `KERNEL_MARGIN` of the swarm's best on the same held-out folds, the model is the
trend alone, with no support vectors (as `--method auto` takes another family only if it wins by 2 %): a
kernel that scores no better than the trend is support vectors to serve on every sample of every channel
for nothing. Over a lag bank the kernel reads the temperature alone (`kernel_columns`,
fogd.core.inputs.kernel_columns, which says why). The paper's recipe (`--fitness train`, no trend) keeps
its kernel.

The SVR can sit on a least-squares trend, refitted on every training fold, and then models only what the
trend leaves: `trend="coil"` (fogd's default, fogd.calibration.models.coil: the inputs linear plus the static curve at
a fitted coil temperature), `trend="linear"` (IEEE 952's linear model in the inputs), `trend="poly"` (the
inputs linear plus powers 2..3 of the temperature inputs that follow the coil, `static_columns`, the static
nonlinearity; over a lag bank this is a grey-box thermal model) or `"none"` (the paper's plain SVR). An RBF
kernel decays to its intercept away from the data; with the trend underneath, the model degrades towards
the trend rather than towards a constant where a held-out run leaves the calibration data. A trend fits one
offset per calibration run (fogd.calibration.models.least_squares), so run-to-run turn-on bias is not thermal; the SVR
then fits what is left about each run's mean.
"""

from __future__ import annotations

import functools
import warnings

import numpy as np
from sklearn.base import BaseEstimator, RegressorMixin
from sklearn.exceptions import ConvergenceWarning
from sklearn.svm import SVR

from fogd.calibration.models.coil import CoilTerms
from fogd.calibration.models.folds import Clamp, Split, drift_rmse, run_levels
from fogd.calibration.models.least_squares import RunOffsetLeastSquares
from fogd.calibration.models.method import MethodFit
from fogd.calibration.models.pso import pso_minimize
from fogd.core.errorstats import centred_within_runs
from fogd.errors import InputError

LOG10_LOWER = np.array([-2.0, -4.0, -2.0])  # log10 of C, epsilon (scaled y), sigma (scaled x)
LOG10_UPPER = np.array([4.0, 0.0, 2.0])
# Over a polynomial trend the SVR is there for what the trend leaves of the static curve, not for the
# calibration runs' own histories: its kernel is kept broad, sigma >= 10**0.5 input stds. With the full box
# the swarm's cv fitness picked a narrow kernel on the lag bank and the held-out drift was 1.23-3.01x the
# noise floor against 1.03-1.58x (tools/accuracy_table.py --quick, lumped coil, fine sensor).
POLY_TREND_LOG10_SIGMA_MIN = 0.5
KERNEL_MARGIN = 0.02  # the kernel's held-out fitness must beat the trend alone's by this share
# Large C with a thin tube and a mid-sized sigma makes libsvm's SMO crawl (tens of seconds for one
# 300-row fit); such settings are ill-conditioned, so the search gives up on them after this many SMO
# iterations and scores them +inf. The final model is then fitted without the cap. The paper's train fitness
# leads the swarm among such settings: on a 4-hour run its 60 x 100 search took 196 s on 2 cores with a cap of
# 50,000, and 58-66 s with 10,000, for a best fitness 1.6 % higher (tools/bench_train.py).
FITNESS_MAX_ITER = 10_000
_CACHE_MB = 64  # the whole float32 kernel matrix of 4000 rows; libsvm allocates it only as needed


TRENDS = ("coil", "poly", "linear", "none")


class TrendSvr(RegressorMixin, BaseEstimator):
    """An RBF SVR (paper eq. 12-13, k(x, x_i) = exp(-||x - x_i||^2 / (2 sigma^2))) on top of a least-squares
    trend with one offset per run: predict(x) = trend(x) + svr(x). `trend_powers` are the trend's monomials
    (None: the inputs themselves, a linear trend; CoilTerms: fogd.calibration.models.coil); `trend=False` is the paper's
    plain SVR."""

    def __init__(self, C: float = 1.0, epsilon: float = 0.1, sigma: float = 1.0, trend: bool = True,
                 max_iter: int = -1, trend_powers: np.ndarray | CoilTerms | None = None, kernel: bool = True,
                 kernel_columns: tuple[int, ...] | None = None):  # fmt: skip
        self.kernel = kernel
        self.kernel_columns = kernel_columns
        self.C = C
        self.epsilon = epsilon
        self.sigma = sigma
        self.trend = trend
        self.max_iter = max_iter
        self.trend_powers = trend_powers

    def fit(self, xs: np.ndarray, ys: np.ndarray, groups: np.ndarray | None = None) -> "TrendSvr":
        target = np.asarray(ys, dtype=np.float64)
        if self.trend:
            self.trend_ = RunOffsetLeastSquares(self.trend_powers).fit(xs, ys, groups)
            target = target - self.trend_.predict(xs)
            if groups is not None:  # what the trend leaves, about each run's own offset
                target = centred_within_runs(target, groups) + target.mean()
        if not self.kernel:  # the trend alone
            self.svr_ = None
            return self
        self.svr_ = SVR(
            kernel="rbf", C=self.C, epsilon=self.epsilon, gamma=0.5 / self.sigma**2, cache_size=_CACHE_MB,
            max_iter=self.max_iter,
        ).fit(self._kernel_inputs(xs), target)  # fmt: skip
        return self

    def _kernel_inputs(self, xs: np.ndarray) -> np.ndarray:
        return xs if self.kernel_columns is None else xs[:, list(self.kernel_columns)]

    def _trend(self, xs: np.ndarray) -> np.ndarray:
        return self.trend_.predict(xs) if self.trend else np.zeros(len(xs))

    def predict(self, xs: np.ndarray) -> np.ndarray:
        return self._trend(xs) + (0.0 if self.svr_ is None else self.svr_.predict(self._kernel_inputs(xs)))


def svr_fitness(
    log10_position: np.ndarray, xs: np.ndarray, ys: np.ndarray, splits: list[Split], y_scale: float, trend: bool,
    groups: np.ndarray | None = None, trend_powers: np.ndarray | CoilTerms | None = None, clamp: Clamp | None = None,
    kernel: bool = True, kernel_columns: tuple[int, ...] | None = None,
) -> float:
    """Drift RMSE in deg/h (about each run's mean) of the model at `log10_position` on the test rows of `splits`
    (`kernel=False`: of the trend alone); +inf if SMO did not converge."""
    c, epsilon, sigma = 10.0 ** np.asarray(log10_position)
    residual = np.empty_like(ys)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        for train, test in splits:
            model = TrendSvr(c, epsilon, sigma, trend, FITNESS_MAX_ITER, trend_powers, kernel, kernel_columns).fit(
                xs[train], ys[train], None if groups is None else groups[train])
            if model.svr_ is not None and model.svr_.fit_status_ != 0:
                return np.inf
            if train is test:  # the paper's training fitness
                residual[test] = model.predict(xs[test]) - ys[test]
                continue
            x_test = xs[test] if clamp is None else clamp(xs[test], xs[train])
            residual[test] = model.predict(x_test) - ys[test]
            if groups is not None:
                residual[test] += run_levels(ys[train] - model.predict(xs[train]), groups[train], groups[test])
    return float(y_scale * drift_rmse(residual, groups))


def fit_pso_svr(
    xs: np.ndarray,
    ys: np.ndarray,
    splits: list[Split],
    y_scale: float,
    *,
    fitness: str,
    trend: bool,
    trend_powers: np.ndarray | CoilTerms | None = None,
    groups: np.ndarray | None = None,
    clamp: Clamp | None = None,
    kernel_columns: tuple[int, ...] | None = None,
    particles: int,
    iterations: int,
    c1: float,
    c2: float,
    seed: int,
    n_jobs: int,
    progress: bool,
    patience: int = 0,
    search: bool = True,
) -> MethodFit:
    """Search C, epsilon, sigma with the swarm, then fit the SVR on every row with the best of them (its kernel
    over the inputs `kernel_columns` only, when given); `search=False`: the trend alone, with no kernel."""
    coil = trend_powers if isinstance(trend_powers, CoilTerms) else None
    trend_label = "none" if not trend else "linear" if trend_powers is None else "coil" if coil else "poly"
    rows = np.arange(len(ys))
    fitness_splits = [(rows, rows)] if fitness == "train" else splits
    lower = LOG10_LOWER.copy()
    if trend and trend_powers is not None:
        lower[2] = POLY_TREND_LOG10_SIGMA_MIN
    if not search:  # the trend alone, asked for: no swarm, no support vectors
        return _trend_alone(xs, ys, groups, trend_powers, kernel_columns, y_scale, trend_label, coil)
    result = pso_minimize(
        functools.partial(svr_fitness, xs=xs, ys=ys, splits=fitness_splits, y_scale=y_scale, trend=trend,
                          groups=groups, trend_powers=trend_powers, clamp=clamp, kernel_columns=kernel_columns),
        lower,
        LOG10_UPPER,
        particles=particles,
        iterations=iterations,
        c1=c1,
        c2=c2,
        seed=seed,
        n_jobs=n_jobs,
        progress=progress,
        label=f"PSO-SVR ({fitness})",
        patience=patience,
    )
    if not np.isfinite(result.best_fitness):
        raise InputError("PSO-SVR: no C, epsilon, sigma in the search box gave a converged SVR; check the runs for flat or repeated blocks")
    c, epsilon, sigma = (float(value) for value in 10.0 ** result.best_position)
    kernel, trend_alone_dph = True, None
    if trend and fitness != "train":
        trend_alone_dph = svr_fitness(result.best_position, xs, ys, splits, y_scale, trend, groups, trend_powers,
                                      clamp, kernel=False)  # fmt: skip
        kernel = not trend_alone_dph <= result.best_fitness * (1.0 + KERNEL_MARGIN)
    model = TrendSvr(c, epsilon, sigma, trend, trend_powers=trend_powers, kernel=kernel,
                     kernel_columns=kernel_columns).fit(xs, ys, groups)  # fmt: skip
    params, hyperparameters = _frozen(model, xs, trend_powers, kernel_columns, y_scale, trend_label, coil)
    if trend_alone_dph is not None:
        hyperparameters["trend_alone_dph"] = trend_alone_dph  # the trend without a kernel, same folds as the swarm's best
        hyperparameters["kernel"] = "rbf" if kernel else f"none (the trend alone scored within {KERNEL_MARGIN:.0%} of it)"
    return MethodFit(model, params, hyperparameters, result.history)


def _trend_alone(xs: np.ndarray, ys: np.ndarray, groups: np.ndarray | None, trend_powers, kernel_columns,
                 y_scale: float, trend_label: str, coil: CoilTerms | None) -> MethodFit:  # fmt: skip
    """The trend with no kernel (the ladder's rungs below the SVR, fogd.calibration.ladder)."""
    model = TrendSvr(trend=True, trend_powers=trend_powers, kernel=False, kernel_columns=kernel_columns).fit(xs, ys, groups)
    params, hyperparameters = _frozen(model, xs, trend_powers, kernel_columns, y_scale, trend_label, coil)
    hyperparameters["kernel"] = "none (the trend alone)"
    return MethodFit(model, params, hyperparameters)


def _frozen(model: TrendSvr, xs: np.ndarray, trend_powers, kernel_columns, y_scale: float, trend_label: str,
            coil: CoilTerms | None) -> tuple[dict, dict]:  # fmt: skip
    """The fitted model's params for the model file and its hyper-parameters."""
    c, epsilon, sigma, trend, kernel = model.C, model.epsilon, model.sigma, model.trend, model.svr_ is not None
    trend_coef = model.trend_.coef_ if trend else np.zeros(xs.shape[1] if trend_powers is None else len(trend_powers))
    trend_mix = None
    if isinstance(trend_powers, CoilTerms):  # frozen as fitted: the mix, and monomials over the inputs and q
        trend_mix, trend_powers = trend_powers.mix, trend_powers.mix_form()
    gamma = 0.5 / sigma**2  # the SVR's own (TrendSvr passes it as is)
    params = {
        "support_vectors": model.svr_.support_vectors_.tolist() if kernel else [],
        "dual_coef": model.svr_.dual_coef_[0].tolist() if kernel else [],
        "gamma": gamma,
        "trend_coef": trend_coef.tolist(),
        "intercept": (float(model.svr_.intercept_[0]) if kernel else 0.0) + (model.trend_.intercept_ if trend else 0.0),
    }
    if trend_powers is not None:
        params["trend_powers"] = np.asarray(trend_powers).tolist()
    if trend_mix is not None:
        params["trend_mix"] = trend_mix.tolist()
    if kernel_columns is not None:
        params["kernel_columns"] = [int(column) for column in kernel_columns]
    hyperparameters = {
        "C": c,
        "epsilon": epsilon,
        "epsilon_dph": epsilon * y_scale,
        "sigma": sigma,
        "gamma": gamma,
        "trend": trend_label,
        "support_vectors": len(params["dual_coef"]),
    }
    if coil is not None:
        hyperparameters["coil_mix"] = coil.mix.tolist()
        if coil.prior_strength is not None:
            hyperparameters["rate_prior_strength"] = coil.prior_strength  # relative (fogd.calibration.models.coil)
    return params, hyperparameters
