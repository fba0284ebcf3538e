"""What a model gives for inputs outside its calibrated range (`POLICIES`), stored in the model file.

Inside the range (fogd.core.frozen's clamp moves nothing) every policy is the model itself, bit for bit.
Outside, with c the clamped row (fogd.core.inputs.clamp_rows: a lag bank's temperatures moved together) and
every value in the model's scaled units (x' = (x - mean) / scale, y = y_mean + y_scale * g):

- "clamp": g(c'), the model at the edge (as PX4's temperature compensation does);
- "trend": g(c') + a . (x' - c'), the model at the edge continued along the slope `a` of the linear fit to
  the same blocks and inputs (IEEE 952's model): continuous at the edge, a straight line beyond it;
- "linear": a . x' + b, the linear fit itself (the domain guard's fallback), evaluated unclamped;
- "edge": g(c') + s |x' - c'|, the model at the edge continued along its own slope s towards the sample,
  the secant from the point `EDGE_STEP` scaled units back inside (clamped again) to the edge.

The sample is flagged CLAMPED whatever the policy (fogd.core.flags). docs/results/range.md measures them
(tools/range_policy.py) on held-out runs that leave the range of their calibration runs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

POLICIES = ("clamp", "trend", "linear", "edge")
LINEAR_POLICIES = ("trend", "linear")  # the ones that need the linear fit stored beside the model
DEFAULT_POLICY = "trend"  # what fogd-train writes; measured: docs/results/range.md (tools/range_policy.py)
EDGE_STEP = 0.5  # "edge": the secant's length back inside, scaled units (half a calibration std)


def point_dot(values: Sequence[float], weights: Sequence[float]) -> float:
    """values . weights for Python floats, summed in column order (as the array paths sum a row)."""
    total = 0.0
    for value, weight in zip(values, weights):
        total += value * weight
    return total


@dataclass(frozen=True)
class OutsideRange:
    """A policy and, for "trend" and "linear", the linear fit (coefficients and intercept, scaled units)."""

    policy: str = "clamp"  # a model file without `outside_range` (every file from before it): the clamp
    coef: np.ndarray | None = None
    intercept: float = 0.0

    def __post_init__(self) -> None:
        if self.policy not in POLICIES:
            raise ValueError(f"unknown policy {self.policy!r}: choose one of {', '.join(POLICIES)}")
        if self.policy in LINEAR_POLICIES and self.coef is None:
            raise ValueError(f"policy {self.policy!r} needs the linear fit's coefficients")
        coef = None if self.coef is None else np.asarray(self.coef, dtype=np.float64)
        object.__setattr__(self, "coef", coef)
        object.__setattr__(self, "_coef", None if coef is None else tuple(coef.tolist()))

    def rows(self, xs: np.ndarray, cs: np.ndarray, edge_g: np.ndarray,
             inside_g: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]) -> np.ndarray:  # fmt: skip
        """g for rows outside: scaled raw rows xs, their clamped rows cs and the model there (edge_g);
        `inside_g(ys)`: (g at the scaled rows ys clamped again, those rows) for "edge"."""
        if self.policy == "clamp":
            return edge_g
        if self.policy in LINEAR_POLICIES:
            step = [xs - cs, xs][self.policy == "linear"]
            # a row at a time in column order, as `one` sums (bit for bit whatever the batch)
            total = np.zeros(len(xs))
            for column, weight in enumerate(self._coef):
                total += step[:, column] * weight
            return edge_g + total if self.policy == "trend" else total + self.intercept
        away = xs - cs
        length = np.sqrt(np.einsum("ij,ij->i", away, away))
        with np.errstate(invalid="ignore", divide="ignore"):
            back_g, back = inside_g(cs - away * (EDGE_STEP / length)[:, None])
            moved = back - cs
            step = np.sqrt(np.einsum("ij,ij->i", moved, moved))
            slope = np.where(step > 0, (edge_g - back_g) / step, 0.0)
        return edge_g + slope * length

    def one(self, xs: Sequence[float], cs: Sequence[float], edge_g: float,
            inside_g: Callable[[list[float]], tuple[float, list[float]]]) -> float:  # fmt: skip
        """`rows` of one row of Python floats."""
        if self.policy == "clamp":
            return edge_g
        if self.policy == "trend":
            return edge_g + point_dot([x - c for x, c in zip(xs, cs)], self._coef)
        if self.policy == "linear":
            return point_dot(xs, self._coef) + self.intercept
        away = [x - c for x, c in zip(xs, cs)]
        length = math.sqrt(point_dot(away, away))
        if not length > 0:  # NaN
            return math.nan
        back_g, back = inside_g([c - a * (EDGE_STEP / length) for c, a in zip(cs, away)])
        moved = [b - c for b, c in zip(back, cs)]
        step = math.sqrt(point_dot(moved, moved))
        slope = (edge_g - back_g) / step if step > 0 else 0.0
        return edge_g + slope * length

    def to_dict(self) -> dict:
        """The model file's `outside_range`."""
        if self.coef is None:
            return {"policy": self.policy}
        return {"policy": self.policy, "coef": self.coef.tolist(), "intercept": float(self.intercept)}
