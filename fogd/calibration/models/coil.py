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
this trend over temp and the lags). Frozen, the trend is stored as it is fitted (`mix_form`: the mix, and
monomials over the inputs and q), not expanded into the 165 monomials of the inputs a cubic in q makes over a
nine-input lag bank: per sample the daemon forms q and eleven terms (tools/bench_point.py 1b).
"""

from __future__ import annotations

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

    def mix_form(self) -> np.ndarray:
        """The trend's monomials over the inputs and one more column, q (what the model file's `trend_powers`
        read beside `trend_mix`): every input to the power 1, then q ** 2 .. q ** degree, in the order of the
        features, so the fitted coefficients serve as they are."""
        d = self.mix.size
        linear = np.eye(d, d + 1, dtype=np.int64)
        powers = np.zeros((self.degree - 1, d + 1), dtype=np.int64)
        powers[:, d] = np.arange(2, self.degree + 1)
        return np.vstack((linear, powers))


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
