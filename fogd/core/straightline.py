"""A frozen model's one row written out as straight-line Python: the daemon's per-sample sum, run cold.

Per sample FrozenModel.predict_one loops over tuples: a clamp per column, then the evaluator's `point` (several
calls, a loop's bytecodes per term, a tuple unpacked per factor). `row_function` writes that clamp, scaling,
point and output scaling out as one function with the model's constants in its code: far fewer bytecodes and
objects touched (tools/bench_point.py 1d times both, warm and with the caches flushed before each call). The
float operations are the very same, in the very same order, so the result is the same float, bit for bit: x ** 0
is 1.0 and 1.0 * x is x exactly, and a sum of squares starting from 0.0 or not is the same (d * d is never -0.0).
On the daemon's row path (the bundled demo model) a frame's lexing, compensation, encoding and write went from
22-24 to 17-19 us in process; on a dedicated box (tools/bench_dedicated.py, issue 37) the change was within
that benchmark's noise: there a frame's cost is mostly not its Python's.

The source holds nothing a model file could smuggle in: fixed names, integer indices and powers, and the
model's constants as `repr` of finite floats (which reads back as the same float). Anything else (a kernel
large enough for numpy, POINT_NUMPY_WORK; a non-finite constant; more than MAX_TERMS terms) gets None, and
predict_one's loop serves.
"""

from __future__ import annotations

import math
from typing import Callable, Sequence

MAX_TERMS = 400  # beyond this many terms the function's source outgrows what it saves
_FILENAME = "<straight-line "  # the written functions' co_filename begins so (`written_out`)


class NotStraight(ValueError):
    """The evaluator has a part this module does not write out."""


def _number(value: float) -> str:
    value = float(value)
    if not math.isfinite(value):
        raise NotStraight("a non-finite constant")
    return repr(value)


def _sum(terms: list[str]) -> str:
    """A loop's `total = 0.0; total += term` in one expression, added left to right as the loop adds."""
    return " + ".join(["0.0", *terms])


def _product(names: Sequence[str], factors: Sequence[tuple[int, int]]) -> str:
    """A monomial's `term = 1.0; term *= x ** p` over its nonzero factors (1.0 * x is x: left out)."""
    parts = [names[column] if power == 1 else f"{names[column]} ** {int(power)}" for column, power in factors]
    return " * ".join(parts) if parts else "1.0"


def _trend_lines(trend: object, names: list[str], mix: Sequence[float] | None) -> list[str]:
    """`trend = ...`: a Linear's or Polynomial's point over `names` (and q = mix . x after them, with `mix`)."""
    lines = []
    if mix is not None:
        lines.append("q = " + _sum([f"{name} * {_number(weight)}" for name, weight in zip(names, mix)]))
        names = [*names, "q"]
    point_terms = getattr(trend, "_point_terms", None)
    if point_terms is not None:  # Polynomial
        terms = [f"({_product(names, factors)}) * {_number(coef)}" for factors, coef in point_terms]
    else:  # Linear
        terms = [f"{name} * {_number(coef)}" for name, coef in zip(names, trend._coef)]
    if len(terms) > MAX_TERMS:
        raise NotStraight("too many trend terms")
    lines.append(f"trend = ({_sum(terms)}) + {_number(trend.intercept)}")
    return lines


def _kernel_lines(gaussian: object, names: list[str]) -> list[str]:
    """`kernel = ...`: a _GaussianPoint's Python loop over the inputs `names`."""
    if gaussian.use_numpy:
        raise NotStraight("a kernel served through numpy")
    if len(gaussian.terms) > MAX_TERMS:
        raise NotStraight("too many kernel terms")
    lines = ["kernel = 0.0"]
    neg_gamma = _number(gaussian.neg_gamma)
    for centre, weight in gaussian.terms:
        differences = []
        for j, (name, c) in enumerate(zip(names, centre)):
            lines.append(f"d{j} = {name} - {_number(c)}")
            differences.append(f"d{j} * d{j}")
        squared = " + ".join(differences) if differences else "0.0"
        lines.append(f"kernel += {_number(weight)} * exp({neg_gamma} * ({squared}))")
    return lines


def _body(evaluator: object, names: list[str]) -> list[str]:
    """The lines computing `evaluator.point` of the inputs `names`, the last a `return`."""
    kind = type(evaluator).__name__
    if kind in ("Linear", "Polynomial"):
        return [*_trend_lines(evaluator, names, None), "return trend"]
    if kind == "RbfNetwork":
        return [*_kernel_lines(evaluator._point, names), f"return kernel + {_number(evaluator.intercept)}"]
    if kind == "Svr":
        columns = evaluator.kernel_columns
        kernel_names = names if columns is None else [names[int(column)] for column in columns]
        trend_part = evaluator._trend_point.__self__
        return [*_kernel_lines(evaluator._point, kernel_names), *_trend_lines(trend_part, names, evaluator._mix),
                f"return trend + kernel + {_number(evaluator.intercept)}"]  # fmt: skip
    raise NotStraight(f"no straight-line form for {kind}")


def row_source(evaluator: object, columns: Sequence[tuple[float, float, float, float, bool]], first: int | None,
               y_mean: float, y_scale: float, beyond: bool) -> str:  # fmt: skip
    """The source of `row(x) -> (thermal error, clamped)`: FrozenModel.predict_one's clamp (the temperature
    column `first` moving the columns marked to move with it, fogd.core.inputs.clamp_rows), scaling and output
    scaling around the evaluator's point, as its loop does them; with `beyond` a clamped row returns (0.0, True)
    at once (the model's outside-range policy serves it)."""
    raw = [f"x{j}" for j in range(len(columns))]
    lines = []
    if first is not None:
        low, high = _number(columns[first][0]), _number(columns[first][1])
        value = raw[first]
        lines.append(f"shift = ({low} if {value} < {low} else {high} if {value} > {high} else {value}) - {value}")
    for name, (low, high, mean, scale, moves) in zip(raw, columns):
        low, high = _number(low), _number(high)
        used = f"{name} + shift" if moves else f"{low} if {name} < {low} else {high} if {name} > {high} else {name}"
        lines.append(f"v{name} = {used}")
        lines.append(f"u{name} = (v{name} - {_number(mean)}) / {_number(scale)}")
    lines.append("clamped = " + " or ".join(f"v{name} != {name}" for name in raw) if raw else "clamped = False")
    if beyond:
        lines.append("if clamped:")
        lines.append("    return 0.0, True")
    body = _body(evaluator, [f"u{name}" for name in raw])
    body[-1] = body[-1].replace("return ", "value = ", 1)
    lines += body
    lines.append(f"return {_number(y_mean)} + {_number(y_scale)} * (value), clamped")
    return "\n".join(["def row(x):", *_unpack(raw, "x"), *_indent(lines)]) + "\n"


def _unpack(names: list[str], sequence: str) -> list[str]:
    return [f"    {', '.join(names)}{',' if len(names) == 1 else ''} = {sequence}"] if names else []


def _indent(lines: list[str]) -> list[str]:
    return ["    " + line for line in lines]


def written_out(function: Callable) -> bool:
    """True for a function this module wrote."""
    return getattr(getattr(function, "__code__", None), "co_filename", "").startswith(_FILENAME)


def _compiled(source: str, name: str, label: str) -> Callable:
    namespace: dict = {"exp": math.exp, "__builtins__": {}}
    exec(compile(source, f"{_FILENAME}{label}>", "exec"), namespace)  # noqa: S102 (numbers only: module docstring)
    return namespace[name]


def row_function(evaluator: object, columns: Sequence[tuple[float, float, float, float, bool]], first: int | None,
                 y_mean: float, y_scale: float, beyond: bool) -> Callable[[Sequence[float]], tuple[float, bool]] | None:  # fmt: skip
    """`row_source`'s function, or None where the evaluator or a constant has no straight-line form."""
    try:
        return _compiled(row_source(evaluator, columns, first, y_mean, y_scale, beyond), "row", type(evaluator).__name__)
    except NotStraight:
        return None
