"""A fast look at what the coil trend alone leaves on the accuracy table's held-out runs, by temperature input.

No swarm and no SVR: this simulates `tools/accuracy_table.py`'s calibration and held-out runs (the same
seeds, gyro and sensor), fits only the default's least-squares coil trend (fogd.calibration.models.coil:
the inputs linear plus the static curve at a fitted coil temperature, one offset per run) to the calibration
runs' 200 s block means (fogd-train's FIT_BLOCK_S), evaluates it sample by sample on each held-out run (inputs clamped as the daemon
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
    und:SIGMA fogd.core.undither's estimate assuming SIGMA C of noise, as the daemon serves it (und:SIGMA:TAU
              averages the readings over a TAU s lag instead of DEFAULT_TAU_S); `und:auto` takes
              the noise as fogd-train does (training.with_undither: the readings or the candidate whose coil
              trend leaves the least residual on the calibration blocks, the play's lag then chosen on it)
`+deq` after any of them runs it through fogd.core.dequantise's causal estimate at the sensor's resolution (the
parabola through the last three crossings, as the daemon serves a whole-degree sensor), `+deqfb` through the
mean of that estimate run forwards and backwards (what fogd-train fits it on), and `+pre:TAU` puts a causal
first-order lag of TAU s in front of the bank (fitted on the same lag of the fit temperature, so its delay is
compensated). A case is FIT/SERVE, or FIT/SERVE/truth to fit the calibration runs' true thermal error. `--ridge` adds a ridge on the trend's scaled
coefficients (`loro`: its strength chosen by leave-one-calibration-run-out drift about each run's mean);
`--play WIDTH[@TAU]` adds a play operator (fogd.core.play) of a TAU s lag of the temperature as an input,
`--rate-prior smooth` adds fogd-train's default prior on the lags' rate coefficients (plain least squares
without it), `--target truth` fits the calibration runs' true thermal error instead of the measured rate (no gyro noise),
`--calibration-copies N` records each calibration programme N times (the first as the accuracy table does),
`--five-run` calibrates on the KVH guide's five-run programme (tools/accuracy_table.py --five-run) and
`--hysteresis-dph 0` simulates the gyro without its play hysteresis. Besides each case's figures: the
trend's drift RMSE on the calibration blocks (fit) and left out run by run (loro). `--markdown PATH` adds a
table of each case's worst run per seed and writes what is printed as a results page
(docs/results/fine-sensor.md, written by the first command below).

    python tools/trend_diagnostic.py --five-run --rate-prior smooth --seed 1 --seed 2 --seed 3 --seed 4 --seed 5 --case read/read --case read/read/truth --case true/true --case noisy/noisy --case quant/quant --case quant+deq/quant+deq --case read+deq/read+deq --case inv:10/inv:10 --case und:auto/und:auto --markdown docs/results/fine-sensor.md

    python tools/trend_diagnostic.py --case read/read --case true/true --case true/read
    python tools/trend_diagnostic.py --inputs temp,lags@10..3000/7 --case true/true --case read/read --play '' --play 2
    python tools/trend_diagnostic.py --seed 3 --thermal diffusive --case held/held --case quant/quant --case noisy/noisy
    python tools/trend_diagnostic.py --seed 1 --seed 2 --seed 3 --case read/read --case inv:10/inv:10
    python tools/trend_diagnostic.py --seed 3 --seed 4 --case true/true --rate-prior smooth --hysteresis-dph 0
"""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np

from fogd.calibration.models.coil import PRIORS, fit_mix, fit_rate_prior
from fogd.calibration.models.least_squares import RunOffsetLeastSquares
from fogd.calibration.training import PLAY_LAGS_S, UNDITHER_NOISE_STEPS, UNDITHER_TOLERANCE, shortest_within_tolerance
from fogd.core.columns import BLOCK_S, FIT_BLOCK_S
from fogd.core.errorstats import block_means, centred_within_runs, detrended_stats
from fogd.core.inputs import (
    DEFAULT_INPUTS_TEXT,
    clamp_rows,
    inputs_batch,
    lag_taus_s,
    parse_inputs,
    shifted_columns,
    temperature_columns,
    with_play_lag_s,
)
from fogd.core.dequantise import DEFAULT_PACE, dequantise_batch, smoothed_batch
from fogd.core.lag import lag_batch
from fogd.core.play import play_batch
from fogd.core.undither import DEFAULT_TAU_S, undither_batch
from fogd.simulation.profiles import builtin
from fogd.errors import FogdError
from fogd.simulation.simulator import Simulation, params_for

from accuracy_table import CALIBRATION, FIVE_RUN, HELD_OUT, physics_setting  # tools/, beside this file
from bench_common import captured_stdout, results_header, write_results_page

SETTLE_S = 600.0
TARGETS = ("rate", "truth")
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
    base, dequantise, backwards = base.partition("+deq")
    if backwards not in ("", "fb"):
        raise SystemExit(f"unknown temperature {spec!r}")
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
    elif name == "und":
        noise, _, tau = value.partition(":")
        out = undither_batch(run.read_c, run.resolution_c, float(noise), float(tau or DEFAULT_TAU_S), run.rate_hz)
    elif name == "fb":
        from scipy.signal import filtfilt

        tau_s = float(value) / 2
        gain = -math.expm1(-1.0 / (tau_s * run.rate_hz))
        out = filtfilt([gain], [1.0, gain - 1.0], run.read_c, method="gust")
    elif name == "spline":
        out = spline_c(run)
    else:
        raise SystemExit(f"unknown temperature {spec!r}")
    if dequantise:  # causal as the daemon serves it, or forwards and backwards as fogd-train fits it
        estimate = smoothed_batch if backwards else dequantise_batch
        out = estimate(out, run.resolution_c, run.rate_hz, DEFAULT_PACE)
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
    if fit_spec == serve_spec == "und:auto":  # as training.with_undither (which leaves the play out while it chooses)
        resolution_c = calibration[0].resolution_c
        noises = [0.0] + [steps * resolution_c for steps in UNDITHER_NOISE_STEPS]
        no_play = tuple(spec for spec in specs if spec.width_c is None)
        names = [f"und:{noise}" if noise else "read" for noise in noises]
        trials = [(case_scores(calibration, held_out, name, name, no_play, ridge, play, target, rate_prior)[1].fit_rmse_dph,
                   noise) for name, noise in zip(names, noises)]  # fmt: skip
        least = min(residual for residual, _ in trials)
        noise = next(noise for residual, noise in trials if residual <= least * (1.0 + UNDITHER_TOLERANCE))
        chosen = f"und:{noise}" if noise else "read"
        print(f"    (und:auto took {chosen})")
        return case_scores(calibration, held_out, chosen, chosen, specs, ridge, play, target, rate_prior)
    if any(spec.play_lag_auto for spec in specs):  # chosen as fogd-train chooses it, by the residual on the blocks
        trials = [case_scores(calibration, held_out, fit_spec, serve_spec, with_play_lag_s(specs, lag_s), ridge, play,
                              target, rate_prior) for lag_s in PLAY_LAGS_S]  # fmt: skip
        return shortest_within_tolerance([(trial[1].fit_rmse_dph, trial) for trial in trials])
    block_n = round(FIT_BLOCK_S * calibration[0].rate_hz)  # as fogd-train fits; scored on BLOCK_S
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


PAGE_TITLE = "What limits the fine sensor"
PAGE_INTRO = """The default's coil trend alone (no SVR), fitted on the calibration runs' 200 s blocks as fogd-train fits it and replayed on the
accuracy table's five held-out runs, with one thing changed at a time: what the trend is fitted to (the
measured rate, or the true thermal error: no gyro noise) and the temperature its inputs are computed from at fit
and at serve time (`read`: the readings as the daemon sees them; `noisy`: the true temperature with the sensor's
noise, sampled and held, no steps; `quant`: the true temperature in the sensor's 1/16 C steps, no noise;
`+deq`: through fogd.core.dequantise's causal estimate, `+deqfb` its forwards-and-backwards mean, as fogd-train
fits a whole-degree sensor; `inv:10`: a 10 s mean of the readings through the inverse of the noise-dithered
staircase, the noise known; `und:auto`: fogd.core.undither's estimate as fogd-train now computes a fine sensor's
inputs, its noise chosen on the calibration blocks, which the line before each of its rows names). Each cell is the worst held-out run's drift over the noise floor, as in the accuracy
table (the lines first give every run, then each coil's table the worst per seed). A case near 1.0 says what is
left when that one thing is removed."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, action="append", help="seeds (repeatable; default 1 and 2)")
    parser.add_argument("--thermal", choices=("lumped", "diffusive"), action="append")
    parser.add_argument("--rate-hz", type=float, default=10.0)
    parser.add_argument("--resolution-c", type=float, default=0.0625)
    parser.add_argument("--sensor-hz", type=float, default=4.0)
    parser.add_argument("--inputs", default=DEFAULT_INPUTS_TEXT)
    parser.add_argument("--case", action="append",
                        help="FIT/SERVE temperatures, e.g. read/read, or FIT/SERVE/truth (repeatable)")
    parser.add_argument("--hysteresis-dph", type=float, default=None, help="the gyro's play (default: the preset's)")
    parser.add_argument("--play", action="append", help="WIDTH@TAU: add a play operator input (repeatable: one case each)")
    parser.add_argument("--target", choices=TARGETS, default="rate",
                        help="fit the calibration runs' measured rate, or their true thermal error (no gyro noise), "
                             "where a case does not say")
    parser.add_argument("--ridge", default="0", help="ridge strength on the scaled trend, or 'loro'")
    parser.add_argument("--rate-prior", choices=PRIORS, default="none",
                        help="the coil trend's prior on its lags' rate coefficients, as fogd-train's --rate-prior "
                             "(default none here: plain least squares, as before the prior)")
    parser.add_argument("--calibration-copies", type=int, default=1, metavar="N",
                        help="record each calibration programme N times (other noise seeds): what more calibration buys")
    parser.add_argument("--physics", type=physics_setting, action="append", metavar="KEY=VALUE",
                        help="another simulated gyro, as tools/accuracy_table.py --physics (repeatable)")
    parser.add_argument("--five-run", action="store_true",
                        help="calibrate on the KVH guide's five-run programme (" + " + ".join(FIVE_RUN) + ")")
    parser.add_argument("--title", default=PAGE_TITLE, help=f"the results page's title (default: {PAGE_TITLE})")
    parser.add_argument("--markdown", metavar="PATH", help="also write what is printed, with a table of each "
                        "case's worst run per seed, as a results page (replaced whole)")  # fmt: skip
    args = parser.parse_args()
    cases = args.case or ["read/read", "true/true", "true/read"]
    for case in cases:
        if not 2 <= len(case.split("/")) <= 3 or case.count("/") == 2 and case.rsplit("/", 1)[1] not in TARGETS:
            parser.error(f"--case {case!r}: give FIT/SERVE or FIT/SERVE/TARGET, TARGET one of {', '.join(TARGETS)}")
    if not args.markdown:
        run_cases(args, cases)
        return
    with captured_stdout() as printed:
        run_cases(args, cases)
    physics = ", ".join(f"{key}={value}" for key, value in args.physics or []) or "the navigation preset's"
    header = results_header(f"{args.title} (tools/trend_diagnostic.py)", ["python", "tools/trend_diagnostic.py", *sys.argv[1:]],
                            settings=f"coil trend alone on {args.inputs}, rate prior {args.rate_prior}; calibration "
                                     f"{' + '.join(programme(args))}; physics {physics}")  # fmt: skip
    try:
        write_results_page(args.markdown, header, PAGE_INTRO + "\n\n" + printed.getvalue())
    except FogdError as error:
        raise SystemExit(f"trend_diagnostic: cannot write {args.markdown}: {error}") from None
    print(f"trend_diagnostic: wrote {args.markdown}", file=sys.stderr)


def programme(args) -> tuple[str, ...]:
    """The calibration runs' chamber programmes."""
    return FIVE_RUN if args.five_run else CALIBRATION


def run_cases(args, cases: list[str]) -> None:
    """Print each case's line per seed and coil, then each coil's table of the worst run per seed."""
    specs = parse_inputs(args.inputs)
    ridge = args.ridge if args.ridge == "loro" else float(args.ridge)
    seeds, thermals = args.seed or [1, 2], args.thermal or ["lumped", "diffusive"]
    print(f"coil trend alone on {args.inputs}, ridge {args.ridge}, rate prior {args.rate_prior}, calibration "
          f"{' + '.join(programme(args))}: held-out drift / noise floor ({', '.join(HELD_OUT)}), worst\n")  # fmt: skip
    worst: dict[tuple[str, str], list[float]] = {}
    for seed in seeds:
        for thermal in thermals:
            extra = dict(args.physics or [])
            if args.hysteresis_dph is not None:
                extra["hysteresis_dph"] = args.hysteresis_dph
            params = params_for("navigation", thermal, sensor_resolution_c=args.resolution_c,
                                sensor_rate_hz=args.sensor_hz, **extra)  # fmt: skip
            calibration = [SimRun(name, seed + i + 1000 * copy, args.rate_hz, params)  # copy 0: the accuracy table's
                           for copy in range(args.calibration_copies) for i, name in enumerate(programme(args))]
            held_out = [SimRun(name, seed + 100 + i, args.rate_hz, params) for i, name in enumerate(HELD_OUT)]
            for case, play in ((case, play) for case in cases for play in args.play or [None]):
                fit_spec, serve_spec, target = (case.split("/") + [args.target])[:3]
                ratios, trend = case_scores(calibration, held_out, fit_spec, serve_spec, specs, ridge, play, target,
                                            args.rate_prior)  # fmt: skip
                case = case if play is None else f"{case} play {play}"
                worst.setdefault((thermal, case), []).append(max(ratios))
                chosen = f" ridge {trend.ridge:g}" if ridge == "loro" else ""
                print(f"    seed {seed} {thermal:9s} {case:28s} " + " ".join(f"{r:5.2f}" for r in ratios)
                      + f"  worst {max(ratios):.2f}{chosen}  fit {trend.fit_rmse_dph * 1e3:.3f} loro {trend.loro_dph * 1e3:.3f} mdeg/h",
                      flush=True)  # fmt: skip
    for thermal in thermals:
        print(f"\n{thermal} coil: the worst held-out run's drift / noise floor, per seed\n")
        print("| case (fit / serve [/ target]) | " + " | ".join(f"seed {seed}" for seed in seeds) + " | worst | mean |")
        print("|---|" + "---:|" * (len(seeds) + 2))
        for (coil, case), values in worst.items():
            if coil == thermal:
                print(f"| {case} | " + " | ".join(f"{v:.2f}" for v in values)
                      + f" | {max(values):.2f} | {np.mean(values):.2f} |")  # fmt: skip


if __name__ == "__main__":
    main()
