"""A fast look at what the coil trend alone leaves on the accuracy table's held-out runs, by temperature input.

No swarm and no SVR: this simulates `tools/accuracy_table.py`'s calibration and held-out runs (the same
seeds, gyro and sensor), fits only the default's least-squares coil trend (fogd.calibration.models.coil:
the inputs linear plus the static curve at a fitted coil temperature, one offset per run) to the calibration
runs' 100 s block means, evaluates it sample by sample on each held-out run (inputs clamped as the daemon
clamps them) and prints the accuracy table's figure: the std of 100 s block means after 600 s over the noise
floor. What changes between cases is the temperature the inputs are computed from, at fit time and at serve
time, each one of

    true      the sensor element's temperature (no noise, no quantisation, no sample-and-hold)
    read      the readings, as the daemon sees them
    fb:W      offline, zero-phase: a forward-backward first-order lag of W/2 s over the readings (fit only)
    spline    offline: a smoothing spline through the readings, residual budget the quantisation's LSB^2/12
    held      the true temperature sampled and held at the sensor's rate (the readings without noise or steps)
    quant     the true temperature quantised to the sensor's resolution (no noise, no sample-and-hold)
    noisy     the true temperature with the sensor's noise, sampled and held (no quantisation)
    ma:W      causal: the mean of the last W s of readings (tma:W: of the true temperature)
    inv:W     causal: ma:W through the inverse of the noise-dithered staircase (the expected reading as a
              function of the temperature, Gaussian noise then the quantiser); exploratory: the sensor's
              noise is taken as known from the simulation (inv:W:SIGMA assumes SIGMA C instead)
and `+pre:TAU` after any of them puts a causal first-order lag of TAU s in front of the bank (fitted on the
same lag of the fit temperature, so its delay is compensated). `--ridge` adds a ridge on the trend's scaled
coefficients (`loro`: its strength chosen by leave-one-calibration-run-out drift about each run's mean);
`--play WIDTH[@TAU]` adds a play operator (fogd.core.play) of a TAU s lag of the temperature as an input,
`--rate-prior smooth` adds fogd-train's default prior on the lags' rate coefficients (plain least squares
without it), `--target truth` fits the calibration runs' true thermal error instead of the measured rate (no gyro noise),
`--calibration-copies N` records each calibration programme N times (the first as the accuracy table does)
and `--hysteresis-dph 0` simulates the gyro without its play hysteresis. Besides each case's figures: the
trend's drift RMSE on the calibration blocks (fit) and left out run by run (loro).

    python tools/trend_diagnostic.py --case read/read --case true/true --case true/read
    python tools/trend_diagnostic.py --inputs temp,lags@10..3000/7 --case true/true --case read/read --play '' --play 2
    python tools/trend_diagnostic.py --seed 3 --thermal diffusive --case held/held --case quant/quant --case noisy/noisy
    python tools/trend_diagnostic.py --seed 1 --seed 2 --seed 3 --case read/read --case inv:10/inv:10
    python tools/trend_diagnostic.py --seed 3 --seed 4 --case true/true --rate-prior smooth --hysteresis-dph 0
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from fogd.calibration.models.coil import PRIORS, fit_mix, fit_rate_prior
from fogd.calibration.models.least_squares import RunOffsetLeastSquares
from fogd.core.columns import BLOCK_S
from fogd.core.errorstats import block_means, centred_within_runs, detrended_stats
from fogd.core.inputs import (
    DEFAULT_INPUTS_TEXT,
    clamp_rows,
    inputs_batch,
    lag_taus_s,
    parse_inputs,
    shifted_columns,
    temperature_columns,
)
from fogd.core.lag import lag_batch
from fogd.core.play import play_batch
from fogd.simulation.profiles import builtin
from fogd.simulation.simulator import Simulation, params_for

CALIBRATION = ("paper-train", "cooling", "cycle")  # as tools/accuracy_table.py
HELD_OUT = ("paper-test", "cool-40-to-0", "fast-ramp", "soak-after-ramp", "fast-cycle")
SETTLE_S = 600.0
RIDGES = (0.0, 1e-4, 1e-3, 1e-2, 1e-1, 1.0)


class SimRun:
    """One simulated run: its readings, the sensor element's true temperature, the rate and its truth."""

    def __init__(self, profile: str, seed: int, rate_hz: float, params) -> None:
        sim = Simulation(builtin(profile), rate_hz, seed, params)
        columns = sim.columns()
        self.name = profile
        self.rate_hz = rate_hz
        self.t_s = columns["t_s"]
        self.read_c = columns["temp_c"]
        self.rate_dph = columns["rate_dph"]
        self.truth_dph = columns["true_error_dph"]
        self.true_c = np.interp(self.t_s, sim.grid_t_s, sim.states[sim.network.sensor])
        self.resolution_c = params.sensor_resolution_c
        self.sensor_hz = params.sensor_rate_hz
        self.noise_c = params.sensor_noise_c
        self.seed = seed


def temperature(run: SimRun, spec: str) -> np.ndarray:
    """The temperature `spec` (module docstring) of a run."""
    base, _, pre = spec.partition("+pre:")
    name, _, value = base.partition(":")
    if name == "true":
        out = run.true_c
    elif name == "read":
        out = run.read_c
    elif name in ("held", "quant", "noisy"):  # one of the readings' errors alone: sample-and-hold, quantisation, noise
        index = np.floor(run.t_s * run.sensor_hz + 1e-9).astype(np.int64)
        out = np.interp(index / run.sensor_hz, run.t_s, run.true_c) if name == "held" else run.true_c
        if name == "quant":
            out = np.round(out / run.resolution_c) * run.resolution_c
        if name == "noisy":
            out = out + np.random.default_rng(run.seed).normal(0.0, run.noise_c, index[-1] + 1)[index]
    elif name in ("ma", "inv", "tma"):  # causal: the mean of the last W s of readings (tma: of the true temperature);
        # inv: then through the dithered staircase's inverse
        window, _, noise = value.partition(":")
        out = moving_mean(run.true_c if name == "tma" else run.read_c, round(float(window) * run.rate_hz))
        if name == "inv":
            out = undither(out, run.resolution_c, float(noise) if noise else run.noise_c)
    elif name == "fb":
        from scipy.signal import filtfilt

        tau_s = float(value) / 2
        gain = -math.expm1(-1.0 / (tau_s * run.rate_hz))
        out = filtfilt([gain], [1.0, gain - 1.0], run.read_c, method="gust")
    elif name == "spline":
        out = spline_c(run)
    else:
        raise SystemExit(f"unknown temperature {spec!r}")
    return lag_batch(out, float(pre), run.rate_hz) if pre else out


def moving_mean(values: np.ndarray, n: int) -> np.ndarray:
    sums = np.cumsum(np.r_[0.0, values])
    rows = np.arange(1, values.size + 1)
    start = np.maximum(rows - n, 0)
    return (sums[rows] - sums[start]) / (rows - start)


def undither(mean_c: np.ndarray, resolution_c: float, noise_c: float) -> np.ndarray:
    """The temperature whose expected reading (Gaussian noise, then the quantiser) is `mean_c`: the inverse of
    the dithered staircase, periodic in the resolution (an exploratory estimate: the noise is taken as known)."""
    from scipy.stats import norm

    x = np.linspace(0.0, 1.0, 2001)  # in steps, within one period
    s = max(noise_c / resolution_c, 1e-3)
    k = np.arange(-3, 5)[:, None]
    expected = (k * (norm.cdf((k + 0.5 - x) / s) - norm.cdf((k - 0.5 - x) / s))).sum(axis=0)
    base = np.floor(mean_c / resolution_c)
    frac = mean_c / resolution_c - base
    # expected(x) runs from expected(0) to expected(1) = expected(0) + 1 over a period: shift into that range
    lift = frac < expected[0]
    frac, base = np.where(lift, frac + 1.0, frac), np.where(lift, base - 1.0, base)
    return (base + np.interp(frac, expected, x)) * resolution_c


def spline_c(run: SimRun) -> np.ndarray:
    from scipy.interpolate import UnivariateSpline

    change = np.flatnonzero(np.diff(run.read_c) != 0) + 1
    # the sensor's own samples are unknown to the daemon: take every 10th row (about the sensor's rate or less)
    rows = np.arange(0, run.read_c.size, max(1, int(run.rate_hz // 4)))
    rows = np.union1d(rows, change)
    budget = rows.size * run.resolution_c**2 / 12
    spline = UnivariateSpline(run.t_s[rows], run.read_c[rows], s=budget)
    return spline(run.t_s)


def with_play(x: np.ndarray, temp_c: np.ndarray, play: str | None, rate_hz: float) -> np.ndarray:
    """The inputs and, with `play` 'WIDTH@TAU', a play operator of width WIDTH C on a TAU s lag of the temperature."""
    if not play:
        return x
    width, _, tau = play.partition("@")
    source = lag_batch(temp_c, float(tau), rate_hz) if tau else temp_c
    return np.column_stack([x, play_batch(source, float(width))])


def blocks(run: SimRun, x: np.ndarray, block_n: int, target: str = "rate") -> tuple[np.ndarray, np.ndarray]:
    use = np.ones(run.rate_dph.size, dtype=bool)
    y = run.rate_dph if target == "rate" else run.truth_dph
    return block_means(x, use, block_n)[0], block_means(y, use, block_n)[0]


class Trend:
    """The coil trend (fit_mix then run-offset least squares, optionally ridged) on scaled block rows."""

    def __init__(self, x: np.ndarray, y: np.ndarray, groups: np.ndarray, specs, ridge: float | str = 0.0,
                 rate_prior: str = "none") -> None:  # fmt: skip
        self.x_mean, std = x.mean(axis=0), x.std(axis=0)
        self.x_scale = np.where(std > 0, std, 1.0)
        self.y_scale = float(y.std()) or 1.0
        xs, ys = (x - self.x_mean) / self.x_scale, (y - y.mean()) / self.y_scale
        self.terms = fit_mix(xs, ys, groups, temperature_columns(specs), 3)
        if rate_prior == "smooth":  # as fogd-train's (fogd.calibration.models.fit.trend_terms)
            taus_s = np.zeros(xs.shape[1])  # an added play (--play) is not a lag
            taus_s[: len(specs)] = lag_taus_s(specs)
            self.terms = fit_rate_prior(self.terms, xs, ys, groups, taus_s / self.x_scale)
        if ridge == "loro":
            scores = {value: _loro(xs, ys, groups, self.terms, value) for value in RIDGES}
            ridge = min(scores, key=scores.get)
            self.scores = scores
        self.ridge = float(ridge)
        self.coef, self.intercept = _ridge_fit(self.terms, xs, ys, groups, self.ridge)
        residual = self.terms(xs) @ self.coef + self.intercept - ys
        self.fit_rmse_dph = float(np.sqrt(np.mean(centred_within_runs(residual, groups) ** 2))) * self.y_scale
        self.loro_dph = _loro(xs, ys, groups, self.terms, self.ridge) * self.y_scale

    def predict(self, x: np.ndarray) -> np.ndarray:
        xs = (x - self.x_mean) / self.x_scale
        return (self.terms(xs) @ self.coef + self.intercept) * self.y_scale


def _ridge_fit(terms, xs: np.ndarray, ys: np.ndarray, groups: np.ndarray, ridge: float) -> tuple[np.ndarray, float]:
    if ridge == 0:  # with the terms' rate prior, if any
        model = RunOffsetLeastSquares(terms).fit(xs, ys, groups)
        return model.coef_, model.intercept_
    features = terms(xs)
    cx, cy = centred_within_runs(features, groups), centred_within_runs(ys, groups)
    n = len(cy)
    coef = np.linalg.solve(cx.T @ cx + ridge * n * np.eye(cx.shape[1]), cx.T @ cy)
    return coef, float(np.mean(ys) - features.mean(axis=0) @ coef)


def _loro(xs, ys, groups, terms, ridge: float) -> float:
    residual = []
    for run in np.unique(groups):
        train = groups != run
        coef, intercept = _ridge_fit(terms, xs[train], ys[train], groups[train], ridge)
        r = terms(xs[~train]) @ coef + intercept - ys[~train]
        residual.append(r - r.mean())
    return float(np.sqrt(np.mean(np.concatenate(residual) ** 2)))


def score(run: SimRun, comp_dph: np.ndarray) -> float:
    """The accuracy table's figure: std of 100 s block means after the settling over the noise floor."""
    start, block_n = round(SETTLE_S * run.rate_hz), round(BLOCK_S * run.rate_hz)
    use = np.ones(run.rate_dph.size - start, dtype=bool)
    after = detrended_stats(block_means(comp_dph[start:], use, block_n)[0]).rmse_dph
    floor = detrended_stats(block_means((run.rate_dph - run.truth_dph)[start:], use, block_n)[0]).rmse_dph
    return after / floor


def case_scores(calibration: list[SimRun], held_out: list[SimRun], fit_spec: str, serve_spec: str, specs,
                ridge: float | str, play: str | None = None, target: str = "rate",
                rate_prior: str = "none") -> tuple[list[float], Trend]:  # fmt: skip
    block_n = round(BLOCK_S * calibration[0].rate_hz)
    xs, ys, groups, samples = [], [], [], []
    for index, run in enumerate(calibration):
        temp_c = temperature(run, fit_spec)
        x = with_play(inputs_batch(temp_c, specs, run.rate_hz), temp_c, play, run.rate_hz)
        xb, yb = blocks(run, x, block_n, target)
        xs.append(xb)
        ys.append(yb)
        groups.append(np.full(len(yb), index))
        samples.append(x)
    trend = Trend(np.concatenate(xs), np.concatenate(ys), np.concatenate(groups), specs, ridge, rate_prior)
    low = np.min([x.min(axis=0) for x in samples], axis=0)
    high = np.max([x.max(axis=0) for x in samples], axis=0)
    out = []
    for run in held_out:
        temp_c = temperature(run, serve_spec)
        x = with_play(inputs_batch(temp_c, specs, run.rate_hz), temp_c, play, run.rate_hz)
        x = clamp_rows(x, low, high, shifted_columns(specs))
        out.append(score(run, run.rate_dph - trend.predict(x)))
    return out, trend


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, action="append", help="seeds (repeatable; default 1 and 2)")
    parser.add_argument("--thermal", choices=("lumped", "diffusive"), action="append")
    parser.add_argument("--rate-hz", type=float, default=10.0)
    parser.add_argument("--resolution-c", type=float, default=0.0625)
    parser.add_argument("--sensor-hz", type=float, default=4.0)
    parser.add_argument("--inputs", default=DEFAULT_INPUTS_TEXT)
    parser.add_argument("--case", action="append", help="FIT/SERVE temperatures, e.g. read/read (repeatable)")
    parser.add_argument("--hysteresis-dph", type=float, default=None, help="the gyro's play (default: the preset's)")
    parser.add_argument("--play", action="append", help="WIDTH@TAU: add a play operator input (repeatable: one case each)")
    parser.add_argument("--target", choices=("rate", "truth"), default="rate",
                        help="fit the calibration runs' measured rate, or their true thermal error (no gyro noise)")
    parser.add_argument("--ridge", default="0", help="ridge strength on the scaled trend, or 'loro'")
    parser.add_argument("--rate-prior", choices=PRIORS, default="none",
                        help="the coil trend's prior on its lags' rate coefficients, as fogd-train's --rate-prior "
                             "(default none here: plain least squares, as before the prior)")
    parser.add_argument("--calibration-copies", type=int, default=1, metavar="N",
                        help="record each calibration programme N times (other noise seeds): what more calibration buys")
    args = parser.parse_args()
    specs = parse_inputs(args.inputs)
    cases = args.case or ["read/read", "true/true", "true/read"]
    ridge = args.ridge if args.ridge == "loro" else float(args.ridge)
    print(f"coil trend alone on {args.inputs}, ridge {args.ridge}, rate prior {args.rate_prior}: held-out drift / noise floor "
          f"({', '.join(HELD_OUT)}), worst")  # fmt: skip
    for seed in args.seed or [1, 2]:
        for thermal in args.thermal or ["lumped", "diffusive"]:
            extra = {} if args.hysteresis_dph is None else {"hysteresis_dph": args.hysteresis_dph}
            params = params_for("navigation", thermal, sensor_resolution_c=args.resolution_c,
                                sensor_rate_hz=args.sensor_hz, **extra)  # fmt: skip
            calibration = [SimRun(name, seed + i + 1000 * copy, args.rate_hz, params)  # copy 0: the accuracy table's
                           for copy in range(args.calibration_copies) for i, name in enumerate(CALIBRATION)]
            held_out = [SimRun(name, seed + 100 + i, args.rate_hz, params) for i, name in enumerate(HELD_OUT)]
            for case, play in ((case, play) for case in cases for play in args.play or [None]):
                fit_spec, _, serve_spec = case.partition("/")
                ratios, trend = case_scores(calibration, held_out, fit_spec, serve_spec, specs, ridge, play, args.target,
                                            args.rate_prior)  # fmt: skip
                case = case if play is None else f"{case} play {play}"
                chosen = f" ridge {trend.ridge:g}" if ridge == "loro" else ""
                print(f"seed {seed} {thermal:9s} {case:28s} " + " ".join(f"{r:5.2f}" for r in ratios)
                      + f"  worst {max(ratios):.2f}{chosen}  fit {trend.fit_rmse_dph * 1e3:.3f} loro {trend.loro_dph * 1e3:.3f} mdeg/h",
                      flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
