"""Least-squares models: the linear fit (IEEE 952) and the paper's 5th-order polynomial (section 4.1).

Both are ordinary least squares in the scaled space. The polynomial's terms are one of `POLY_TERMS`:
- `full` (the paper's): every monomial of total degree 1..degree of the scaled inputs, in scikit-learn's
  PolynomialFeatures order;
- `temp`: the powers 1..degree of each temperature input (the sensor temperature, lagged temperatures) and
  the other inputs (temperature rates) linear, with no cross terms: IEEE 952's model with its static term
  a polynomial in temperature. It has far fewer terms and, having no powers of the rate, cannot bend far
  from the linear model where calibration data were sparse.
Either way the monomials are the `powers` stored in the model file. Every fit has one offset per calibration
run (`RunOffsetLeastSquares`), so run-to-run turn-on bias is not read as a temperature effect.
"""

from __future__ import annotations

import math

import numpy as np
from sklearn.base import BaseEstimator, RegressorMixin
from sklearn.preprocessing import PolynomialFeatures

from fogd.calibration.models.coil import CoilTerms
from fogd.calibration.models.method import MethodFit
from fogd.core.errorstats import centred_within_runs
from fogd.core.frozen import monomials

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


class RunOffsetLeastSquares(RegressorMixin, BaseEstimator):
    """Least squares on the monomials `powers` of the scaled inputs (the inputs themselves when None; the
    coil-temperature terms when CoilTerms, fogd.calibration.models.coil), with one
    offset per calibration run: a gyro's turn-on bias differs from run to run and is not thermal, so it must
    not leak into the temperature coefficients. Fitting on rows centred within each run is the same as fitting
    an offset per run (Frisch-Waugh-Lovell); the model's intercept is then the runs' mean offset, weighted by
    rows, and predictions need no run."""

    def __init__(self, powers: np.ndarray | CoilTerms | None = None) -> None:
        self.powers = powers

    def features(self, xs: np.ndarray) -> np.ndarray:
        if self.powers is None:
            return xs
        if isinstance(self.powers, CoilTerms):
            return self.powers(xs)
        return monomials(xs, np.asarray(self.powers))

    def fit(self, xs: np.ndarray, ys: np.ndarray, groups: np.ndarray | None = None) -> "RunOffsetLeastSquares":
        features = self.features(xs)
        centred_x, centred_y = centred_within_runs(features, groups), centred_within_runs(ys, groups)
        moving = moves_within_runs(features, centred_x)  # the others are the runs' offsets over again
        centred_x = centred_x[:, moving]
        penalty = self.powers.penalty_rows if isinstance(self.powers, CoilTerms) else None
        if penalty is not None and penalty.shape[0]:  # the coil trend's rate prior: |penalty coef|^2 added
            centred_x = np.vstack((centred_x, penalty[:, moving]))
            centred_y = np.concatenate((centred_y, np.zeros(penalty.shape[0])))
        self.coef_ = np.zeros(features.shape[1])
        self.coef_[moving] = np.linalg.lstsq(centred_x, centred_y, rcond=None)[0]
        self.intercept_ = float(np.mean(ys) - features.mean(axis=0) @ self.coef_)
        return self

    def predict(self, xs: np.ndarray) -> np.ndarray:
        return self.features(xs) @ self.coef_ + self.intercept_


def moves_within_runs(features: np.ndarray, centred: np.ndarray) -> np.ndarray:
    """The columns of `features` that the rows can tell from their runs' offsets (`centred`: the same columns
    centred within each run): their squares about their run means add up to more than one row at their spread
    about the rows' overall mean. The others get no coefficient. The play operator held at +1 on a heating run
    and -1 on a cooling one, once a time fold has held out the stretch where each turned (fogd.calibration.
    ladder), is told from the offsets by its sensor-noise wiggles alone; its coefficient was fitted on them, and
    a held-out row where it is back at 0 was off by it: the 200 Hz quick-start's time folds scored the lag bank
    at 0.5 deg/h against linear's 0.06. A t-test on the coefficient does not tell: the wiggles go with the lags'
    sensor noise, and the fit takes them to cancel it."""
    total_ms = np.mean((features - features.mean(axis=0)) ** 2, axis=0)
    return np.sum(centred**2, axis=0) > total_ms


def full_powers(inputs: int, degree: int) -> np.ndarray:
    """The paper's terms: every monomial of total degree 1..degree, in scikit-learn's PolynomialFeatures order."""
    return PolynomialFeatures(degree, include_bias=False).fit(np.zeros((1, inputs))).powers_.astype(np.int64)


def fit_linear(xs: np.ndarray, ys: np.ndarray, groups: np.ndarray | None = None) -> MethodFit:
    model = RunOffsetLeastSquares().fit(xs, ys, groups)
    params = {"coef": model.coef_.tolist(), "intercept": model.intercept_}
    return MethodFit(model, params, {})


def fit_polynomial(
    xs: np.ndarray, ys: np.ndarray, degree: int, terms: str = "full", temperature_columns: tuple[int, ...] = (0,),
    groups: np.ndarray | None = None,
) -> MethodFit:
    if terms == "full":
        powers = full_powers(xs.shape[1], degree)
    else:
        powers = temperature_powers(xs.shape[1], degree, temperature_columns)
    model = RunOffsetLeastSquares(powers).fit(xs, ys, groups)
    params = {"powers": powers.tolist(), "coef": model.coef_.tolist(), "intercept": model.intercept_}
    return MethodFit(model, params, {"degree": degree, "terms": terms})
