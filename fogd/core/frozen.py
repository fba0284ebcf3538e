"""Frozen, numpy-only model evaluators: what the daemon and replay run (never scikit-learn, never pickle).

A `FrozenModel` takes raw inputs (temperature, temperature rate, ...), clamps them to the calibrated domain
(a lag bank's temperatures move together, fogd.core.inputs.clamp_rows) and reports which rows were clamped,
scales them, and evaluates one of the method evaluators below in the scaled space:

    y_dph = y_mean + y_scale * g((clamp(x) - x_mean) / x_scale)

A clamped row is then served by the model's `outside` policy (fogd.core.outside_range: the clamp as above,
or the edge continued in a straight line); inside the domain the policy changes nothing.

Each evaluator's parameters are exactly what the model file stores under `params`.

`FrozenModel.predict_one` is the per-sample form for one input row of Python floats: the same clamp, scaling
and sums in plain Python (each evaluator's `point`), because numpy's per-call overhead dominates one row. It
agrees with `predict` to rounding (sums in another order, `math.exp` for numpy's exp), far inside 1e-12
relative; large kernel models go through numpy instead, one row at a time (`POINT_NUMPY_WORK`).

`StackedModels` evaluates several models on the same inputs (an IMU's channels) together, in one numpy pass.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Callable, NamedTuple, Sequence

import numpy as np

from fogd.core import straightline
from fogd.core.inputs import InputSpec, clamp_rows, shifted_columns
from fogd.core.outside_range import OutsideRange, point_dot

_CHUNK_ROWS = 4096  # kernel evaluations in blocks, so memory stays bounded on million-row replays
# Above this many kernel terms x inputs one row is cheaper through numpy than a Python loop (tools/bench_point.py:
# the loop's cost grows with both, numpy's hardly)
POINT_NUMPY_WORK = 48
# A trend of more monomials than this (a coil trend expanded over a lag bank, as files from before `trend_mix`
# hold) is cheaper through numpy with the kernel (StackedModels, one row) than in a Python loop
POINT_TREND_TERMS = 40


def _floats(values: np.ndarray) -> tuple:
    return tuple(np.asarray(values, dtype=np.float64).tolist())


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
        return point_dot(xs, self._coef) + self.intercept


def monomials(xs: np.ndarray, powers: np.ndarray) -> np.ndarray:
    """Each row's monomials prod_j x_j ** powers_kj: the polynomial's features, in fitting and evaluation alike.

    Each monomial is the product of its nonzero factors x_j ** p in column order, left to right (x ** 0 is
    1.0 and 1.0 * x is x exactly, so leaving them out changes nothing: the floats of the full product, and of
    StackedModels' trend), and reuses the product of its leading
    factors when another monomial has formed it: a coil trend's cubic in nine inputs is 220 monomials formed
    in about 220 vector products instead of 220 x 9 powers and products (tools/bench_point.py 1b). Products
    are formed in place in the monomials' own columns; only leading factors that are no monomial take more."""
    xs = np.asarray(xs, dtype=np.float64)
    plan = _monomial_plan(np.asarray(powers))
    terms = np.empty((xs.shape[0], len(plan.outputs)))
    # x_j ** p as one np.power of the column against the powers 0..max (a scalar exponent would take numpy's
    # other paths, x * x for 2, and part in the last bit from the fit's features)
    exponents = np.arange(plan.top + 1, dtype=np.float64)
    tables: dict[int, np.ndarray] = {}
    products: list[np.ndarray] = []
    for step, (parent, column, power) in enumerate(plan.steps):
        table = tables.get(column)
        if table is None:
            table = tables[column] = np.power(xs[:, column : column + 1], exponents)
        factor = table[:, power]
        k = plan.column_of[step]
        out = terms[:, k] if k >= 0 else None
        if parent >= 0:
            products.append(np.multiply(products[parent], factor, out=out))
        elif out is not None:
            out[:] = factor
            products.append(out)
        else:
            products.append(factor)
    for k, node in enumerate(plan.outputs):
        if node < 0:
            terms[:, k] = 1.0
        elif plan.column_of[node] != k:  # a monomial listed twice
            terms[:, k] = terms[:, plan.column_of[node]]
    return terms


@dataclass(frozen=True)
class _MonomialPlan:
    steps: tuple[tuple[int, int, int], ...]  # (parent step or -1, column, power): one product each
    outputs: tuple[int, ...]  # each monomial's step, -1 for the constant 1
    column_of: tuple[int, ...]  # per step, the first monomial it is (its column), or -1
    top: int  # the highest power


def _monomial_plan(powers: np.ndarray) -> _MonomialPlan:
    """The products `monomials` forms for `powers`, each prefix of factors once."""
    table = powers.astype(np.int64)
    return _plan_of(table.tobytes(), table.shape)


@functools.lru_cache(maxsize=128)  # the tables in use (a model's, a fit's) stay; old ones leave
def _plan_of(table_bytes: bytes, shape: tuple[int, ...]) -> _MonomialPlan:
    steps: list[tuple[int, int, int]] = []
    index: dict[tuple[tuple[int, int], ...], int] = {}
    outputs = []
    for row in np.frombuffer(table_bytes, dtype=np.int64).reshape(shape).tolist():
        node, prefix = -1, ()
        for column, power in enumerate(row):
            if power == 0:
                continue
            prefix = (*prefix, (column, power))
            if prefix not in index:
                index[prefix] = len(steps)
                steps.append((node, column, power))
            node = index[prefix]
        outputs.append(node)
    column_of = [-1] * len(steps)
    for k, node in enumerate(outputs):
        if node >= 0 and column_of[node] < 0:
            column_of[node] = k
    return _MonomialPlan(tuple(steps), tuple(outputs), tuple(column_of), max((step[2] for step in steps), default=0))


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
        self._column = np.ascontiguousarray(self.centres[:, 0]) if self.centres.shape[1] == 1 else None
        self._last: tuple[list[float], float] | None = None  # the previous row and its sum (the numpy path)

    def __call__(self, xs: Sequence[float]) -> float:
        if self.use_numpy:
            last = self._last
            if last is not None and last[0] == xs:  # a kernel on the temperature alone: it repeats (exact reuse)
                return last[1]
            if self.centres.shape[1] == 1:  # one input (a kernel on the temperature): no sum over the inputs
                difference = self._column - xs[0]
                np.multiply(difference, difference, out=difference)
                difference *= self.neg_gamma
                value = float(np.dot(np.exp(difference, out=difference), self.weights))
            else:
                difference = self.centres - np.asarray(xs, dtype=np.float64)
                np.multiply(difference, difference, out=difference)
                squared = difference.sum(axis=1)
                squared *= self.neg_gamma
                value = float(np.dot(np.exp(squared, out=squared), self.weights))
            self._last = (list(xs), value)  # (NaN == NaN is False: a NaN row is never reused)
            return value
        neg_gamma, exp = self.neg_gamma, math.exp
        total = 0.0
        if len(xs) == 1:  # a kernel on the temperature alone (0.0 + d * d is d * d: the same floats as below)
            x0 = xs[0]
            for (c0,), weight in self.terms:
                d0 = x0 - c0
                total += weight * exp(neg_gamma * (d0 * d0))
            return total
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


def _distinct_gaussian_sum(xs: np.ndarray, centres: np.ndarray, weights: np.ndarray, gamma: float) -> np.ndarray:
    """`_gaussian_sum` evaluated once per distinct row (exact: a row's sum is that row's alone). A kernel that
    reads the temperature alone sees a few hundred distinct values in a run of a quantised sensor, while the
    lags beside it make every whole row distinct (tools/bench_point.py 1b, 4,096 a call)."""
    if len(xs) < _UNIQUE_MIN_ROWS or not len(weights):
        return _gaussian_sum(xs, centres, weights, gamma)
    rows, inverse = unique_rows(xs)
    return _gaussian_sum(rows, centres, weights, gamma)[inverse]


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
    (fogd's polynomial trend); it is zero for the paper's plain SVR. With `trend_mix` the monomials read one
    more input after the model's own, the coil temperature q = trend_mix . x (fogd.calibration.models.coil):
    the default trend is every input linear plus powers of q, 11 terms over a nine-input lag bank where its
    expansion into monomials of the inputs has 165. The kernel reads the inputs `kernel_columns` only when
    given (over a lag bank, the sensor's temperature: the static curve the trend leaves, not the thermal
    state), and every input otherwise."""

    support_vectors: np.ndarray
    dual_coef: np.ndarray
    gamma: float
    trend_coef: np.ndarray
    intercept: float
    trend_powers: np.ndarray | None = None
    kernel_columns: tuple[int, ...] | None = None
    trend_mix: np.ndarray | None = None

    def __call__(self, xs: np.ndarray) -> np.ndarray:
        if self.kernel_columns is None:
            kernel = _gaussian_sum(xs, self.support_vectors, self.dual_coef, self.gamma)
        else:
            kernel = _distinct_gaussian_sum(xs[:, list(self.kernel_columns)], self.support_vectors, self.dual_coef,
                                            self.gamma)  # fmt: skip
        if self.trend_powers is None:
            terms = xs
        elif self.trend_mix is None:
            terms = monomials(xs, self.trend_powers)
        else:
            terms = monomials(np.column_stack((xs, _row_dot(xs, self.trend_mix))), self.trend_powers)
        return _row_dot(terms, self.trend_coef) + kernel + self.intercept

    def __post_init__(self) -> None:
        object.__setattr__(self, "_point", _GaussianPoint(self.support_vectors, self.dual_coef, self.gamma))
        trend = (Linear(self.trend_coef, 0.0) if self.trend_powers is None
                 else Polynomial(self.trend_powers, self.trend_coef, 0.0))  # fmt: skip
        object.__setattr__(self, "_trend_point", trend.point)
        object.__setattr__(self, "_mix", None if self.trend_mix is None else _floats(self.trend_mix))

    def point(self, xs: Sequence[float]) -> float:
        columns, mix = self.kernel_columns, self._mix
        if columns is None:
            kernel = self._point(xs)
        elif len(columns) == 1:  # (a list comprehension is a call of its own in Python 3.11)
            kernel = self._point((xs[columns[0]],))
        else:
            kernel = self._point([xs[column] for column in columns])
        trend = self._trend_point(xs) if mix is None else self._trend_point([*xs, point_dot(xs, mix)])
        return trend + kernel + self.intercept


Evaluator = Callable[[np.ndarray], np.ndarray]
_UNIQUE_MIN_ROWS = 64
# StackedModels: fewer rows than _UNIQUE_MIN_ROWS but more than this evaluate their kernels once per run of equal
# rows (bit for bit: a row's sums are that row's alone)
_RUN_MIN_ROWS = 4


def _row_changes(bits: np.ndarray) -> np.ndarray:
    """True where a row (of a float array viewed as int64) differs bit for bit from the row before; the first
    row always: where each run of equal consecutive rows starts."""
    change = np.empty(len(bits), dtype=bool)
    change[0] = True
    np.any(bits[1:] != bits[:-1], axis=1, out=change[1:])
    return change


def unique_rows(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(distinct rows, index of each row of x among them), rows compared bit for bit (-0.0 is not 0.0).

    Runs of equal consecutive rows are collapsed first (cheap, and most repeats are consecutive), then the
    runs' rows are sorted, which is much faster than np.unique(axis=0) on the whole array."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    n = x.shape[0]
    if n == 0:
        return x, np.zeros(0, dtype=np.intp)
    bits = x.view(np.int64)
    change = _row_changes(bits)
    starts = np.flatnonzero(change)
    run_of_row = np.cumsum(change) - 1
    firsts = bits[starts]
    order = np.lexsort(firsts.T[::-1]) if x.shape[1] else np.arange(starts.size)
    new = _row_changes(firsts[order])  # sorted, equal rows are neighbours
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
    outside: OutsideRange | None = field(default=None, compare=False)  # beyond the domain (None: the clamp)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_shifted", shifted_columns(self.inputs))  # clamp_rows' temperature columns
        beyond = self.outside is not None and self.outside.policy != "clamp"
        object.__setattr__(self, "_beyond", beyond)  # fogd.core.outside_range: a policy other than the clamp

    def predict(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(thermal error in deg/h, True where an input was clamped) for raw input rows x of shape (n, d)."""
        x = np.asarray(x, dtype=np.float64).reshape(-1, len(self.inputs))
        clamped_x = clamp_rows(x, self.domain_min, self.domain_max, self._shifted)
        clamped = np.any(clamped_x != x, axis=1)
        if len(clamped_x) >= _UNIQUE_MIN_ROWS and isinstance(self.evaluator, (Polynomial, Svr, RbfNetwork)):
            # Exact: a row's result depends on that row alone, and quantised temperatures (and the rates eq. 16
            # makes of them) repeat, so a million-row replay holds a few ten thousand distinct rows.
            rows, inverse = unique_rows(clamped_x)
            comp = self.predict_unclamped(rows)[inverse]
        else:
            comp = self.predict_unclamped(clamped_x)
        if self._beyond and clamped.any():
            comp[clamped] = self.beyond_rows(x[clamped])
        return comp, clamped

    def beyond_rows(self, x: np.ndarray) -> np.ndarray:
        """The thermal error of raw rows outside the domain by the model's `outside` policy (fogd.core.outside_range)."""
        mean, scale = self.x_mean, self.x_scale
        clamp = lambda rows: clamp_rows(rows, self.domain_min, self.domain_max, self._shifted)  # noqa: E731

        def inside_g(ys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            back = (clamp(ys * scale + mean) - mean) / scale
            return self.evaluator(back), back

        cs = (clamp(x) - mean) / scale
        g = self.outside.rows((x - mean) / scale, cs, self.evaluator(cs), inside_g)
        return self.y_mean + self.y_scale * g

    def beyond_one(self, x: Sequence[float]) -> float:
        """`beyond_rows` of one raw row of Python floats."""
        lows, highs, means, scales = self._point_constants()
        evaluate = getattr(self.evaluator, "point", None)
        if evaluate is None:
            evaluate = lambda xs: float(self.evaluator(np.array([xs], dtype=np.float64))[0])  # noqa: E731

        def scaled_clamp(row: Sequence[float]) -> list[float]:
            used, _ = self._clamp_one(row, lows, highs)
            return [(u - m) / s for u, m, s in zip(used, means, scales)]

        def inside_g(ys: list[float]) -> tuple[float, list[float]]:
            back = scaled_clamp([y * s + m for y, m, s in zip(ys, means, scales)])
            return evaluate(back), back

        cs = scaled_clamp(x)
        xs = [(v - m) / s for v, m, s in zip(x, means, scales)]
        return self.y_mean + self.y_scale * self.outside.one(xs, cs, evaluate(cs), inside_g)

    def _clamp_one(self, x: Sequence[float], lows: Sequence[float], highs: Sequence[float]) -> tuple[list[float], bool]:
        """clamp_rows of one row in Python floats: (the row used, True if it moved)."""
        shifted = self._shifted
        if shifted:  # the temperature columns move by their first one's clip
            first = shifted[0]
            value, low, high = x[first], lows[first], highs[first]
            shift = (low if value < low else high if value > high else value) - value
        used, clamped = [], False
        for column, (value, low, high) in enumerate(zip(x, lows, highs)):
            if shifted and column in shifted:
                new = value + shift
            else:
                new = low if value < low else high if value > high else value  # np.clip; NaN stays NaN
            if new != value:
                clamped = True
            used.append(new)
        return used, clamped

    def predict_one(self, x: Sequence[float]) -> tuple[float, bool]:
        """`predict` for one row of Python floats: (thermal error in deg/h, True if an input was clamped)."""
        row = self.__dict__.get("_one")
        if row is None:
            row = self._one_plan()
        if row is False:
            return self._predict_one_otherwise(x)
        x = tuple(x)
        last = self.__dict__.get("_last_point")
        if last is not None and last[0] == x:  # quantised inputs repeat sample after sample: exact reuse
            return last[1]
        result = row(x)
        if result[1]:  # (NaN inputs count as clamped, so a remembered row never holds one)
            return (self.beyond_one(x), True) if self._beyond else result
        object.__setattr__(self, "_last_point", (x, result))
        return result

    def _one_plan(self, straight: bool = True) -> Callable[[tuple[float, ...]], tuple[float, bool]] | bool:
        """predict_one's row function, made once: the row written out as straight-line Python where it can be
        (fogd.core.straightline; with `straight` False, never), else `_loop_row`; False for a model that takes
        another path (`_predict_one_otherwise`)."""
        point = getattr(self.evaluator, "point", None)
        rows = self.__dict__.get("_rows")
        if rows is None:
            rows = self._row_path()
        if point is None or rows is not False:
            plan: Callable | bool = False
        else:
            columns, first = self.row_columns()
            plan = (straight and straightline.row_function(self.evaluator, columns, first, self.y_mean, self.y_scale,
                                                           self._beyond)) or self._loop_row(point, columns, first)  # fmt: skip
        object.__setattr__(self, "_one", plan)
        return plan

    def row_columns(self) -> tuple[tuple[tuple[float, float, float, float, bool], ...], int | None]:
        """Each column's (low, high, mean, scale, moved with the temperature?) and the temperature column whose
        clip moves them (clamp_rows; None: no column moves)."""
        shifted = self._shifted
        columns = tuple((*bounds, column in shifted) for column, bounds in enumerate(zip(*self._point_constants())))
        return columns, (shifted[0] if shifted else None)

    def _loop_row(self, point: Callable[[list[float]], float], columns: tuple, first: int | None) -> Callable:
        """The row function as a loop over the columns: clamp_rows in Python floats, scaling, the evaluator's
        `point` and output scaling; a clamped row under another policy than the clamp is (0.0, True), left to
        predict_one (as straightline's rows)."""
        y_mean, y_scale, beyond = self.y_mean, self.y_scale, self._beyond

        def looped_row(x: tuple[float, ...]) -> tuple[float, bool]:
            clamped = False
            xs = []
            shift = 0.0
            if first is not None:
                value, (low, high, _, _, _) = x[first], columns[first]
                shift = (low if value < low else high if value > high else value) - value
            for value, (low, high, mean, scale, moves) in zip(x, columns):
                if moves:
                    used = value + shift
                else:
                    used = low if value < low else high if value > high else value  # np.clip; NaN stays NaN
                if used != value:
                    clamped = True
                xs.append((used - mean) / scale)
            if clamped and beyond:
                return 0.0, True
            return y_mean + y_scale * point(xs), clamped

        return looped_row

    def _predict_one_otherwise(self, x: Sequence[float]) -> tuple[float, bool]:
        """predict_one of a large kernel model (its trend and kernel in a few numpy calls, and the policy) or of
        a plain callable evaluator (the array path)."""
        rows = self.__dict__.get("_rows")
        if rows is not False:
            comps, clamped_all = rows.predict_one(x)
            return comps[0], clamped_all[0]
        comp, clamped = self.predict(np.asarray(x, dtype=np.float64))
        return float(comp[0]), bool(clamped[0])

    def _row_path(self) -> StackedModels | bool:
        """For a kernel model too large for a Python loop (POINT_NUMPY_WORK) whose trend has more than
        POINT_TREND_TERMS monomials (a coil trend expanded, as files from before `trend_mix` hold), the model
        alone as a stack: one row through numpy in a few calls, trend included; False for every other model,
        whose trend is cheaper in Python floats beside its kernel's few numpy calls (tools/bench_point.py 1b
        times fogd-train's default one sample a call)."""
        point = getattr(self.evaluator, "_point", None)
        long_trend = len(getattr(self.evaluator, "trend_coef", ())) > POINT_TREND_TERMS
        rows = StackedModels([self]) if isinstance(point, _GaussianPoint) and point.use_numpy and long_trend else False
        object.__setattr__(self, "_rows", rows)
        return rows

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
        mix = None if params.get("trend_mix") is None else array("trend_mix")
        inputs = array("trend_coef").size if powers is None else powers.shape[1] - (mix is not None)
        columns = params.get("kernel_columns")
        columns = None if columns is None else tuple(int(column) for column in columns)
        return Svr(
            array("support_vectors").reshape(-1, inputs if columns is None else len(columns)),  # none at all when
            array("dual_coef"), float(params["gamma"]), array("trend_coef"),  # the trend explains everything
            float(params["intercept"]), powers, columns, mix,
        )  # fmt: skip
    raise ValueError(f"unknown method {method!r}")


_STACK_ELEMENTS = 1 << 17  # rows x terms x inputs per block of StackedModels.predict: bounded memory (1 MiB)


class _StackTerms(NamedTuple):
    """A stackable model in its scaled space: every method evaluator is a polynomial trend (a linear one has the
    identity's powers: x ** 1 is x and x ** 0 is 1.0 exactly; a coil trend's powers have one more column, q)
    plus a Gaussian kernel sum plus an intercept. The centres have every input; those the kernel does not read
    are 0 there."""

    powers: np.ndarray  # the trend's monomials
    trend_coef: np.ndarray
    centres: np.ndarray  # the kernel's
    weights: np.ndarray
    gamma: float
    intercept: float
    read: np.ndarray  # the inputs the kernel reads (bool, one per input)
    mix: np.ndarray | None  # the coil trend's mix (its q = mix . x), or None


def _stack_terms(model: FrozenModel) -> _StackTerms:
    """A stackable model's trend and kernel terms (`_StackTerms`)."""
    evaluator, d = model.evaluator, len(model.inputs)
    identity = np.eye(d, dtype=np.int64)
    no_centres, no_weights, every = np.empty((0, d)), np.empty(0), np.ones(d, dtype=bool)
    if isinstance(evaluator, Linear):
        return _StackTerms(identity, evaluator.coef, no_centres, no_weights, 0.0, evaluator.intercept, every, None)
    if isinstance(evaluator, Polynomial):
        return _StackTerms(evaluator.powers, evaluator.coef, no_centres, no_weights, 0.0, evaluator.intercept, every,
                           None)  # fmt: skip
    if isinstance(evaluator, RbfNetwork):
        return _StackTerms(np.empty((0, d), dtype=np.int64), np.empty(0), evaluator.centres, evaluator.coef,
                           0.5 / evaluator.width**2, evaluator.intercept, every, None)  # fmt: skip
    assert isinstance(evaluator, Svr)
    powers = identity if evaluator.trend_powers is None else evaluator.trend_powers
    centres, read = evaluator.support_vectors, every
    if evaluator.kernel_columns is not None:
        read = np.zeros(d, dtype=bool)
        read[list(evaluator.kernel_columns)] = True
        centres = np.zeros((len(evaluator.support_vectors), d))
        centres[:, read] = evaluator.support_vectors
    return _StackTerms(powers, evaluator.trend_coef, centres, evaluator.dual_coef, evaluator.gamma, evaluator.intercept,
                       read, evaluator.trend_mix)  # fmt: skip


class StackedModels:
    """Several frozen models on the same inputs (an IMU's channels) evaluated in one numpy pass per block of rows,
    so six channels cost a few numpy calls more than one rather than six times their calls.

    Each channel's input row is clamped and scaled as its own model does; the kernel terms of every channel
    (support vectors, RBF centres) are stacked into one matrix whose rows each read their channel's scaled row,
    with per-row -gamma and weights, exp'd once and summed per channel (np.add.reduceat); the trend monomials
    likewise. One row goes through the very operations of many (`predict_one` is `predict` of that row, bit for
    bit, whatever the block); against a model's own `predict` only the order of the kernel and trend sums
    differs, so each channel agrees with it within 1e-12 relative. (The centres stay in each model's scaled
    space rather than raw units with the scaling folded into per-row weights: then every difference and square
    is the model's own float, and nothing but the summation order can part them.)"""

    def __init__(self, models: Sequence[FrozenModel]) -> None:
        if not models:
            raise ValueError("StackedModels needs at least one model")
        inputs = models[0].inputs
        if any(model.inputs != inputs for model in models) or not all(map(self.supports, models)):
            raise ValueError("StackedModels stacks the method evaluators of models on the same inputs")
        d, count = len(inputs), len(models)
        self.models = tuple(models)
        self.inputs = inputs
        self._beyond_columns = [k for k, model in enumerate(models) if model._beyond]  # fogd.core.outside_range
        self._shifted = models[0]._shifted
        moved = sorted(self._shifted)  # the columns clamp_rows moves together: a slice when they are adjacent
        self._moved: slice | np.ndarray = (slice(moved[0], moved[-1] + 1) if moved and moved[-1] - moved[0] + 1 == len(moved)
                                           else np.array(moved, dtype=np.intp))  # fmt: skip
        per_channel = lambda name: np.stack([np.broadcast_to(np.asarray(getattr(m, name), dtype=np.float64), (d,))
                                             for m in models], axis=1)[:, None, :]  # fmt: skip
        self._low, self._high = per_channel("domain_min"), per_channel("domain_max")
        self._mean, self._scale = per_channel("x_mean"), per_channel("x_scale")
        self._y_mean = np.array([m.y_mean for m in models], dtype=np.float64)
        self._y_scale = np.array([m.y_scale for m in models], dtype=np.float64)
        terms = [_stack_terms(model) for model in models]
        self._intercept = np.array([t.intercept for t in terms], dtype=np.float64)
        # trend: every channel's monomials, each the product of its nonzero factors x_j ** p in column order (as
        # `monomials` forms them: the factors x ** 0 = 1.0 it leaves out change no product), read from a table of
        # the (input, power) pairs some monomial uses, per channel; x ** p is formed as x ** (p - 1) * x, so a
        # row's floats are the same whatever the block (numpy's power may take vector paths that part in the last
        # bit). Coil trends read one more input, q = mix . x (a channel with none: q = 0 and no power of it).
        coil = any(t.mix is not None for t in terms)
        self._mix = (np.stack([np.zeros(d) if t.mix is None else np.asarray(t.mix, dtype=np.float64) for t in terms],
                              axis=1)[:, None, :] if coil else None)  # fmt: skip
        powers = [np.asarray(t.powers, dtype=np.int64).reshape(-1, d + (t.mix is not None)) for t in terms]
        if coil:
            powers = [p if t.mix is not None else np.column_stack((p, np.zeros(len(p), dtype=np.int64)))
                      for p, t in zip(powers, terms)]  # fmt: skip
        t_sizes = [len(t.trend_coef) for t in terms]
        self._t_cols = np.flatnonzero(t_sizes)
        with_trend = self._t_cols.tolist()
        self._t_plan = _factor_plan([powers[k] for k in with_trend], with_trend, count, coil)
        longest = max(t_sizes)
        # every trend's coefficients padded to the longest with zeros (a padded term is 1.0 * 0.0 = 0.0)
        self._coef = np.zeros((len(with_trend), longest))
        for row, k in enumerate(with_trend):
            self._coef[row, : t_sizes[k]] = terms[k].trend_coef
        # kernel: the centres of every channel, each reading its channel's scaled inputs, with their channel's
        # -gamma and their weights
        k_sizes = [len(t.weights) for t in terms]
        self._k_cols = np.flatnonzero(k_sizes)
        self._k_sizes = np.array(k_sizes, dtype=np.intp)
        self._k_starts = _starts(k_sizes)
        # the inputs some kernel reads (the sensor's temperature alone, over a lag bank): the differences are
        # formed for those only, in column order, and an input no kernel reads adds nothing to any sum
        reads = np.concatenate([np.repeat(t.read[None, :], size, axis=0) for t, size in zip(terms, k_sizes)])
        read_any = reads.any(axis=0)
        self._k_read = None if read_any.all() else np.flatnonzero(read_any)
        reads = reads[:, read_any]
        centres = np.concatenate([np.asarray(t.centres, dtype=np.float64).reshape(-1, d) for t in terms])[:, read_any]
        self._centres = centres.T[:, None, :].copy()
        self._weights = np.concatenate([np.asarray(t.weights, dtype=np.float64) for t in terms])
        self._neg_gamma = np.repeat([-t.gamma for t in terms], k_sizes).astype(np.float64)
        # kernels that read different inputs: the differences of the inputs a centre's kernel does not read are
        # multiplied by 0 before squaring (x * 1.0 is x exactly, and adding 0.0 leaves a sum as it was: the very
        # floats of the model alone)
        self._reads = None if reads.all() else reads.T[:, None, :].astype(np.float64)
        self._every_trend = len(self._t_cols) == count
        self._every_kernel = len(self._k_cols) == count
        # a block's largest temporaries, per row: the trend's table of factors and its factors by monomial, and the
        # kernels' differences (the inputs some kernel reads, by centre)
        per_row = ((len(self._t_plan.pairs) + 1) * count + int(np.prod(self._t_plan.shape))
                   + centres.shape[1] * len(self._weights))  # fmt: skip
        self._block_rows = max(1, _STACK_ELEMENTS // max(1, per_row))
        self._last: tuple | None = None
        self._last_kernel: tuple[list, list[float]] | None = None  # `_one`'s previous kernel inputs and sums

    @staticmethod
    def supports(model: FrozenModel) -> bool:
        """Whether the model's evaluator can be stacked (every method's; not a plain callable)."""
        return type(model.evaluator) in (Linear, Polynomial, RbfNetwork, Svr)

    def __len__(self) -> int:
        return len(self.models)

    def predict(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(thermal error, True where an input was clamped), each (rows, models), for raw input rows x (n, d):
        column k is models[k].predict(x) (within 1e-12 relative)."""
        x = np.ascontiguousarray(x, dtype=np.float64).reshape(-1, len(self.inputs))
        if len(x) >= _UNIQUE_MIN_ROWS:  # exact, as FrozenModel.predict: a row's result is that row's alone
            rows, inverse = unique_rows(x)
            comp, clamped = self._blocks(rows)
            comp, clamped = comp[inverse], clamped[inverse]
        else:
            comp, clamped = self._blocks(x)
        for k in self._beyond_columns:  # each model's own policy beyond its domain (fogd.core.outside_range)
            if clamped[:, k].any():
                comp[clamped[:, k], k] = self.models[k].beyond_rows(x[clamped[:, k]])
        return comp, clamped

    def predict_one(self, x: Sequence[float]) -> tuple[list[float], list[bool]]:
        """`predict` of one row of Python floats, as lists by model: the same floats as `predict`."""
        x = tuple(x)
        last = self._last
        if last is not None and last[0] == x:  # quantised inputs repeat sample after sample: exact reuse
            return last[1]
        result = self._one(x)
        if self._beyond_columns and True in result[1]:  # each model's own policy beyond its domain
            for k in self._beyond_columns:
                if result[1][k]:
                    result[0][k] = self.models[k].beyond_one(x)
        if all(value == value for value in x):  # a NaN row is never remembered (NaN == NaN is False)
            self._last = (x, result)
        return result

    def _one(self, x: tuple[float, ...]) -> tuple[list[float], list[bool]]:
        """`_evaluate` of one row: the clamp, the scaling and the final affine map in Python floats (the very
        IEEE operations numpy applies element by element, in the same order), the trend and kernel sums in
        numpy on the (inputs, 1, models) block `_evaluate` forms."""
        shifted, constants = self._shifted, self._row_constants
        first = shifted[0] if shifted else -1
        rows: list[list[float]] = []
        flags: list[bool] = []
        # once per distinct set of constants: an IMU's channels, trained on the same runs, share their inputs'
        # domain and scaling, so six channels clamp and scale the row once
        for lows, highs, means, scales in constants:
            if shifted:  # clamp_rows: the temperature columns move by their first one's clip
                value, low, high = x[first], lows[first], highs[first]
                shift = (low if value < low else high if value > high else value) - value
            was_clamped = False
            row = []
            for column, value in enumerate(x):
                if column in shifted:
                    used = value + shift
                else:
                    low, high = lows[column], highs[column]
                    used = low if value < low else high if value > high else value  # np.clip; NaN stays NaN
                if used != value:
                    was_clamped = True
                row.append((used - means[column]) / scales[column])
            rows.append(row)
            flags.append(was_clamped)
        owner = self._constants_of
        if len(rows) == 1:
            scaled = [[value] * len(owner) for value in rows[0]]
            clamped = flags * len(owner)
        else:
            scaled = [list(column) for column in zip(*(rows[k] for k in owner))]
            clamped = [flags[k] for k in owner]
        xs = np.array(scaled, dtype=np.float64).reshape(len(x), 1, len(owner))
        trend = self._trend(xs)[0].tolist() if len(self._t_cols) else []
        kernel: list[float] = []
        if len(self._k_cols):
            read = scaled if self._k_read is None else [scaled[column] for column in self._k_read]
            last = self._last_kernel
            if last is not None and last[0] == read:  # kernels on the temperature alone: it repeats (exact reuse)
                kernel = last[1]
            else:
                kernel = self._kernel(xs)[0].tolist()
                self._last_kernel = (read, kernel)  # (a NaN input never compares equal: never reused)
        comps = []
        for index, (has_trend, has_kernel, intercept, y_scale, y_mean) in enumerate(self._row_tail):
            value = trend[has_trend] if has_trend >= 0 else 0.0
            if has_kernel >= 0:
                value = value + kernel[has_kernel]
            comps.append((value + intercept) * y_scale + y_mean)
        return comps, clamped

    @property
    def _row_constants(self) -> list[tuple[tuple, ...]]:
        constants = self.__dict__.get("_constants")
        if constants is None:
            every = [model._point_constants() for model in self.models]
            # the distinct ones, in channel order, told apart bit for bit (0.0 and -0.0 are equal, not the same)
            keys = [tuple(tuple(value.hex() for value in array) for array in one) for one in every]
            distinct = list(dict.fromkeys(keys))
            constants = self._constants = [every[keys.index(key)] for key in distinct]
            self._constants_of = [distinct.index(key) for key in keys]  # each channel's
            t_cols, k_cols = self._t_cols.tolist(), self._k_cols.tolist()
            self._row_tail = [
                (t_cols.index(k) if k in t_cols else -1, k_cols.index(k) if k in k_cols else -1, intercept, y_scale, y_mean)
                for k, (intercept, y_scale, y_mean) in enumerate(zip(self._intercept.tolist(), self._y_scale.tolist(),
                                                                     self._y_mean.tolist()))
            ]  # fmt: skip
        return constants

    def _blocks(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if len(x) <= self._block_rows:
            return self._evaluate(x)
        parts = [self._evaluate(x[start : start + self._block_rows]) for start in range(0, len(x), self._block_rows)]
        return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])

    def _evaluate(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # (inputs, rows, models) throughout: sums and products over the inputs are one vectorised pass per
        # input in column order, the same floats for one row as for a block
        raw = x.T[:, :, None]
        xs = np.maximum(raw, self._low)  # np.clip, as clamp_rows, for every model at once
        np.minimum(xs, self._high, out=xs)
        if self._shifted:
            first, moved = self._shifted[0], self._moved
            shift = xs[first] - raw[first]
            if isinstance(moved, slice):
                np.add(raw[moved], shift, out=xs[moved])
            else:
                xs[moved] = raw[moved] + shift
        clamped = np.logical_or.reduce(xs != raw, axis=0)
        xs -= self._mean
        xs /= self._scale
        if self._every_trend:
            g = self._trend(xs)
        else:
            g = np.zeros(xs.shape[1:])
            if len(self._t_cols):
                g[:, self._t_cols] = self._trend(xs)
        if self._every_kernel:
            g += self._kernel(xs)
        elif len(self._k_cols):
            g[:, self._k_cols] += self._kernel(xs)
        g += self._intercept
        g *= self._y_scale
        g += self._y_mean
        return g, clamped

    def _trend(self, xs: np.ndarray) -> np.ndarray:
        """(rows, channels with a trend). Every sum and product is an accumulation, left to right by definition:
        numpy's reductions may add pairwise, in an order that depends on the array's layout (one row of one
        trend is laid out as a vector), and a row's floats must not depend on the rows beside it."""
        plan = self._t_plan
        _, rows, models = xs.shape
        table = np.empty((rows, len(plan.pairs) + 1, models))  # (row, pair, model); the last pair is x ** 0 = 1.0
        firsts = plan.levels[0]
        if self._mix is None:
            table[:, : len(firsts)] = xs[firsts].transpose(1, 0, 2)
        else:  # the coil temperature q = mix . x, the last input, summed over the inputs in column order
            table[:, : len(firsts) - 1] = xs[firsts[:-1]].transpose(1, 0, 2)
            table[:, len(firsts) - 1] = np.add.accumulate(xs * self._mix, axis=0)[-1]
        for level, lower, base in plan.levels[1:]:  # the powers 2, 3, ...: x ** (p - 1) * x
            np.multiply(table[:, lower], table[:, base], out=table[:, level])
        table[:, -1] = 1.0
        flat = table.reshape(rows, table.shape[1] * models)
        terms = flat.take(plan.index, axis=1).reshape(rows, *plan.shape)  # (rows, factors, channels, monomials)
        monomials = terms[:, 0] if plan.shape[0] == 1 else np.multiply.accumulate(terms, axis=1)[:, -1]
        monomials *= self._coef
        return np.add.accumulate(monomials, axis=2)[:, :, -1]

    def _kernel(self, xs: np.ndarray) -> np.ndarray:
        if self._k_read is not None:
            xs = xs[self._k_read]
        inputs, rows, models = xs.shape
        if rows >= _UNIQUE_MIN_ROWS:  # once per distinct row of what the kernels read (as _distinct_gaussian_sum)
            distinct, inverse = unique_rows(xs.transpose(1, 0, 2).reshape(rows, inputs * models))
            return self._kernel_sums(distinct.reshape(-1, inputs, models).transpose(1, 0, 2))[inverse]
        if rows > _RUN_MIN_ROWS:  # a daemon's batch: what the kernels read (the temperature) repeats in runs
            starts = np.flatnonzero(_row_changes(xs.transpose(1, 0, 2).reshape(rows, inputs * models).view(np.int64)))
            if starts.size <= rows // 2:
                return self._kernel_sums(xs[:, starts]).repeat(np.diff(starts, append=rows), axis=0)
        return self._kernel_sums(xs)

    def _kernel_sums(self, xs: np.ndarray) -> np.ndarray:
        difference = xs.repeat(self._k_sizes, axis=2)  # each centre's row reads its model's inputs
        difference -= self._centres
        if self._reads is not None:
            difference *= self._reads
        np.multiply(difference, difference, out=difference)
        squared = np.add.reduce(difference, axis=0)  # over the inputs, in column order
        squared *= self._neg_gamma
        np.exp(squared, out=squared)
        squared *= self._weights
        return np.add.reduceat(squared, self._k_starts, axis=1)


class _FactorPlan(NamedTuple):
    """How StackedModels._trend reads every trend's monomials from a table of their factors x_j ** p."""

    pairs: list[tuple[int, int]]  # the (input, power) pairs some monomial uses: the powers 1, then 2, ...
    levels: list  # the inputs of the powers 1; then per power p above 1, where x ** p, x ** (p - 1) and x are
    index: np.ndarray  # per (factor, channel, monomial), where in a row of the table flattened (pair, model)
    shape: tuple[int, int, int]  # (most factors of a monomial, channels with a trend, most monomials)


def _factor_plan(powers: list[np.ndarray], channels: list[int], count: int, coil: bool) -> _FactorPlan:
    """`_FactorPlan` of the trends `powers` of `channels` (of `count` stacked models); with `coil`, their last
    input is q, which has a place in the table whether or not a monomial uses it. A monomial's factors are its nonzero powers in column order (x ** 0 = 1.0 changes no product),
    padded with the table's 1.0, as are the monomials of a shorter trend."""
    used: dict[int, int] = {}  # input -> highest power used
    for table in powers:
        for row in table.tolist():
            for column, power in enumerate(row):
                if power:
                    used[column] = max(used.get(column, 0), power)
    if coil and powers:  # `_trend` writes q into the table
        q = powers[0].shape[1] - 1
        used[q] = max(used.get(q, 0), 1)
    pairs = sorted(((column, power) for column, top in used.items() for power in range(1, top + 1)),
                   key=lambda pair: (pair[1], pair[0]))  # fmt: skip
    where = {pair: index for index, pair in enumerate(pairs)}
    levels: list = [np.array([column for column, power in pairs if power == 1], dtype=np.intp)]
    for level in range(2, max(used.values(), default=1) + 1):
        columns = [column for column, power in pairs if power == level]
        # the pairs of a power are adjacent (sorted by power): a slice, a view the products are written into
        levels.append((slice(where[(columns[0], level)], where[(columns[-1], level)] + 1),
                       _as_slice([where[(column, level - 1)] for column in columns]),
                       _as_slice([where[(column, 1)] for column in columns])))  # fmt: skip
    one = len(pairs) * count  # the 1.0 (the last pair, any model), in a row flattened as (pair, model)
    slots = [[[where[(column, power)] * count + k for column, power in enumerate(row) if power] for row in table.tolist()]
             for k, table in zip(channels, powers)]  # fmt: skip
    factors = max((len(slot) for trend in slots for slot in trend), default=1) or 1
    monomials = max((len(trend) for trend in slots), default=0)
    index = np.full((factors, len(slots), monomials), one, dtype=np.intp)
    for row, trend in enumerate(slots):
        for m, slot in enumerate(trend):
            index[: len(slot), row, m] = slot
    return _FactorPlan(pairs, levels, index.reshape(-1), (factors, len(slots), monomials))


def _as_slice(indices: list[int]) -> slice | np.ndarray:
    """`indices` as a slice where they are consecutive (a view, no copy), else as an index array."""
    if indices and indices == list(range(indices[0], indices[0] + len(indices))):
        return slice(indices[0], indices[0] + len(indices))
    return np.array(indices, dtype=np.intp)


def _starts(sizes: list[int]) -> np.ndarray:
    """Where each non-empty segment of `sizes` starts in their concatenation (np.add.reduceat's indices)."""
    ends = np.cumsum(sizes)
    return np.array([end - size for end, size in zip(ends.tolist(), sizes) if size], dtype=np.intp)
