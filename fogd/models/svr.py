"""PSO-SVR (paper section 2.2): an RBF-kernel SVR whose C, epsilon and sigma a particle swarm chooses.

The swarm searches log10(C), log10(epsilon) and log10(sigma) in the scaled space (y scaled to unit std,
inputs to unit std), inside `LOG10_LOWER`..`LOG10_UPPER`:
    C       1e-2 .. 1e4   (paper table 2 found 51.9)
    epsilon 1e-4 .. 1     (a tube from 1e-4 of the error's spread up to its whole spread)
    sigma   1e-2 .. 1e2   (from far finer than the block spacing to a kernel flatter than the data)
Fitness "train" is the paper's step 2: RMSE on the training rows, which rewards memorising the noise;
fitness "cv" is the RMSE on held-out folds. Both are reported in deg/h.
"""

from __future__ import annotations

import functools
import warnings

import numpy as np
from sklearn.exceptions import ConvergenceWarning
from sklearn.svm import SVR

from fogd.errors import InputError
from fogd.models.folds import Split
from fogd.models.method import MethodFit
from fogd.models.pso import pso_minimize

LOG10_LOWER = np.array([-2.0, -4.0, -2.0])  # log10 of C, epsilon (scaled y), sigma (scaled x)
LOG10_UPPER = np.array([4.0, 0.0, 2.0])
# Large C with a thin tube and a mid-sized sigma makes libsvm's SMO crawl (tens of seconds for one
# 300-row fit); such settings are ill-conditioned, so the search gives up on them after this many SMO
# iterations and scores them +inf. The final model is then fitted without the cap.
FITNESS_MAX_ITER = 50_000
_CACHE_MB = 64  # the whole float32 kernel matrix of 4000 rows; libsvm allocates it only as needed


def svr(c: float, epsilon: float, sigma: float, max_iter: int = -1) -> SVR:
    """An RBF SVR with the paper's sigma: k(x, x_i) = exp(-||x - x_i||^2 / (2 sigma^2)) (eq. 13)."""
    return SVR(kernel="rbf", C=c, epsilon=epsilon, gamma=0.5 / sigma**2, cache_size=_CACHE_MB, max_iter=max_iter)


def svr_fitness(log10_position: np.ndarray, xs: np.ndarray, ys: np.ndarray, splits: list[Split], y_scale: float) -> float:
    """RMSE in deg/h of the SVR at `log10_position` on the test rows of `splits`; +inf if SMO did not converge."""
    c, epsilon, sigma = 10.0 ** np.asarray(log10_position)
    residual = np.empty_like(ys)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        for train, test in splits:
            model = svr(c, epsilon, sigma, FITNESS_MAX_ITER).fit(xs[train], ys[train])
            if model.fit_status_ != 0:
                return np.inf
            residual[test] = model.predict(xs[test]) - ys[test]
    return float(y_scale * np.sqrt(np.mean(residual**2)))


def fit_pso_svr(
    xs: np.ndarray,
    ys: np.ndarray,
    splits: list[Split],
    y_scale: float,
    *,
    fitness: str,
    particles: int,
    iterations: int,
    c1: float,
    c2: float,
    seed: int,
    n_jobs: int,
    progress: bool,
) -> MethodFit:
    """Search C, epsilon, sigma with the swarm, then fit the SVR on every row with the best of them."""
    rows = np.arange(len(ys))
    fitness_splits = [(rows, rows)] if fitness == "train" else splits
    result = pso_minimize(
        functools.partial(svr_fitness, xs=xs, ys=ys, splits=fitness_splits, y_scale=y_scale),
        LOG10_LOWER,
        LOG10_UPPER,
        particles=particles,
        iterations=iterations,
        c1=c1,
        c2=c2,
        seed=seed,
        n_jobs=n_jobs,
        progress=progress,
        label=f"PSO-SVR ({fitness})",
    )
    if not np.isfinite(result.best_fitness):
        raise InputError("PSO-SVR: no C, epsilon, sigma in the search box gave a converged SVR; check the runs for flat or repeated blocks")
    c, epsilon, sigma = (float(value) for value in 10.0 ** result.best_position)
    model = svr(c, epsilon, sigma).fit(xs, ys)
    params = {
        "support_vectors": model.support_vectors_.tolist(),
        "dual_coef": model.dual_coef_[0].tolist(),
        "gamma": float(model.gamma),
        "intercept": float(model.intercept_[0]),
    }
    hyperparameters = {
        "C": c,
        "epsilon": epsilon,
        "epsilon_dph": epsilon * y_scale,
        "sigma": sigma,
        "gamma": float(model.gamma),
    }
    return MethodFit(model, params, hyperparameters, result.history)
