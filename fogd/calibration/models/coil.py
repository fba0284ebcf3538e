"""The coil-temperature trend: fogd's default grey-box thermal model under the SVR.

The static part of the thermal error (the D_T term of eq. 4) is a curve in the fibre coil's temperature, and
the coil lags the sensor. Over a lag bank, the coil's temperature is close to a weighted mean of the lagged
temperatures, so the trend is

    trend(u) = b . u + sum_{p=2..degree} a_p q^p,    q = v . u,  v >= 0,  sum(v) = 1

on the scaled inputs u: every input linear (the lag bank spans the coil's thermal state, and its rates and
gradients are linear in it) plus the static curve at one estimated coil temperature q. The mix v is found by
variable projection (for a given v the rest is linear least squares with one offset per run) and then held
fixed, so every fold and every swarm particle refits only the linear part.

Fitting powers of every lagged temperature on their own (the "poly" trend) lets differences of cubes of
nearby lags stand in for the coil's rate on calibration ramps, which extrapolates badly to faster ones
(tools/accuracy_table.py --quick, fine sensor, worst held-out run: 1.58x the noise floor on the lumped coil
and 3.15x on the diffusive one with the previous default, "poly" over the lags alone; 1.52x and 1.48x with
this trend over temp and the lags). Frozen, the trend is an ordinary polynomial (`monomial_form`), so the model
file and the daemon's evaluator do not change.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from fogd.core.errorstats import centred_within_runs

MIX_FLOOR = 1e-3  # mix weights below this are dropped (and the rest renormalised): fewer monomials to serve
_MAX_EVALUATIONS = 400


@dataclass(frozen=True)
class CoilTerms:
    """The trend's features of scaled inputs: every input, then q**2 .. q**degree for q = mix . u."""

    mix: np.ndarray  # one weight per input, >= 0, summing to 1 (zero for inputs that are not temperatures)
    degree: int = 3

    def __call__(self, xs: np.ndarray) -> np.ndarray:
        xs = np.asarray(xs, dtype=np.float64)
        q = xs @ self.mix
        return np.column_stack([xs] + [q**power for power in range(2, self.degree + 1)])

    @property
    def columns(self) -> int:
        return self.mix.size + self.degree - 1

    def monomial_form(self, coef: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(powers, coefficients) of the same trend as a polynomial in the inputs: q**p expanded by the
        multinomial theorem over the inputs with a nonzero weight."""
        d = self.mix.size
        active = [i for i in range(d) if self.mix[i] != 0.0]
        rows, values = [list(row) for row in np.eye(d, dtype=np.int64)], list(coef[:d])
        for power, a_p in zip(range(2, self.degree + 1), coef[d:]):
            for combo in itertools.combinations_with_replacement(active, power):
                row = [0] * d
                for i in combo:
                    row[i] += 1
                multinomial = math.factorial(power)
                weight = 1.0
                for i in active:
                    multinomial //= math.factorial(row[i])
                    weight *= self.mix[i] ** row[i]
                rows.append(row)
                values.append(a_p * multinomial * weight)
        return np.array(rows, dtype=np.int64), np.array(values, dtype=np.float64)


def fit_mix(xs: np.ndarray, ys: np.ndarray, groups: np.ndarray | None, candidates: tuple[int, ...],
            degree: int = 3) -> CoilTerms:  # fmt: skip
    """The coil-temperature mix over the `candidates` columns (the temperature inputs) that makes the trend fit
    the scaled rows best, one offset per run (variable projection; weights through a softmax so they stay a
    weighted mean)."""
    from scipy.optimize import (
        least_squares,  # calibration only: the daemon never imports scipy
    )

    xs = np.asarray(xs, dtype=np.float64)
    centred_y = centred_within_runs(ys, groups)
    candidates = tuple(candidates)

    def terms(logits: np.ndarray) -> CoilTerms:
        weights = np.exp(logits - logits.max())
        mix = np.zeros(xs.shape[1])
        mix[list(candidates)] = weights / weights.sum()
        return CoilTerms(mix, degree)

    def residual(logits: np.ndarray) -> np.ndarray:
        features = centred_within_runs(terms(logits)(xs), groups)
        return centred_y - features @ np.linalg.lstsq(features, centred_y, rcond=None)[0]

    if len(candidates) == 1:
        return terms(np.zeros(1))
    solution = least_squares(residual, np.zeros(len(candidates)), max_nfev=_MAX_EVALUATIONS)
    mix = terms(solution.x).mix
    mix[mix < MIX_FLOOR] = 0.0
    return CoilTerms(mix / mix.sum(), degree)
