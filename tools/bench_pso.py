"""Wall time of PSO-SVR with the paper's swarm (table 1: 60 particles x 100 iterations) on synthetic block rows.

One chamber sweep -15 -> 50 C with a wobble, error = a smooth nonlinear function of T and dT/dt plus noise,
so the one-run case uses time folds. Usage: .venv/bin/python tools/bench_pso.py [--rows 150 300] [--jobs 1 2]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from fogd.models import FitOptions, fit


def chamber_blocks(rows: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    t_s = np.linspace(0.0, 6.5 * 3600.0, rows)
    temp_c = -15.0 + 65.0 * t_s / t_s[-1] + 3.0 * np.sin(2.0 * np.pi * t_s / 3000.0)
    rate_cps = np.gradient(temp_c, t_s)
    error_dph = 0.08 * np.tanh((temp_c - 15.0) / 25.0) + 15.0 * rate_cps + rng.normal(0.0, 0.002, rows)
    return np.c_[temp_c, rate_cps], error_dph, np.zeros(rows, int)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, nargs="+", default=[150, 300])
    parser.add_argument("--jobs", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--fitness", nargs="+", default=["train", "cv"])
    parser.add_argument("--particles", type=int, default=60)
    parser.add_argument("--iterations", type=int, default=100)
    args = parser.parse_args()
    print("rows fitness n_jobs wall_s best_dph cv_rmse_dph C epsilon sigma")
    for rows in args.rows:
        x, y, groups = chamber_blocks(rows)
        for fitness in args.fitness:
            for jobs in args.jobs:
                options = FitOptions(particles=args.particles, iterations=args.iterations, fitness=fitness, n_jobs=jobs, progress=False)
                start = time.perf_counter()
                fitted = fit("pso-svr", x, y, groups, options)
                wall_s = time.perf_counter() - start
                h = fitted.hyperparameters
                print(
                    f"{rows} {fitness} {jobs} {wall_s:.1f} {fitted.fitness_history[-1]:.3e} {fitted.cv_rmse_dph:.3e} "
                    f"{h['C']:.3g} {h['epsilon']:.3g} {h['sigma']:.3g}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
