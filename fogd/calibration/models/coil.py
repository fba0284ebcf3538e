"""The coil-temperature trend: fogd's default grey-box thermal model under the SVR.

The static part of the thermal error (the D_T term of eq. 4) is a curve in the fibre coil's temperature, and
the coil lags the sensor. Over a lag bank, the coil's temperature is close to a weighted mean of the lagged
temperatures, so the trend is

    trend(u) = b . u + sum_{p=2..degree} a_p q^p,    q = v . u,  sum(v) = 1

on the scaled inputs u: every input linear (the lag bank spans the coil's thermal state, and its rates and
gradients are linear in it) plus the static curve at one estimated coil temperature q. The mix v is found by
variable projection (for a given v the rest is linear least squares with one offset per run) and then held
fixed, so every fold and every swarm particle refits only the linear part.

The mix is first a weighted mean (v >= 0): a temperature that follows the sensor through one lag. A layer deep
in the coil follows through a chain of lags and starts to move only after a delay; over a bank of first-order
lags that response is a mix with negative weights on the fast ones (partial fractions: a lag of tau_a after
one of tau_b is (tau_a lag_a - tau_b lag_b) / (tau_a - tau_b)). The signed mix (weights summing to 1, each
free one within +-SIGNED_MIX_BOUND so that no large cancelling pair reads noise) replaces the mean only where it
leaves at least SIGNED_MIX_GAIN less residual on the calibration blocks: a static curve taken deep in the coil.
Where the mean describes the blocks as well, the extra freedom only fits their noise and a ramp four times
faster than calibration pays for it (tools/accuracy_table.py --quick --schemes default, fine sensor, seeds 2
and 3: the z gyro's worst held-out run 1.20-1.64x the noise floor with the mean, 1.51-1.97x with
`--coil-mix signed`). With the choice, `--imu` seed 1 lumped: accel_z_g's worst run 3.85 -> 1.82x, accel_y_g's
2.47 -> 1.33x. The bound is wide (4) because a sensor far ahead of the coil needs it: on the baseplate
(`tools/accuracy_table.py --physics sensor_on=baseplate`, seed 1, worst run lumped / diffusive) the mix hit +-1
and +-2 and left 1.89 / 2.37x (fine sensor) and 2.47 / 3.16x (whole degrees); within +-4, 1.51 / 1.61x and 2.08 /
2.37x. On the default physics nothing moved; `--imu` seed 1 lumped accel_z_g lost 1.82 -> 1.90x.

The lag coefficients carry the coil's dynamics, and calibration ramps (20-24 C/h) pin down only part of them:
the gyro's noise in the calibration blocks moves the rest, which a ramp four times faster reads. A ridge
towards zero cannot help (the coefficients of a lag bank are large and of alternating sign by nature). The
rate prior works in another basis: a lag of tau s is the temperature minus tau times the same lag of the
temperature's rate, so the bank's linear part is the temperature plus a coefficient per lagged rate, and a
coil's response spreads over neighbouring time constants. The prior penalises the second differences of those
rate coefficients along the bank (a straight line along it costs nothing), at the strength that maximises the
calibration blocks' marginal likelihood (the noise variance profiled out), chosen once like the mix. On
tools/accuracy_table.py --quick --sensor fine --schemes default, seeds 1-5, `--rate-prior none` against the
default: the diffusive coil's worst held-out run 1.36 / 1.51 / 1.64 / 1.66 / 1.50 -> 1.37 / 1.42 / 1.38 / 1.54 /
1.46x the noise floor; the lumped coil's, whose fitted lags alternate at the fast end to undo the sensor's own
lag, 1.12 / 1.20 / 1.60 / 1.29 / 1.38 -> 1.14 / 1.25 / 1.56 / 1.22 / 1.47x; whole degrees within 2 % either way.

Fitting powers of every lagged temperature on their own (the "poly" trend) lets differences of cubes of
nearby lags stand in for the coil's rate on calibration ramps, which extrapolates badly to faster ones
(tools/accuracy_table.py --quick, fine sensor, worst held-out run: 1.58x the noise floor on the lumped coil
and 3.15x on the diffusive one with the previous default, "poly" over the lags alone; 1.52x and 1.48x with
this trend over temp and the lags). Frozen, the trend is stored as it is fitted (`mix_form`: the mix, and
monomials over the inputs and q), not expanded into the 165 monomials of the inputs a cubic in q makes over a
nine-input lag bank: per sample the daemon forms q and eleven terms (tools/bench_point.py 1b).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from fogd.core.errorstats import centred_within_runs

MIX_FLOOR = 1e-3  # mix weights smaller than this are dropped (and the rest renormalised): fewer monomials to serve
SIGNED_MIX_BOUND = 4.0  # the signed mix's free weights stay within +-this (its largest weight is 1 minus their sum)
SIGNED_MIX_GAIN = 0.03  # the signed mix must leave this share less residual RMS than the mean to replace it
MIXES = ("auto", "mean", "signed")  # fit_mix's choice: the gate above, the weighted mean, or the signed mix
# The rate prior's strengths tried, relative to the features' scale. Where the best is the top (the 200 Hz quick
# start's final fit: tools/bench_train.py), the evidence is flat beyond it, not still rising: scored up to 1e6 it
# gained 0.0007 in -2 log evidence and the held-out drift stayed 1.267x the floor. The prior smooths second
# differences of the lags' rate coefficients, so a straight line along the bank costs nothing at any strength:
# the large coefficients such a fit keeps lie there, out of the prior's reach.
PRIOR_STRENGTHS = np.geomspace(1e-9, 1e-1, 33)
PRIORS = ("smooth", "none")  # the coil trend's rate prior (fit_rate_prior), or plain least squares
_MAX_EVALUATIONS = 400


@dataclass(frozen=True)
class CoilTerms:
    """The trend's features of scaled inputs: every input, then q**2 .. q**degree for q = mix . u."""

    mix: np.ndarray  # one weight per input, >= 0, summing to 1 (zero for inputs that are not temperatures)
    degree: int = 3
    # rows A of the fit's penalty |A coef|^2 (fit_rate_prior), or None: plain least squares
    penalty_rows: np.ndarray | None = field(default=None, compare=False, repr=False)
    prior_strength: float | None = None  # the rate prior's strength, relative to the features' scale (PRIOR_STRENGTHS)

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
            degree: int = 3, mix: str = "auto") -> CoilTerms:  # fmt: skip
    """The coil-temperature mix over the `candidates` columns (the temperature inputs) that makes the trend fit
    the scaled rows best, one offset per run: a weighted mean, or a signed mix where it fits SIGNED_MIX_GAIN
    better (`mix` "auto", the module's docstring); `mix` "mean" or "signed" forces one."""
    if mix not in MIXES:
        raise ValueError(f"unknown coil mix {mix!r}: choose one of {', '.join(MIXES)}")
    xs = np.asarray(xs, dtype=np.float64)
    centred_y = centred_within_runs(ys, groups)
    candidates = tuple(candidates)
    mean = _fit_mean_mix(xs, centred_y, groups, candidates, degree)
    if len(candidates) == 1 or mix == "mean":
        return mean
    signed = _fit_signed_mix(xs, centred_y, groups, candidates, degree, mean)
    if mix == "signed":
        return signed
    left_signed, left_mean = (np.linalg.norm(_residual(terms, xs, centred_y, groups)) for terms in (signed, mean))
    return signed if left_signed < (1.0 - SIGNED_MIX_GAIN) * left_mean else mean  # same rows: norms compare as RMS


def _residual(terms: CoilTerms, xs: np.ndarray, centred_y: np.ndarray, groups: np.ndarray | None) -> np.ndarray:
    """What the trend of these terms leaves of the run-centred targets (variable projection's residual)."""
    features = centred_within_runs(terms(xs), groups)
    return centred_y - features @ np.linalg.lstsq(features, centred_y, rcond=None)[0]


def _with_floor(mix: np.ndarray, degree: int) -> CoilTerms:
    mix = mix.copy()
    mix[np.abs(mix) < MIX_FLOOR] = 0.0
    return CoilTerms(mix / mix.sum(), degree)


def _fit_mean_mix(xs: np.ndarray, centred_y: np.ndarray, groups: np.ndarray | None, candidates: tuple[int, ...],
                  degree: int) -> CoilTerms:  # fmt: skip
    """The weighted mean: weights through a softmax, so they stay non-negative and sum to 1."""
    from scipy.optimize import (
        least_squares,  # calibration only: the daemon never imports scipy
    )

    def terms(logits: np.ndarray) -> CoilTerms:
        weights = np.exp(logits - logits.max())
        mix = np.zeros(xs.shape[1])
        mix[list(candidates)] = weights / weights.sum()
        return CoilTerms(mix, degree)

    if len(candidates) == 1:
        return terms(np.zeros(1))
    solution = least_squares(lambda logits: _residual(terms(logits), xs, centred_y, groups), np.zeros(len(candidates)),
                             max_nfev=_MAX_EVALUATIONS)  # fmt: skip
    return _with_floor(terms(solution.x).mix, degree)


def _fit_signed_mix(xs: np.ndarray, centred_y: np.ndarray, groups: np.ndarray | None, candidates: tuple[int, ...],
                    degree: int, start: CoilTerms) -> CoilTerms:  # fmt: skip
    """The signed mix, from the mean's: the weight that is largest there is 1 minus the others, and the others
    stay within +-SIGNED_MIX_BOUND."""
    from scipy.optimize import least_squares

    columns = list(candidates)
    first = start.mix[columns]
    largest = int(np.argmax(first))
    free = [k for k in range(len(columns)) if k != largest]

    def terms(weights: np.ndarray) -> CoilTerms:
        mix = np.zeros(xs.shape[1])
        mix[[columns[k] for k in free]] = weights
        mix[columns[largest]] = 1.0 - weights.sum()
        return CoilTerms(mix, degree)

    solution = least_squares(lambda weights: _residual(terms(weights), xs, centred_y, groups),
                             np.clip(first[free], -SIGNED_MIX_BOUND, SIGNED_MIX_BOUND),
                             bounds=(-SIGNED_MIX_BOUND, SIGNED_MIX_BOUND), max_nfev=_MAX_EVALUATIONS)  # fmt: skip
    return _with_floor(terms(solution.x).mix, degree)


def rate_prior_rows(terms: CoilTerms, lag_rates: np.ndarray) -> np.ndarray:
    """The rate prior's rows over the trend's features, before its strength: second differences, along the bank,
    of the lags' coefficients in the lagged-rate basis.

    A lag of tau s is the temperature minus tau times its own lag of the temperature's rate (d lag/dt =
    (T - lag) / tau), so the trend's coefficient b_i of the scaled lag i is, on the lagged rate, c_i = -b_i
    tau_i / scale_i: `lag_rates` holds tau_i / scale_i for each lag column (0 for the other inputs), in the
    bank's order. Rows for fewer than three lags: none (nothing to smooth)."""
    columns = np.flatnonzero(lag_rates)
    if columns.size < 3:
        return np.zeros((0, terms.columns))
    to_rates = np.zeros((columns.size, terms.columns))
    to_rates[np.arange(columns.size), columns] = -lag_rates[columns]
    return np.diff(np.eye(columns.size), 2, axis=0) @ to_rates


def fit_rate_prior(terms: CoilTerms, xs: np.ndarray, ys: np.ndarray, groups: np.ndarray | None,
                   lag_rates: np.ndarray) -> CoilTerms:  # fmt: skip
    """`terms` with the rate prior's penalty at the strength that maximises the calibration blocks' marginal
    likelihood (module docstring); unchanged where the bank has fewer than three lags, or where the blocks
    cannot tell one strength from another (fewer rows than terms, a degenerate fit at every strength)."""
    rows = rate_prior_rows(terms, np.asarray(lag_rates, dtype=np.float64))
    if rows.shape[0] == 0:
        return terms
    features = centred_within_runs(terms(xs), groups)
    moving = np.linalg.norm(features, axis=0) > 0  # an input flat in these rows (a play that never slid) drops out
    features, fit_rows = features[:, moving], rows[:, moving]
    centred_y = centred_within_runs(np.asarray(ys, dtype=np.float64), groups)
    gram, prior = features.T @ features, fit_rows.T @ fit_rows
    rank = np.linalg.matrix_rank(fit_rows)
    dof = centred_y.size - (1 if groups is None else np.unique(groups).size) - (features.shape[1] - rank)
    if rank == 0 or dof <= 0:
        return terms
    unit = np.trace(gram) / np.trace(prior)
    best_score, best_relative = np.inf, None
    for relative in PRIOR_STRENGTHS:
        strength = unit * relative
        sign, log_det = np.linalg.slogdet(gram + strength * prior)
        coef = np.linalg.lstsq(np.vstack((features, np.sqrt(strength) * fit_rows)),
                               np.concatenate((centred_y, np.zeros(rows.shape[0]))), rcond=None)[0]  # fmt: skip
        penalised_rss = float(np.sum((centred_y - features @ coef) ** 2) + strength * coef @ prior @ coef)
        if sign <= 0 or not np.isfinite(log_det) or not penalised_rss > 0:  # singular, or a perfect fit
            continue
        # -2 log evidence with the noise variance profiled out, up to a constant (a Gaussian prior on the rows'
        # second differences, flat on what they do not see): Wahba / REML's criterion for a penalised fit
        score = dof * np.log(penalised_rss) + log_det - rank * np.log(strength)
        if score < best_score:
            best_score, best_relative = score, float(relative)
    if best_relative is None:
        return terms
    return replace(terms, penalty_rows=np.sqrt(unit * best_relative) * rows, prior_strength=best_relative)
