"""Held-out accuracy of every method on simulated runs that were not used for training.

Simulates calibration runs and held-out runs with fogd's simulator (another temperature range, a faster
ramp, cooling, a soak after a ramp), trains each method the way `fogd-train` does, replays the held-out runs
with the daemon's compensator, and prints the RMSE of 100 s block means after compensation as a multiple of
the best possible result (the run with its true thermal error removed). 1.00 would be perfect.

    python tools/accuracy_table.py            # the README's table (a few minutes on 2 cores)
    python tools/accuracy_table.py --quick    # a smaller swarm, for a quick look
"""

from __future__ import annotations

import argparse
import hashlib
import time

import numpy as np

from fogd.models import FitOptions
from fogd.profiles import builtin
from fogd.replay import replay, replay_table
from fogd.runio import Run
from fogd.simulator import simulate
from fogd.training import TrainConfig, prepare, train

CALIBRATION = ("paper-train", "cooling")
HELD_OUT = ("paper-test", "fast-ramp", "cycle", "soak-after-ramp")
SCHEMES = (  # (label, method, fitness, linear trend under the SVR)
    ("linear (IEEE 952)", "linear", "cv", False),
    ("ls-poly (order 5)", "ls-poly", "cv", False),
    ("rbf-nn (L1)", "rbf-nn", "cv", False),
    ("paper's recipe: pso-svr --fitness train --trend none", "pso-svr", "train", False),
    ("pso-svr --fitness cv --trend none", "pso-svr", "cv", False),
    ("fogd default: pso-svr --fitness cv --trend linear", "pso-svr", "cv", True),
)


def simulated_run(profile: str, seed: int, rate_hz: float) -> Run:
    sim = simulate(builtin(profile), rate_hz, seed)
    digest = hashlib.sha256(sim.rate_dph.tobytes()).hexdigest()
    return Run(f"{profile}.csv", sim.t_s, sim.rate_dph, sim.temp_c, rate_hz, digest, {"true_error_dph": sim.true_error_dph})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rate-hz", type=float, default=200.0)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--quick", action="store_true", help="PSO 20 x 20 instead of the paper's 60 x 100")
    args = parser.parse_args()

    calibration = [simulated_run(name, args.seed + i, args.rate_hz) for i, name in enumerate(CALIBRATION)]
    held_out = [simulated_run(name, args.seed + 100 + i, args.rate_hz) for i, name in enumerate(HELD_OUT)]
    size = (20, 20) if args.quick else (60, 100)
    config = TrainConfig()
    prepared = prepare(calibration, config)

    ratios: dict[str, list[float]] = {}
    rmse: dict[str, list[float]] = {}
    best: list[float] = []
    before: list[float] = []
    for label, method, fitness, trend in SCHEMES:
        config.method = method
        config.fit = FitOptions(
            particles=size[0], iterations=size[1], fitness=fitness, trend=trend, n_jobs=args.jobs, seed=args.seed,
            progress=False,
        )  # fmt: skip
        started = time.perf_counter()
        trained = train(calibration, config, prepared)
        seconds = time.perf_counter() - started
        print(f"# {label}: trained in {seconds:.1f} s, {trained.fitted.hyperparameters}", flush=True)
        for run in held_out:
            table = replay_table(run, replay(trained.model, run), config.block_s)
            ratios.setdefault(label, []).append(table.after.rmse_dph / table.best.rmse_dph)
            rmse.setdefault(label, []).append(table.after.rmse_dph)
            if len(best) < len(held_out):
                best.append(table.best.rmse_dph)
                before.append(table.before.rmse_dph)

    print(f"\nCalibration: {' + '.join(CALIBRATION)} at {args.rate_hz:g} Hz; PSO {size[0]} x {size[1]}; seed {args.seed}.")
    print("RMSE of 100 s block means after compensation, as a multiple of the best possible (1.00 = perfect);")
    print("the last column is the mean over the held-out runs.\n")
    print("| Scheme | " + " | ".join(HELD_OUT) + " | mean |")
    print("|---|" + "---:|" * (len(HELD_OUT) + 1))
    print("| Before compensation | " + " | ".join(f"{b / o:.2f}" for b, o in zip(before, best)) + f" | {np.mean(np.array(before) / best):.2f} |")
    for label, values in ratios.items():
        print(f"| {label} | " + " | ".join(f"{v:.2f}" for v in values) + f" | {np.mean(values):.2f} |")
    print("| Best possible, RMSE in deg/h | " + " | ".join(f"{b:.2e}" for b in best) + " | |")


if __name__ == "__main__":
    main()
