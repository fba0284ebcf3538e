"""Training: wall time of `fogd-train --method pso-svr` with the paper's swarm (table 1: 60 particles x 100
iterations) on a 4-hour 200 Hz run made by `fogd-sim --profile cooling`, with --jobs 1 and 2 and both
fitnesses (train: the paper's RMSE on the training blocks; cv: held-out time folds), and what the swarm buys:
the same budget of SVR evaluations (particles x iterations) spent by random search in the same log10 box.

Targets: under 2 minutes with the paper's fitness (train), under 10 minutes with cv.
This replaces tools/bench_pso.py (synthetic block rows): here the rows come from the real CLI's input.

Usage: python tools/bench_train.py [--quick] [--jobs 1 2] [--fitness train cv]
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from bench_common import machine, print_table, verdict
from joblib import Parallel, delayed

from fogd.calibration.models.folds import folds
from fogd.calibration.models.svr import LOG10_LOWER, LOG10_UPPER, svr_fitness
from fogd.calibration.training import TrainConfig, prepare
from fogd.core.inputs import default_inputs
from fogd.core.runio import read_run

BIN = Path(sys.executable).parent
TARGET_S = {"train": 120.0, "cv": 600.0}


def fogd_command(name: str) -> list[str]:
    """The installed console script next to this Python, else the module."""
    script = BIN / name
    module = {"fogd-sim": "fogd.cli.sim", "fogd-train": "fogd.cli.train"}[name]
    return [str(script)] if script.exists() else [sys.executable, "-m", module]


def make_run(folder: str, rate_hz: float) -> str:
    path = os.path.join(folder, "cooling.csv")
    subprocess.run([*fogd_command("fogd-sim"), "--profile", "cooling", "--rate-hz", f"{rate_hz:g}", "-o", path], check=True,
                   stderr=subprocess.DEVNULL)  # fmt: skip
    return path


def train_once(run_path: str, folder: str, fitness: str, jobs: int, particles: int, iterations: int) -> tuple[float, dict]:
    model_path = os.path.join(folder, f"model-{fitness}-{jobs}.json")
    # the paper's inputs and the trend the timings were first measured with; --force: a single run with the train
    # fitness may well be refused as worse than no compensation, and this measures time, not accuracy
    command = [*fogd_command("fogd-train"), run_path, "--method", "pso-svr", "--fitness", fitness, "--jobs", str(jobs),
               "--particles", str(particles), "--iterations", str(iterations), "--inputs", "paper", "--trend", "linear",
               "--force", "-o", model_path, "-q"]  # fmt: skip
    start = time.perf_counter()
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall_s = time.perf_counter() - start
    return wall_s, json.loads(Path(model_path).read_text())


def random_search(run_path: str, fitness: str, evaluations: int, jobs: int, seed: int = 0) -> tuple[float, float]:
    """Best fitness (deg/h) of `evaluations` uniform draws in PSO's log10 box, scored as fogd-train scores."""
    config = TrainConfig(method="pso-svr", inputs=default_inputs())
    data, reference = prepare([read_run(run_path)], config)
    x, y = data.x, data.rate_dph - reference
    x_std = x.std(axis=0)
    xs = (x - x.mean(axis=0)) / np.where(x_std > 0, x_std, 1.0)
    y_scale = float(y.std()) or 1.0
    ys = (y - y.mean()) / y_scale
    rows = np.arange(len(ys))
    splits = [(rows, rows)] if fitness == "train" else folds(data.groups, config.fit.folds)
    score = functools.partial(svr_fitness, xs=xs, ys=ys, splits=splits, y_scale=y_scale, trend=True,
                              groups=data.groups)  # the linear trend fogd-train is run with above
    positions = LOG10_LOWER + np.random.default_rng(seed).random((evaluations, LOG10_LOWER.size)) * (LOG10_UPPER - LOG10_LOWER)
    start = time.perf_counter()
    values = np.array(Parallel(n_jobs=jobs)(delayed(score)(row) for row in positions))
    return float(np.min(values)), time.perf_counter() - start


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--strict", action="store_true", help="exit 1 when a target is missed")
    parser.add_argument("--quick", action="store_true", help="a 10 Hz run and a 6x4 swarm (smoke test)")
    parser.add_argument("--jobs", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--fitness", nargs="+", choices=("train", "cv"), default=["train", "cv"])
    parser.add_argument("--particles", type=int, default=None, help="swarm size (default: the paper's 60; quick 6)")
    parser.add_argument("--iterations", type=int, default=None, help="PSO iterations (default: the paper's 100; quick 4)")
    args = parser.parse_args(argv)
    rate_hz, (particles, iterations) = (10.0, (6, 4)) if args.quick else (200.0, (60, 100))
    particles, iterations = args.particles or particles, args.iterations or iterations
    paper = (particles, iterations) == (60, 100)
    print(machine())
    rows, ok = [], True
    with tempfile.TemporaryDirectory() as folder:
        start = time.perf_counter()
        run_path = make_run(folder, rate_hz)
        print(f"fogd-sim --profile cooling (4 h) at {rate_hz:g} Hz: {os.path.getsize(run_path) / 1e6:.0f} MB in "
              f"{time.perf_counter() - start:.0f} s; PSO {particles} x {iterations} = {particles * iterations} SVR "
              f"evaluations per fit")  # fmt: skip
        for fitness in args.fitness:
            best_pso = None
            for jobs in args.jobs:
                wall_s, document = train_once(run_path, folder, fitness, jobs, particles, iterations)
                best_pso = document["training"]["fitness_history_dph"][-1]
                hyper = document["training"]["hyperparameters"]
                good = wall_s < TARGET_S[fitness]
                ok &= good or not paper
                target = f"< {TARGET_S[fitness]:.0f} s: {verdict(good)}" if paper else "(not the paper's swarm)"
                print(f"  fogd-train --fitness {fitness} --jobs {jobs}: {wall_s:.1f} s, best {best_pso:.5f} deg/h", flush=True)
                rows.append([
                    f"fogd-train pso-svr --fitness {fitness} --jobs {jobs}", f"{wall_s:.1f}", f"{best_pso:.5f}",
                    f"C={hyper['C']:.3g} eps={hyper['epsilon']:.3g} sigma={hyper['sigma']:.3g}",
                    target,
                ])  # fmt: skip
            jobs = max(args.jobs)
            best_random, random_s = random_search(run_path, fitness, particles * iterations, jobs)
            print(f"  random search, fitness {fitness}: {random_s:.1f} s, best {best_random:.5f} deg/h", flush=True)
            rows.append([
                f"random search, {particles * iterations} evaluations, fitness {fitness}, {jobs} jobs", f"{random_s:.1f}",
                f"{best_random:.5f}", f"PSO/random best fitness = {best_pso / best_random:.3f}", "-",
            ])  # fmt: skip
    print_table("4. Training wall time (s) and best fitness (deg/h, lower is better)",
                ["what", "wall s", "best fitness dph", "result", "target"], rows)  # fmt: skip
    return 1 if args.strict and not ok else 0


if __name__ == "__main__":
    raise SystemExit(main())
