"""Least-squares models: the linear fit (IEEE 952) and the paper's 5th-order polynomial (section 4.1).

Both are ordinary least squares in the scaled space; the polynomial uses every monomial of total degree
1..degree of the scaled inputs, in scikit-learn's PolynomialFeatures order, which is the `powers` order
stored in the model file.
"""

from __future__ import annotations

import math

import numpy as np
from sklearn.linear_model import LinearRegression
from sklearn.pipeline import Pipeline, make_pipeline
from sklearn.preprocessing import PolynomialFeatures

from fogd.models.method import MethodFit


def polynomial_terms(inputs: int, degree: int) -> int:
    """How many monomials of total degree 1..degree there are in `inputs` variables."""
    return math.comb(inputs + degree, degree) - 1


def fit_linear(xs: np.ndarray, ys: np.ndarray) -> MethodFit:
    model = LinearRegression().fit(xs, ys)
    params = {"coef": model.coef_.tolist(), "intercept": float(model.intercept_)}
    return MethodFit(model, params, {})


def fit_polynomial(xs: np.ndarray, ys: np.ndarray, degree: int) -> MethodFit:
    model: Pipeline = make_pipeline(PolynomialFeatures(degree, include_bias=False), LinearRegression()).fit(xs, ys)
    features, regression = model.steps[0][1], model.steps[1][1]
    params = {
        "powers": features.powers_.astype(int).tolist(),
        "coef": regression.coef_.tolist(),
        "intercept": float(regression.intercept_),
    }
    return MethodFit(model, params, {"degree": degree})
