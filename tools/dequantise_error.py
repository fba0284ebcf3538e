"""How much drift does a coarse sensor's causal temperature estimate cost? A fast diagnostic, no PSO.

`tools/quantisation_bound.py --hindsight` showed that what holds a whole-degree sensor's fast held-out runs
far above the bound is the dequantised temperature (fogd.core.dequantise), not the calibration runs. This
tool measures an estimator by the error it induces in what matters, in seconds: it simulates
`tools/accuracy_table.py`'s runs, fits the default's linear coil trend (fogd.calibration.models.coil, no SVR)
on the calibration runs' TRUE sensor temperature (the sensor element's, before its noise and quantisation)
against their true thermal error, then applies those fixed coefficients on each held-out run to (a) the true
temperature's lag bank and (b) the estimate's, and prints the accuracy table's metric (std of 100 s block
means after 600 s, over the run's noise floor) of (b) - (a): the drift the estimate alone adds. Also the
estimate's own RMS error against the true temperature (what the sensor element itself reads, noise-free).

    python tools/dequantise_error.py                      # seeds 1 and 2, both coils, every estimator
    python tools/dequantise_error.py --estimators linear,quadratic --seeds 1 --thermal lumped
    python tools/dequantise_error.py --estimators quadratic --fit smoothed   # fitted as fogd-train fits it

Estimators: `readings` (the staircase itself); fogd.core.dequantise at its `linear` pace (fogd-train's before
`dequantise_pace`) and its `quadratic` pace (the default now); `kalman-edge` and `kalman-clamp`, an
experimental (temperature, pace) Kalman filter on the crossings (`TrackingDequantiser`, here only: it did worse
than either pace).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np

from fogd.calibration.models.coil import fit_mix
from fogd.calibration.models.least_squares import RunOffsetLeastSquares
from fogd.calibration.replay import block_grid
from fogd.core.columns import BLOCK_S
from fogd.core.dequantise import dequantise_batch
from fogd.core.errorstats import detrended_stats
from fogd.core.inputs import DEFAULT_INPUTS_TEXT, inputs_batch, parse_inputs, temperature_columns, with_play_lag_s
from fogd.core.runio import Run
from fogd.simulation.profiles import builtin
from fogd.simulation.simulator import Simulation, params_for

CALIBRATION = ("paper-train", "cooling", "cycle")  # as accuracy_table.py, with its seeds
HELD_OUT = ("paper-test", "cool-40-to-0", "fast-ramp", "soak-after-ramp", "fast-cycle")
THERMALS = ("lumped", "diffusive")
FIT_EVERY = 10  # rows: the trend is fitted on 1 Hz rows (10 Hz runs), which is plenty for eight coefficients

class TrackingDequantiser:
    """Experimental: a (temperature, pace) Kalman filter (white acceleration of spectral density `accel_psd`,
    C^2/s^3) whose measurements are the crossings (the level at the change, variance `cross_var_c2`) and whose
    band is applied, when the prediction leaves it, as a measurement at the band's edge (`edge_var_c2`: an
    overdue crossing says the pace has dropped) or, with `edge_var_c2` 0, as a clamp of the temperature alone."""

    def __init__(self, resolution_c: float, rate_hz: float, accel_psd: float = 1e-7, cross_var_c2: float = 1e-3,
                 edge_var_c2: float = 1e-3, pace0_cps: float = 0.01) -> None:
        self.resolution_c = float(resolution_c)
        self.rate_hz = float(rate_hz)
        dt = 1.0 / self.rate_hz
        self._dt = dt
        self._q = (accel_psd * dt**3 / 3.0, accel_psd * dt**2 / 2.0, accel_psd * dt)
        self._cross_var = cross_var_c2
        self._edge_var = edge_var_c2
        self._pace0 = pace0_cps
        self.reset()

    def reset(self) -> None:
        self._reading_c: float | None = None
        self._x = 0.0
        self._v = 0.0
        self._pxx = self._pxv = self._pvv = 0.0

    def update(self, temp_c: np.ndarray) -> np.ndarray:
        temp_c = np.atleast_1d(np.asarray(temp_c, dtype=np.float64))
        return np.array([self.update_one(value) for value in temp_c.tolist()], dtype=np.float64)

    def _measure(self, z: float, r: float) -> None:
        s = self._pxx + r
        kx, kv = self._pxx / s, self._pxv / s
        innovation = z - self._x
        self._x += kx * innovation
        self._v += kv * innovation
        pxx, pxv, pvv = self._pxx, self._pxv, self._pvv
        self._pxx = pxx - kx * pxx
        self._pxv = pxv - kx * pxv
        self._pvv = pvv - kv * pxv

    def update_one(self, temp_c: float) -> float:
        half_c = 0.5 * self.resolution_c
        if self._reading_c is None:
            self._reading_c = temp_c
            self._x, self._v = temp_c, 0.0
            self._pxx, self._pxv, self._pvv = self.resolution_c**2 / 12.0, 0.0, self._pace0**2
            return temp_c
        dt = self._dt
        self._x += self._v * dt
        pxx, pxv, pvv = self._pxx, self._pxv, self._pvv
        self._pxx = pxx + 2.0 * dt * pxv + dt * dt * pvv + self._q[0]
        self._pxv = pxv + dt * pvv + self._q[1]
        self._pvv = pvv + self._q[2]
        if temp_c != self._reading_c:
            level_c = 0.5 * (temp_c + self._reading_c)
            self._reading_c = temp_c
            self._measure(level_c, self._cross_var)
        low, high = temp_c - half_c, temp_c + half_c
        if self._edge_var > 0.0:
            if self._x > high:
                self._measure(high, self._edge_var)
            elif self._x < low:
                self._measure(low, self._edge_var)
        else:  # the mean projected onto the band, its pace kept
            self._x = min(max(self._x, low), high)
        return min(max(self._x, low), high)


Estimator = Callable[[np.ndarray, float, float], np.ndarray]  # (held readings, resolution C, rate Hz) -> estimate
ESTIMATORS: dict[str, Estimator] = {
    "readings": lambda temp_c, resolution_c, rate_hz: np.asarray(temp_c, dtype=np.float64),
    "linear": lambda temp_c, resolution_c, rate_hz: dequantise_batch(temp_c, resolution_c, rate_hz, "linear"),
    "quadratic": lambda temp_c, resolution_c, rate_hz: dequantise_batch(temp_c, resolution_c, rate_hz, "quadratic"),
    "kalman-edge": lambda temp_c, resolution_c, rate_hz: TrackingDequantiser(
        resolution_c, rate_hz, accel_psd=1e-7, edge_var_c2=1e-2).update(temp_c),
    "kalman-clamp": lambda temp_c, resolution_c, rate_hz: TrackingDequantiser(
        resolution_c, rate_hz, accel_psd=1e-7, edge_var_c2=0.0).update(temp_c),
}


class SimRun:
    """One simulated run: its 10 Hz rows, the sensor's held readings and its element's true temperature."""

    def __init__(self, name: str, seed: int, rate_hz: float, params) -> None:
        sim = Simulation(builtin(name), rate_hz, seed, params)
        columns = sim.columns()
        self.name = name
        self.t_s = columns["t_s"]
        self.rate_dph = columns["rate_dph"]
        self.readings_c = columns["temp_c"]
        self.true_error_dph = columns["true_error_dph"]
        self.true_c = np.interp(self.t_s, sim.grid_t_s, sim.states[sim.network.sensor])
        grid = block_grid(Run(name, self.t_s, self.rate_dph, self.readings_c, rate_hz, "", {}),
                          np.zeros(self.t_s.size, dtype=np.uint16), BLOCK_S)  # fmt: skip
        self.means = grid.means
        self.floor_dph = self.drift(self.rate_dph - self.true_error_dph)

    def drift(self, values: np.ndarray) -> float:
        return detrended_stats(self.means(values)).rmse_dph


def fitted_trend(runs: list[SimRun], temps_c: list[np.ndarray], specs, rate_hz: float):
    """The default's linear coil trend (no SVR) fitted on the runs' temperatures `temps_c`: a predictor from
    a temperature."""
    features = [inputs_batch(temp_c, specs, rate_hz)[::FIT_EVERY] for temp_c in temps_c]
    xs = np.vstack(features)
    centre, scale = xs.mean(axis=0), xs.std(axis=0)
    xs = (xs - centre) / scale
    ys = np.concatenate([run.true_error_dph[::FIT_EVERY] for run in runs])
    groups = np.concatenate([np.full(f.shape[0], k) for k, f in enumerate(features)])
    terms = fit_mix(xs, ys, groups, temperature_columns(specs))
    model = RunOffsetLeastSquares(terms).fit(xs, ys, groups)
    return lambda temp_c: model.predict((inputs_batch(temp_c, specs, rate_hz) - centre) / scale)


def fit_temperature(estimator: Estimator, readings_c: np.ndarray, resolution_c: float, rate_hz: float,
                    fit: str) -> np.ndarray:  # fmt: skip
    """The calibration run's temperature the trend is fitted on: the estimate as served ("causal") or, as
    fogd-train fits a dequantised temperature, the mean of the estimate forwards and backwards in time."""
    forwards = estimator(readings_c, resolution_c, rate_hz)
    if fit == "causal":
        return forwards
    return 0.5 * (forwards + estimator(readings_c[::-1], resolution_c, rate_hz)[::-1])


def evaluate(thermal: str, seed: int, names: list[str], resolution_c: float, sensor_hz: float,
             rate_hz: float, fit: str = "causal") -> dict[str, list[tuple[float, float, float]]]:  # fmt: skip
    """Per estimator, per held-out run: (added drift / floor, total drift / floor, estimate RMS error C)."""
    params = params_for("navigation", thermal, sensor_resolution_c=resolution_c, sensor_rate_hz=sensor_hz)
    calibration = [SimRun(name, seed + i, rate_hz, params) for i, name in enumerate(CALIBRATION)]
    held_out = [SimRun(name, seed + 100 + i, rate_hz, params) for i, name in enumerate(HELD_OUT)]
    specs = with_play_lag_s(parse_inputs(DEFAULT_INPUTS_TEXT), 0.0)  # the play's lag is not this tool's question
    predict = fitted_trend(calibration, [run.true_c for run in calibration], specs, rate_hz)
    results: dict[str, list[tuple[float, float, float]]] = {"true": []}
    truths = []
    for run in held_out:
        truth = predict(run.true_c)
        truths.append(truth)
        results["true"].append((0.0, run.drift(run.true_error_dph - truth) / run.floor_dph, 0.0))
    for name in names:
        estimator = ESTIMATORS[name]
        own = fitted_trend(calibration, [fit_temperature(estimator, run.readings_c, resolution_c, rate_hz, fit)
                                         for run in calibration], specs, rate_hz)  # fmt: skip
        results[name] = []
        for run, truth in zip(held_out, truths):
            estimate_c = estimator(run.readings_c, resolution_c, rate_hz)
            rms_c = float(np.sqrt(np.mean((estimate_c - run.true_c) ** 2)))
            results[name].append((run.drift(predict(estimate_c) - truth) / run.floor_dph,
                                  run.drift(run.true_error_dph - own(estimate_c)) / run.floor_dph, rms_c))  # fmt: skip
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--resolution-c", type=float, default=1.0, help="sensor resolution, C (default 1: a KVH)")
    parser.add_argument("--sensor-hz", type=float, default=1.0, help="sensor report rate, Hz (default 1)")
    parser.add_argument("--rate-hz", type=float, default=10.0, help="simulated gyro rate, Hz (default 10)")
    parser.add_argument("--seeds", type=lambda text: [int(s) for s in text.split(",")], default=[1, 2],
                        help="comma-separated seeds, as accuracy_table.py's --seed (default 1,2)")
    parser.add_argument("--thermal", choices=THERMALS, action="append", help="only this coil structure (repeatable)")
    parser.add_argument("--fit", choices=("causal", "smoothed"), default="causal",
                        help="the total's trend fitted on the calibration runs' estimate as served (default), or on "
                             "its mean forwards and backwards in time, as fogd-train fits a dequantised temperature")
    parser.add_argument("--estimators", type=lambda text: text.split(","), default=list(ESTIMATORS),
                        help="comma-separated, of: " + ", ".join(ESTIMATORS))
    args = parser.parse_args()
    unknown = sorted(set(args.estimators) - set(ESTIMATORS))
    if unknown:
        parser.error(f"unknown estimator {', '.join(unknown)}: choose from {', '.join(ESTIMATORS)}")
    print(f"# sensor {args.resolution_c:g} C at {args.sensor_hz:g} Hz, gyro {args.rate_hz:g} Hz; the default's linear "
          f"coil trend ({DEFAULT_INPUTS_TEXT}) fitted on the calibration runs' true sensor temperature")
    print("# added: drift / floor of (trend on the estimate) - (trend on the true temperature); total: of the true "
          "error minus the trend "
          f"fitted on the calibration runs' estimate ({args.fit}) and served the estimate (fogd-train and the daemon "
          "without the SVR); rms: the estimate's error, C\n")
    print("| seed | coil | estimator | added: " + " / ".join(HELD_OUT) + " | mean | total (own fit) | mean | rms C |")
    print("|---|---|---|---|---:|---|---:|---|")
    summary: dict[str, list[float]] = {}
    totals: dict[str, list[float]] = {}
    for seed in args.seeds:
        for thermal in args.thermal or THERMALS:
            started = time.perf_counter()
            results = evaluate(thermal, seed, args.estimators, args.resolution_c, args.sensor_hz, args.rate_hz, args.fit)
            for name, values in results.items():
                added = [v[0] for v in values]
                total = [v[1] for v in values]
                summary.setdefault(name, []).extend(added)
                totals.setdefault(name, []).extend(total)
                print(f"| {seed} | {thermal} | {name} | " + " / ".join(f"{a:.2f}" for a in added)
                      + f" | {np.mean(added):.2f} | " + " / ".join(f"{a:.2f}" for a in total) + f" | {np.mean(total):.2f} | "
                      + " / ".join(f"{v[2]:.3f}" for v in values) + " |", flush=True)
            print(f"#   {time.perf_counter() - started:.0f} s", flush=True)
    print("\nOver every seed, coil and run, mean (worst): added drift / floor; total with its own fit")
    for name, added in summary.items():
        print(f"  {name:12s} {np.mean(added):.2f} ({max(added):.2f});  {np.mean(totals[name]):.2f} ({max(totals[name]):.2f})")


if __name__ == "__main__":
    main()
