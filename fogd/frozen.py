"""Frozen, numpy-only model evaluators: what the daemon and replay run (never scikit-learn, never pickle).

A `FrozenModel` takes raw inputs (temperature, temperature rate, ...), clamps them to the calibrated domain
(as PX4's temperature compensation does, rather than extrapolating) and reports which rows were clamped,
scales them, and evaluates one of the method evaluators below in the scaled space:

    y_dph = y_mean + y_scale * g((clamp(x) - x_mean) / x_scale)

Each evaluator's parameters are exactly what the model file stores under `params`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from fogd.inputs import InputSpec

_CHUNK_ROWS = 4096  # kernel evaluations in blocks, so memory stays bounded on million-row replays


def _row_dot(rows: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """rows @ weights, summed row by row so a row's result never depends on how many rows came with it
    (BLAS may round differently by batch size; the daemon and replay must agree bit for bit)."""
    return (rows * weights).sum(axis=1)


@dataclass(frozen=True)
class Linear:
    """g(x) = coef . x + intercept (IEEE 952's linear model)."""

    coef: np.ndarray
    intercept: float

    def __call__(self, xs: np.ndarray) -> np.ndarray:
        return _row_dot(xs, self.coef) + self.intercept


@dataclass(frozen=True)
class Polynomial:
    """g(x) = sum_k coef_k prod_j x_j ** powers_kj + intercept (the least-squares polynomial)."""

    powers: np.ndarray  # (terms, inputs) non-negative integers
    coef: np.ndarray
    intercept: float

    def __call__(self, xs: np.ndarray) -> np.ndarray:
        terms = np.ones((xs.shape[0], self.powers.shape[0]))
        for column in range(self.powers.shape[1]):
            terms *= xs[:, column : column + 1] ** self.powers[:, column]
        return _row_dot(terms, self.coef) + self.intercept


def _gaussian_sum(xs: np.ndarray, centres: np.ndarray, weights: np.ndarray, gamma: float) -> np.ndarray:
    """sum_k weights_k exp(-gamma ||x - centre_k||^2) per row, in bounded-memory chunks."""
    out = np.empty(xs.shape[0])
    for start in range(0, xs.shape[0], _CHUNK_ROWS):
        block = xs[start : start + _CHUNK_ROWS]
        squared = ((block[:, None, :] - centres[None, :, :]) ** 2).sum(axis=2)
        out[start : start + _CHUNK_ROWS] = _row_dot(np.exp(-gamma * squared), weights)
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


@dataclass(frozen=True)
class Svr:
    """g(x) = trend_coef . x + sum_i dual_coef_i exp(-gamma ||x - sv_i||^2) + intercept (paper eq. 12-13,
    gamma = 1/(2 sigma^2); the linear trend is zero for the paper's plain SVR)."""

    support_vectors: np.ndarray
    dual_coef: np.ndarray
    gamma: float
    trend_coef: np.ndarray
    intercept: float

    def __call__(self, xs: np.ndarray) -> np.ndarray:
        kernel = _gaussian_sum(xs, self.support_vectors, self.dual_coef, self.gamma)
        return _row_dot(xs, self.trend_coef) + kernel + self.intercept


Evaluator = Callable[[np.ndarray], np.ndarray]


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

    def predict(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(thermal error in deg/h, True where an input was clamped) for raw input rows x of shape (n, d)."""
        x = np.asarray(x, dtype=np.float64).reshape(-1, len(self.inputs))
        clamped_x = np.clip(x, self.domain_min, self.domain_max)
        clamped = np.any(clamped_x != x, axis=1)
        return self.predict_unclamped(clamped_x), clamped

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
        trend_coef = array("trend_coef")
        return Svr(
            array("support_vectors").reshape(-1, trend_coef.size),  # none at all when the trend explains everything
            array("dual_coef"), float(params["gamma"]), trend_coef,
            float(params["intercept"]),
        )  # fmt: skip
    raise ValueError(f"unknown method {method!r}")
