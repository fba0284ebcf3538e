"""RBF neural network: k-means centres, Gaussian hidden units and an L1 (Lasso) output layer (paper ref. [14]).

The centres and their common width depend on the inputs only; the Lasso's alpha is the one with the lowest
held-out RMSE on the folds (never the training error, which always prefers the smallest alpha).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.distance import cdist
from sklearn.cluster import KMeans
from sklearn.linear_model import Lasso
from sklearn.metrics.pairwise import rbf_kernel
from sklearn.pipeline import Pipeline
from sklearn.preprocessing import FunctionTransformer

from fogd.calibration.models.folds import Split, held_out_rmse
from fogd.calibration.models.method import MethodFit

MAX_CENTRES = 20
ROWS_PER_CENTRE = 3
ALPHAS = np.logspace(-6, -1, 11)  # scaled y, so 1e-1 already silences most units
_KMEANS_RESTARTS = 10
_LASSO_MAX_ITER = 100_000


def rbf_network(centres: np.ndarray, width: float, alpha: float) -> Pipeline:
    """Gaussian features exp(-||x - c||^2 / (2 width^2)) of the fixed centres, then an L1-regularised layer."""
    gaussian = FunctionTransformer(rbf_kernel, kw_args={"Y": centres, "gamma": 0.5 / width**2})
    return Pipeline([("gaussian", gaussian), ("lasso", Lasso(alpha=alpha, max_iter=_LASSO_MAX_ITER))])


def centre_width(centres: np.ndarray) -> float:
    """Mean distance from each centre to its nearest neighbour, so neighbouring units overlap."""
    if len(centres) < 2:
        return 1.0
    distance = cdist(centres, centres)
    np.fill_diagonal(distance, np.inf)
    width = float(np.mean(distance.min(axis=1)))
    return width if width > 0 else 1.0


def fit_rbf_network(xs: np.ndarray, ys: np.ndarray, splits: list[Split], seed: int, groups: np.ndarray | None = None) -> MethodFit:
    count = min(MAX_CENTRES, len(xs) // ROWS_PER_CENTRE)
    centres = KMeans(count, n_init=_KMEANS_RESTARTS, random_state=seed).fit(xs).cluster_centers_
    width = centre_width(centres)
    scores = [held_out_rmse(rbf_network(centres, width, alpha), xs, ys, splits, groups) for alpha in ALPHAS]
    alpha = float(ALPHAS[int(np.argmin(scores))])
    model = rbf_network(centres, width, alpha).fit(xs, ys)
    lasso: Lasso = model.named_steps["lasso"]
    params = {
        "centres": centres.tolist(),
        "width": width,
        "coef": lasso.coef_.tolist(),
        "intercept": float(lasso.intercept_),
    }
    return MethodFit(model, params, {"centres": count, "width": width, "alpha": alpha})
