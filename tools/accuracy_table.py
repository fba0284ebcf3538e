"""Held-out accuracy of every method on simulated runs that were not used for training.

Simulates several calibration runs (heating -15..50 C, cooling 50..-10 C, a heat/cool cycle) and several
held-out runs with fogd's simulator (another range 0..30 C, cooling 40..0 C, a ramp faster than any
calibration run, a soak after a ramp), trains each method the way `fogd-train` does (the paper's recipe,
fogd's default, `--method auto`, and the single families), replays the held-out runs with the daemon's
compensator, and prints the RMSE of 100 s block means after compensation as a multiple of the best possible
result (the run with its true thermal error removed). 1.00 would be perfect. The last lines compare auto
with linear run by run.

    python tools/accuracy_table.py            # the README's table (~10 min on 2 cores)
    python tools/accuracy_table.py --quick    # 10 Hz runs and small swarms, for a quick look (~2 min)
"""

from __future__ import annotations

import argparse
import hashlib
import time

import numpy as np

from fogd.models import FitOptions
import dataclasses

from fogd.profiles import Profile, builtin
from fogd.selection import AUTO_ITERATIONS, AUTO_PARTICLES, DEFAULT_INPUT_SETS, input_sets, select
from fogd.replay import replay, replay_table
from fogd.runio import Run
from fogd.simulator import simulate
from fogd.selection import FAMILIES
from fogd.training import TrainConfig, prepare, train

CALIBRATION = ("paper-train", "cooling", "cycle")
HELD_OUT = ("paper-test", "cool-40-to-0", "fast-ramp", "soak-after-ramp")
EXTRA_PROFILES = {"cool-40-to-0": Profile("cool-40-to-0", ((3600.0, 40.0), (7200.0, 0.0), (3600.0, 0.0)))}
LINEAR = "linear (IEEE 952)"
AUTO = "fogd-train --method auto"
SCHEMES = (  # (label, method, fitness, linear trend under the SVR, domain guard)
    (LINEAR, "linear", "cv", False, False),
    ("ls-poly (order 5)", "ls-poly", "cv", False, False),
    ("rbf-nn (L1)", "rbf-nn", "cv", False, False),
    ("paper's recipe: pso-svr --fitness train --trend none", "pso-svr", "train", False, False),
    ("pso-svr --fitness cv --trend none", "pso-svr", "cv", False, False),
    ("fogd default: pso-svr --fitness cv --trend linear", "pso-svr", "cv", True, True),
    ("fogd default without the domain guard", "pso-svr", "cv", True, False),
    (AUTO, "auto", "cv", True, True),
)


def simulated_run(profile: str, seed: int, rate_hz: float) -> Run:
    sim = simulate(EXTRA_PROFILES.get(profile) or builtin(profile), rate_hz, seed)
    digest = hashlib.sha256(sim.rate_dph.tobytes()).hexdigest()
    return Run(f"{profile}.csv", sim.t_s, sim.rate_dph, sim.temp_c, rate_hz, digest, {"true_error_dph": sim.true_error_dph})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rate-hz", type=float, default=None, help="simulated data rate (default 50 Hz; 10 Hz with --quick)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument(
        "--quick", action="store_true",
        help=f"10 Hz runs, PSO 20 x 20 instead of the paper's 60 x 100, 10 x 10 inside auto instead of {AUTO_PARTICLES} x {AUTO_ITERATIONS}",
    )  # fmt: skip
    args = parser.parse_args()
    args.rate_hz = args.rate_hz or (10.0 if args.quick else 50.0)

    calibration = [simulated_run(name, args.seed + i, args.rate_hz) for i, name in enumerate(CALIBRATION)]
    held_out = [simulated_run(name, args.seed + 100 + i, args.rate_hz) for i, name in enumerate(HELD_OUT)]
    size = (20, 20) if args.quick else (60, 100)
    auto_size = (10, 10) if args.quick else (AUTO_PARTICLES, AUTO_ITERATIONS)
    config = TrainConfig()
    prepared = prepare(calibration, config)

    ratios: dict[str, list[float]] = {}
    rmse: dict[str, list[float]] = {}
    best: list[float] = []
    before: list[float] = []
    for label, method, fitness, trend, guard in SCHEMES:
        swarm = auto_size if method == "auto" else size
        config.method = method
        config.domain_guard = guard
        config.fit = FitOptions(
            particles=swarm[0], iterations=swarm[1], fitness=fitness, trend=trend, n_jobs=args.jobs, seed=args.seed,
            progress=False,
        )  # fmt: skip
        started = time.perf_counter()
        if method == "auto":
            winner, candidates = select(calibration, config, input_sets(None, 0.5, 0.0))
            trained = winner.trained
            chosen = winner.label
            print("# auto candidates (held-out RMSE, leave-one-run-out): "
                  + "; ".join(f"{c.label} {c.held_out_rmse_dph:.3e}" for c in candidates), flush=True)  # fmt: skip
        else:
            trained = train(calibration, dataclasses.replace(config), prepared)
        seconds = time.perf_counter() - started
        print(f"# {label}: trained in {seconds:.1f} s, {trained.fitted.method}, {trained.fitted.hyperparameters}", flush=True)
        for run in held_out:
            table = replay_table(run, replay(trained.model, run), config.block_s)
            ratios.setdefault(label, []).append(table.after.rmse_dph / table.best.rmse_dph)
            rmse.setdefault(label, []).append(table.after.rmse_dph)
            if len(best) < len(held_out):
                best.append(table.best.rmse_dph)
                before.append(table.before.rmse_dph)

    print(f"\nCalibration: {' + '.join(CALIBRATION)} at {args.rate_hz:g} Hz; PSO {size[0]} x {size[1]} "
          f"({auto_size[0]} x {auto_size[1]} inside auto); seed {args.seed}. auto chose {chosen} from "
          f"{len(FAMILIES)} families x input sets {' | '.join(DEFAULT_INPUT_SETS)}.")
    print("RMSE of 100 s block means after compensation, as a multiple of the best possible (1.00 = perfect);")
    print("the last column is the mean over the held-out runs.\n")
    print("| Scheme | " + " | ".join(HELD_OUT) + " | mean |")
    print("|---|" + "---:|" * (len(HELD_OUT) + 1))
    print("| Before compensation | " + " | ".join(f"{b / o:.2f}" for b, o in zip(before, best)) + f" | {np.mean(np.array(before) / best):.2f} |")
    for label, values in ratios.items():
        print(f"| {label} | " + " | ".join(f"{v:.2f}" for v in values) + f" | {np.mean(values):.2f} |")
    print("| Best possible, RMSE in deg/h | " + " | ".join(f"{b:.2e}" for b in best) + " | |")
    gain = np.array(rmse[AUTO]) / np.array(rmse[LINEAR])
    print("\nauto / linear RMSE per held-out run: " + ", ".join(f"{name} {g:.3f}" for name, g in zip(HELD_OUT, gain))
          + f"; mean {gain.mean():.3f} ({(1 - gain.mean()) * 100:+.1f}% better on average), worst {gain.max():.3f}"
          + (" (never worse than linear)" if gain.max() <= 1.0 else " (WORSE than linear on some run)"))


if __name__ == "__main__":
    main()
