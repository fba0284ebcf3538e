"""Held-out accuracy of fogd's compensation on simulated runs that were not used for training.

For each gyro physics (a navigation-grade gyro like the paper's, its thermal error 30-100x the noise floor,
with a lumped and a diffusive coil) and each temperature sensor (a fine one, 0.0625 C at 4 Hz, and a KVH's
whole degrees at 1 Hz), simulates three calibration runs (heating -15..50 C, cooling 50..-10 C, a cycle) and
five held-out runs with other seeds (0..30 C, cooling 40..0 C, a ramp faster than any calibration ramp, a
soak after a ramp, a fast cycle), trains each scheme the way `fogd-train` does, replays the held-out runs
through the daemon's compensator and prints the std of 100 s block means after the first 600 s as a
multiple of the noise floor (the same run with its true thermal error removed): 1.00 is perfect. The
fallback column is the share of the held-out samples that the domain guard sent to its linear fallback.

    python tools/accuracy_table.py            # the README's tables (PSO 60 x 100; about an hour on 2 cores)
    python tools/accuracy_table.py --quick    # PSO 20 x 20 (and 10 x 10 inside auto), about 15 minutes
    python tools/accuracy_table.py --quick --hysteresis-dph 0   # the gyro without its play hysteresis
"""

from __future__ import annotations

import argparse
import hashlib
import time

import numpy as np

from fogd.calibration.models import FitOptions
from fogd.calibration.replay import replay, replay_table
from fogd.calibration.selection import (
    AUTO_ITERATIONS,
    AUTO_PARTICLES,
    input_sets,
    select,
)
from fogd.calibration.training import TrainConfig, train
from fogd.core.inputs import DEFAULT_INPUTS_TEXT, default_inputs, parse_inputs
from fogd.core.runio import Run
from fogd.simulation.profiles import builtin
from fogd.simulation.simulator import params_for, simulate

CALIBRATION = ("paper-train", "cooling", "cycle")
HELD_OUT = ("paper-test", "cool-40-to-0", "fast-ramp", "soak-after-ramp", "fast-cycle")
SENSORS = {"fine (0.0625 C, 4 Hz)": (0.0625, 4.0), "whole degrees (1 C, 1 Hz, a KVH)": (1.0, 1.0)}
THERMALS = ("lumped", "diffusive")
LINEAR = "linear (IEEE 952: temp, rate@50)"
DEFAULT = f"**fogd default: pso-svr, coil trend, {DEFAULT_INPUTS_TEXT}**"
AUTO = "fogd-train --method auto"
SCHEMES = (  # (label, method, inputs, fitness, trend, domain guard)
    (LINEAR, "linear", None, "cv", "linear", False),
    ("paper's recipe: pso-svr --fitness train --trend none (temp, rate@50)", "pso-svr", None, "train", "none", False),
    ("the previous default: pso-svr --trend poly, lags@30..3000/5", "pso-svr", "lags@30..3000/5", "cv", "poly", False),
    (DEFAULT, "pso-svr", DEFAULT_INPUTS_TEXT, "cv", "coil", False),
    ("default with the domain guard", "pso-svr", DEFAULT_INPUTS_TEXT, "cv", "coil", True),
    (AUTO, "auto", None, "cv", "coil", False),
)


def simulated_run(profile: str, seed: int, rate_hz: float, params) -> Run:
    sim = simulate(builtin(profile), rate_hz, seed, params)
    digest = hashlib.sha256(sim.rate_dph.tobytes()).hexdigest()
    return Run(f"{profile}.csv", sim.t_s, sim.rate_dph, sim.temp_c, rate_hz, digest, {"true_error_dph": sim.true_error_dph})


def evaluate(args, thermal: str, resolution_c: float, sensor_hz: float) -> dict[str, list]:
    extra = {} if args.hysteresis_dph is None else {"hysteresis_dph": args.hysteresis_dph}
    params = params_for("navigation", thermal, sensor_resolution_c=resolution_c, sensor_rate_hz=sensor_hz, **extra)
    calibration = [simulated_run(name, args.seed + i, args.rate_hz, params) for i, name in enumerate(CALIBRATION)]
    held_out = [simulated_run(name, args.seed + 100 + i, args.rate_hz, params) for i, name in enumerate(HELD_OUT)]
    size = (20, 20) if args.quick else (60, 100)
    auto_size = (10, 10) if args.quick else (AUTO_PARTICLES, AUTO_ITERATIONS)
    rows: dict[str, list] = {}
    for label, method, inputs, fitness, trend, guard in SCHEMES:
        swarm = auto_size if method == "auto" else size
        options = FitOptions(particles=swarm[0], iterations=swarm[1], fitness=fitness, trend=trend, n_jobs=args.jobs,
                             seed=args.seed, progress=False)  # fmt: skip
        config = TrainConfig(method=method, inputs=parse_inputs(inputs) if inputs else default_inputs(),
                             fit=options, domain_guard=guard)  # fmt: skip
        started = time.perf_counter()
        if method == "auto":
            winner, _ = select(calibration, config, input_sets(None, 0.5, 0.0))
            trained, note = winner.trained, f"chose {winner.label}"
        else:
            trained, note = train(calibration, config), ""
        print(f"#   {label}: {time.perf_counter() - started:.0f} s {note}", flush=True)
        tables = [replay_table(run, replay(trained.model, run), 100.0) for run in held_out]
        rows[label] = [(t.after.rmse_dph / t.best.rmse_dph, t.fallback_share) for t in tables]
        rows.setdefault("Before compensation", [(t.before.rmse_dph / t.best.rmse_dph, 0.0) for t in tables])
        rows.setdefault("_floor", [t.best.rmse_dph for t in tables])
        if method == "auto":
            rows["_auto_choice"] = [note]
    return rows


def print_table(title: str, rows: dict[str, list]) -> None:
    print(f"\n{title}\n")
    print("| Scheme | " + " | ".join(HELD_OUT) + " | worst | fallback |")
    print("|---|" + "---:|" * (len(HELD_OUT) + 2))
    for label in ["Before compensation"] + [scheme[0] for scheme in SCHEMES]:
        ratios = [ratio for ratio, _ in rows[label]]
        fallback = max(share for _, share in rows[label])
        print(f"| {label} | " + " | ".join(f"{r:.2f}" for r in ratios) + f" | {max(ratios):.2f} | {fallback * 100:.1f} % |")
    print("| Noise floor, deg/h | " + " | ".join(f"{f:.1e}" for f in rows["_floor"]) + " | | |")
    auto = np.array([r for r, _ in rows[AUTO]]) / np.array([r for r, _ in rows[LINEAR]])
    print(f"\n{AUTO} {rows['_auto_choice'][0]}; auto / linear per run: " + ", ".join(f"{g:.3f}" for g in auto)
          + f" (worst {auto.max():.3f})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rate-hz", type=float, default=10.0, help="simulated gyro rate, Hz (default 10)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--thermal", choices=THERMALS, action="append", help="only this coil structure (repeatable)")
    parser.add_argument("--sensor", choices=("fine", "whole"), action="append", help="only this sensor (repeatable)")
    parser.add_argument("--hysteresis-dph", type=float, default=None,
                        help="the simulated gyro's play hysteresis, deg/h (default: the navigation preset's, 0.001); "
                             "0 shows what the thermal model alone leaves")
    parser.add_argument("--quick", action="store_true", help="PSO 20 x 20 instead of the paper's 60 x 100, 10 x 10 inside auto")
    args = parser.parse_args()
    for thermal in args.thermal or THERMALS:
        for sensor, (resolution_c, sensor_hz) in SENSORS.items():
            if args.sensor and sensor.split()[0] not in args.sensor:
                continue
            print(f"# {thermal} coil, {sensor} sensor", flush=True)
            rows = evaluate(args, thermal, resolution_c, sensor_hz)
            hysteresis = "" if args.hysteresis_dph is None else f", hysteresis {args.hysteresis_dph:g} deg/h"
            print_table(f"Navigation-grade gyro, {thermal} coil, {sensor} sensor; {args.rate_hz:g} Hz, seed {args.seed}"
                        f"{', PSO 20 x 20' if args.quick else ''}{hysteresis}: std of 100 s block means after 600 s / noise floor",
                        rows)  # fmt: skip


if __name__ == "__main__":
    main()
