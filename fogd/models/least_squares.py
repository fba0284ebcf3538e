"""Least-squares models: the linear fit (IEEE 952) and the paper's 5th-order polynomial (section 4.1).

Both are ordinary least squares in the scaled space. The polynomial's terms are one of `POLY_TERMS`:
- `full` (the paper's): every monomial of total degree 1..degree of the scaled inputs, in scikit-learn's
  PolynomialFeatures order;
- `temp`: the powers 1..degree of each temperature input (the sensor temperature, lagged temperatures) and
  the other inputs (temperature rates) linear, with no cross terms: IEEE 952's model with its static term
  a polynomial in temperature. It has far fewer terms and, having no powers of the rate, cannot bend far
  from the linear model where calibration data were sparse.
Either way the monomials are the `powers` stored in the model file.
"""

from __future__ import annotations

import math

import numpy as np
from sklearn.linear_model import LinearRegression
from sklearn.pipeline import Pipeline, make_pipeline
from sklearn.preprocessing import FunctionTransformer, PolynomialFeatures

from fogd.frozen import monomials
from fogd.models.method import MethodFit


POLY_TERMS = ("full", "temp")


def polynomial_terms(inputs: int, degree: int, terms: str = "full", temperature_columns: tuple[int, ...] = (0,)) -> int:
    """How many monomials the polynomial of `terms` has in `inputs` variables."""
    if terms == "full":
        return math.comb(inputs + degree, degree) - 1
    return len(temperature_powers(inputs, degree, temperature_columns))


def temperature_powers(inputs: int, degree: int, temperature_columns: tuple[int, ...]) -> np.ndarray:
    """The `temp` terms' powers: 1..degree for each temperature column, 1 for the others, one input per term."""
    rows = []
    for column in range(inputs):
        for power in range(1, (degree if column in temperature_columns else 1) + 1):
            row = [0] * inputs
            row[column] = power
            rows.append(row)
    return np.array(rows, dtype=np.int64).reshape(-1, inputs)


def fit_linear(xs: np.ndarray, ys: np.ndarray) -> MethodFit:
    model = LinearRegression().fit(xs, ys)
    params = {"coef": model.coef_.tolist(), "intercept": float(model.intercept_)}
    return MethodFit(model, params, {})


def fit_polynomial(
    xs: np.ndarray, ys: np.ndarray, degree: int, terms: str = "full", temperature_columns: tuple[int, ...] = (0,)
) -> MethodFit:
    if terms == "full":
        model: Pipeline = make_pipeline(PolynomialFeatures(degree, include_bias=False), LinearRegression()).fit(xs, ys)
        powers = model.steps[0][1].powers_.astype(int)
    else:
        powers = temperature_powers(xs.shape[1], degree, temperature_columns)
        model = make_pipeline(FunctionTransformer(monomials, kw_args={"powers": powers}), LinearRegression()).fit(xs, ys)
    regression = model.steps[1][1]
    params = {"powers": powers.tolist(), "coef": regression.coef_.tolist(), "intercept": float(regression.intercept_)}
    return MethodFit(model, params, {"degree": degree, "terms": terms})
