"""Frozen, numpy-only model evaluators: what the daemon and replay run (never scikit-learn, never pickle).

A `FrozenModel` takes raw inputs (temperature, temperature rate, ...), clamps them to the calibrated domain
(as PX4's temperature compensation does, rather than extrapolating; a lag bank's temperatures move together,
fogd.core.inputs.clamp_rows) and reports which rows were clamped,
scales them, and evaluates one of the method evaluators below in the scaled space:

    y_dph = y_mean + y_scale * g((clamp(x) - x_mean) / x_scale)

Each evaluator's parameters are exactly what the model file stores under `params`.

`FrozenModel.predict_one` is the per-sample form for one input row of Python floats: the same clamp, scaling
and sums in plain Python (each evaluator's `point`), because numpy's per-call overhead dominates one row. It
agrees with `predict` to rounding (sums in another order, `math.exp` for numpy's exp), far inside 1e-12
relative; large kernel models go through numpy instead, one row at a time (`POINT_NUMPY_WORK`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from fogd.core.inputs import InputSpec, clamp_rows, shifted_columns

_CHUNK_ROWS = 4096  # kernel evaluations in blocks, so memory stays bounded on million-row replays
# Above this many kernel terms x inputs one row is cheaper through numpy than a Python loop (tools/bench_point.py:
# the loop's cost grows with both, numpy's hardly)
POINT_NUMPY_WORK = 48


def _floats(values: np.ndarray) -> tuple:
    return tuple(np.asarray(values, dtype=np.float64).tolist())


def _point_dot(xs: Sequence[float], weights: tuple) -> float:
    total = 0.0
    for x, w in zip(xs, weights):
        total += x * w
    return total


def _row_dot(rows: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """rows @ weights, summed row by row so a row's result never depends on how many rows came with it
    (BLAS may round differently by batch size; replay's large chunks and the daemon's must agree bit for bit)."""
    return (rows * weights).sum(axis=1)


@dataclass(frozen=True)
class Linear:
    """g(x) = coef . x + intercept (IEEE 952's linear model)."""

    coef: np.ndarray
    intercept: float

    def __call__(self, xs: np.ndarray) -> np.ndarray:
        return _row_dot(xs, self.coef) + self.intercept

    def __post_init__(self) -> None:
        object.__setattr__(self, "_coef", _floats(self.coef))

    def point(self, xs: Sequence[float]) -> float:
        return _point_dot(xs, self._coef) + self.intercept


def monomials(xs: np.ndarray, powers: np.ndarray) -> np.ndarray:
    """Each row's monomials prod_j x_j ** powers_kj: the polynomial's features, in fitting and evaluation alike."""
    terms = np.ones((xs.shape[0], powers.shape[0]))
    for column in range(powers.shape[1]):
        terms *= xs[:, column : column + 1] ** powers[:, column]
    return terms


@dataclass(frozen=True)
class Polynomial:
    """g(x) = sum_k coef_k prod_j x_j ** powers_kj + intercept (the least-squares polynomial)."""

    powers: np.ndarray  # (terms, inputs) non-negative integers
    coef: np.ndarray
    intercept: float

    def __call__(self, xs: np.ndarray) -> np.ndarray:
        return _row_dot(monomials(xs, self.powers), self.coef) + self.intercept

    def __post_init__(self) -> None:
        # Only the factors with a nonzero power, in column order: x**0 is 1.0 and x**1 is x exactly, so the
        # product is bit for bit the one `monomials` forms, with a fraction of the operations.
        factors = tuple(tuple((j, p) for j, p in enumerate(row) if p != 0) for row in self.powers.tolist())
        object.__setattr__(self, "_point_terms", tuple(zip(factors, _floats(self.coef))))

    def point(self, xs: Sequence[float]) -> float:
        total = 0.0
        for factors, coef in self._point_terms:
            term = 1.0
            for column, power in factors:
                term *= xs[column] if power == 1 else xs[column] ** power
            total += term * coef
        return total + self.intercept


class _GaussianPoint:
    """sum_k weights_k exp(-gamma ||x - centre_k||^2) for one row: a Python loop for a few centres in few
    dimensions, else numpy on the whole (centres, inputs) difference at once (the same per-element operations
    as the array path; summed along each row in column order, as the array path sums, for fewer than 8 inputs)."""

    def __init__(self, centres: np.ndarray, weights: np.ndarray, gamma: float) -> None:
        self.neg_gamma = -gamma
        self.use_numpy = len(centres) * max(1, centres.shape[1]) > POINT_NUMPY_WORK
        self.centres = np.ascontiguousarray(centres, dtype=np.float64)
        self.weights = np.ascontiguousarray(weights)
        self.terms = tuple(zip(centres.tolist(), _floats(weights)))

    def __call__(self, xs: Sequence[float]) -> float:
        if self.use_numpy:
            difference = self.centres - np.asarray(xs, dtype=np.float64)
            np.multiply(difference, difference, out=difference)
            squared = difference.sum(axis=1)
            squared *= self.neg_gamma
            return float(np.dot(np.exp(squared, out=squared), self.weights))
        neg_gamma, exp = self.neg_gamma, math.exp
        total = 0.0
        if len(xs) == 2:
            x0, x1 = xs
            for (c0, c1), weight in self.terms:
                d0, d1 = x0 - c0, x1 - c1
                total += weight * exp(neg_gamma * (d0 * d0 + d1 * d1))
            return total
        for centre, weight in self.terms:
            squared = 0.0
            for x, c in zip(xs, centre):
                squared += (x - c) * (x - c)
            total += weight * exp(neg_gamma * squared)
        return total


def _gaussian_sum(xs: np.ndarray, centres: np.ndarray, weights: np.ndarray, gamma: float) -> np.ndarray:
    """sum_k weights_k exp(-gamma ||x - centre_k||^2) per row, in bounded-memory chunks."""
    out = np.empty(xs.shape[0])
    for start in range(0, xs.shape[0], _CHUNK_ROWS):
        block = xs[start : start + _CHUNK_ROWS]
        # ((block[:, None, :] - centres) ** 2).sum(axis=2), a column at a time: the same sums in the same
        # order, without the (rows, centres, inputs) temporary
        squared = np.zeros((block.shape[0], centres.shape[0])) if centres.shape[1] == 0 else None
        for column in range(centres.shape[1]):
            difference = block[:, column : column + 1] - centres[:, column]
            np.multiply(difference, difference, out=difference)
            if squared is None:
                squared = difference
            else:
                squared += difference
        squared *= -gamma
        out[start : start + _CHUNK_ROWS] = _row_dot(np.exp(squared, out=squared), weights)
    return out


@dataclass(frozen=True)
class RbfNetwork:
    """g(x) = sum_k coef_k exp(-||x - centre_k||^2 / (2 width^2)) + intercept (RBF network, L1-fitted)."""

    centres: np.ndarray
    width: float
    coef: np.ndarray
    intercept: float

    def __call__(self, xs: np.ndarray) -> np.ndarray:
        return _gaussian_sum(xs, self.centres, self.coef, 0.5 / self.width**2) + self.intercept

    def __post_init__(self) -> None:
        object.__setattr__(self, "_point", _GaussianPoint(self.centres, self.coef, 0.5 / self.width**2))

    def point(self, xs: Sequence[float]) -> float:
        return self._point(xs) + self.intercept


@dataclass(frozen=True)
class Svr:
    """g(x) = trend(x) + sum_i dual_coef_i exp(-gamma ||x - sv_i||^2) + intercept (paper eq. 12-13,
    gamma = 1/(2 sigma^2)). The trend is trend_coef . x, or over the monomials `trend_powers` of x when given
    (fogd's polynomial trend); it is zero for the paper's plain SVR."""

    support_vectors: np.ndarray
    dual_coef: np.ndarray
    gamma: float
    trend_coef: np.ndarray
    intercept: float
    trend_powers: np.ndarray | None = None

    def __call__(self, xs: np.ndarray) -> np.ndarray:
        kernel = _gaussian_sum(xs, self.support_vectors, self.dual_coef, self.gamma)
        terms = xs if self.trend_powers is None else monomials(xs, self.trend_powers)
        return _row_dot(terms, self.trend_coef) + kernel + self.intercept

    def __post_init__(self) -> None:
        object.__setattr__(self, "_point", _GaussianPoint(self.support_vectors, self.dual_coef, self.gamma))
        trend = (Linear(self.trend_coef, 0.0) if self.trend_powers is None
                 else Polynomial(self.trend_powers, self.trend_coef, 0.0))  # fmt: skip
        object.__setattr__(self, "_trend_point", trend.point)

    def point(self, xs: Sequence[float]) -> float:
        return self._trend_point(xs) + self._point(xs) + self.intercept


Evaluator = Callable[[np.ndarray], np.ndarray]
_UNIQUE_MIN_ROWS = 64


def unique_rows(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(distinct rows, index of each row of x among them), rows compared bit for bit (-0.0 is not 0.0).

    Runs of equal consecutive rows are collapsed first (cheap, and most repeats are consecutive), then the
    runs' rows are sorted, which is much faster than np.unique(axis=0) on the whole array."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    n = x.shape[0]
    if n == 0:
        return x, np.zeros(0, dtype=np.intp)
    bits = x.view(np.int64)
    change = np.empty(n, dtype=bool)
    change[0] = True
    np.any(bits[1:] != bits[:-1], axis=1, out=change[1:])
    starts = np.flatnonzero(change)
    run_of_row = np.cumsum(change) - 1
    firsts = bits[starts]
    order = np.lexsort(firsts.T[::-1]) if x.shape[1] else np.arange(starts.size)
    ordered = firsts[order]
    new = np.empty(starts.size, dtype=bool)
    new[0] = True
    np.any(ordered[1:] != ordered[:-1], axis=1, out=new[1:])
    distinct_of_run = np.empty(starts.size, dtype=np.intp)
    distinct_of_run[order] = np.cumsum(new) - 1
    return x[starts[order[new]]], distinct_of_run[run_of_row]


@dataclass(frozen=True)
class FrozenModel:
    """A validated model: inputs, scaling, calibrated domain and a method evaluator."""

    method: str
    inputs: tuple[InputSpec, ...]
    x_mean: np.ndarray
    x_scale: np.ndarray
    y_mean: float
    y_scale: float
    domain_min: np.ndarray
    domain_max: np.ndarray
    evaluator: Evaluator
    name: str = "model"
    meta: dict = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_shifted", shifted_columns(self.inputs))  # clamp_rows' temperature columns

    def predict(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(thermal error in deg/h, True where an input was clamped) for raw input rows x of shape (n, d)."""
        x = np.asarray(x, dtype=np.float64).reshape(-1, len(self.inputs))
        clamped_x = clamp_rows(x, self.domain_min, self.domain_max, self._shifted)
        clamped = np.any(clamped_x != x, axis=1)
        if len(clamped_x) >= _UNIQUE_MIN_ROWS and isinstance(self.evaluator, (Polynomial, Svr, RbfNetwork)):
            # Exact: a row's result depends on that row alone, and quantised temperatures (and the rates eq. 16
            # makes of them) repeat, so a million-row replay holds a few ten thousand distinct rows.
            rows, inverse = unique_rows(clamped_x)
            return self.predict_unclamped(rows)[inverse], clamped
        return self.predict_unclamped(clamped_x), clamped

    def predict_one(self, x: Sequence[float]) -> tuple[float, bool]:
        """`predict` for one row of Python floats: (thermal error in deg/h, True if an input was clamped)."""
        point = getattr(self.evaluator, "point", None)
        if point is None:  # a plain callable evaluator: the array path
            comp, clamped = self.predict(np.asarray(x, dtype=np.float64))
            return float(comp[0]), bool(clamped[0])
        x = tuple(x)
        last = self.__dict__.get("_last_point")
        if last is not None and last[0] == x:  # quantised inputs repeat sample after sample: exact reuse
            return last[1]
        clamped = False
        xs = []
        lows, highs, means, scales = self._point_constants()
        shifted = self._shifted
        if shifted:  # clamp_rows, in Python floats
            first = shifted[0]
            value, low, high = x[first], lows[first], highs[first]
            shift = (low if value < low else high if value > high else value) - value
        for column, (value, low, high, mean, scale) in enumerate(zip(x, lows, highs, means, scales)):
            if shifted and column in shifted:
                used = value + shift
            else:
                used = low if value < low else high if value > high else value  # np.clip; NaN stays NaN
            if used != value:
                clamped = True
            xs.append((used - mean) / scale)
        result = (self.y_mean + self.y_scale * point(xs), clamped)
        if not clamped:  # (NaN inputs count as clamped, so a remembered row never holds one)
            object.__setattr__(self, "_last_point", (x, result))
        return result

    def _point_constants(self) -> tuple[tuple, ...]:
        constants = self.__dict__.get("_constants")
        if constants is None:
            constants = tuple(_floats(np.broadcast_to(array, (len(self.inputs),))) for array in (
                self.domain_min, self.domain_max, self.x_mean, self.x_scale))  # fmt: skip
            object.__setattr__(self, "_constants", constants)
        return constants

    def predict_unclamped(self, x: np.ndarray) -> np.ndarray:
        """The thermal error in deg/h with no domain guard (for comparisons with scikit-learn)."""
        xs = (np.asarray(x, dtype=np.float64) - self.x_mean) / self.x_scale
        return self.y_mean + self.y_scale * self.evaluator(xs)


def build_evaluator(method: str, params: dict) -> Evaluator:
    """The evaluator for `method` from its JSON-ready `params` (shapes are checked by the model-file loader)."""
    array = lambda key: np.asarray(params[key], dtype=np.float64)  # noqa: E731
    if method == "linear":
        return Linear(array("coef"), float(params["intercept"]))
    if method == "ls-poly":
        return Polynomial(np.asarray(params["powers"], dtype=np.int64), array("coef"), float(params["intercept"]))
    if method == "rbf-nn":
        return RbfNetwork(array("centres"), float(params["width"]), array("coef"), float(params["intercept"]))
    if method == "pso-svr":
        powers = params.get("trend_powers")
        powers = None if powers is None else np.asarray(powers, dtype=np.int64)
        inputs = array("trend_coef").size if powers is None else powers.shape[1]
        return Svr(
            array("support_vectors").reshape(-1, inputs),  # none at all when the trend explains everything
            array("dual_coef"), float(params["gamma"]), array("trend_coef"),
            float(params["intercept"]), powers,
        )  # fmt: skip
    raise ValueError(f"unknown method {method!r}")
