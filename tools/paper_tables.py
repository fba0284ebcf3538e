"""The paper's tables 3 and 4 reproduced with its own recipe, on a gyro like its own.

Simulates a navigation-grade gyro (fogd-sim --noise navigation: thermal error 30-100x the noise floor, as
the paper's 0.081 deg/h error against its 4.3e-4 deg/h residual) through the paper's heating run (-15 to 50
C, section 4.1) and its real-time test run (0 to 30 C, section 4.2), fits the paper's three models with the
paper's settings on the heating run alone (inputs T and the eq. 16 rate; 5th-order least squares; an
L1-regularised RBF network; an RBF SVR whose C, epsilon, sigma a 60 x 100 swarm with c1 = c2 = 2 tunes on
the training RMSE, no trend), and prints table 3 (in-sample RMSE and maximum error of 100 s block means,
and the share of the error removed) and table 4 (the test run, block means about its own mean).

    python tools/paper_tables.py            # the paper's swarm, a few minutes on 2 cores
    python tools/paper_tables.py --quick    # a 20 x 20 swarm
"""

from __future__ import annotations

import argparse
import hashlib

from fogd.calibration.models import FitOptions
from fogd.calibration.replay import replay, replay_table
from fogd.calibration.training import TrainConfig, prepare, train
from fogd.core.errorstats import ErrorStats
from fogd.core.inputs import default_inputs
from fogd.core.runio import Run
from fogd.simulation.profiles import builtin
from fogd.simulation.simulator import params_for, simulate

METHODS = (("5th-order LS", "ls-poly"), ("RBF-NN (L1)", "rbf-nn"), ("PSO-SVR", "pso-svr"))


def simulated_run(profile: str, seed: int, rate_hz: float, params) -> Run:
    sim = simulate(builtin(profile), rate_hz, seed, params)
    digest = hashlib.sha256(sim.rate_dph.tobytes()).hexdigest()
    return Run(f"{profile}.csv", sim.t_s, sim.rate_dph, sim.temp_c, rate_hz, digest, {"true_error_dph": sim.true_error_dph})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rate-hz", type=float, default=10.0, help="simulated gyro rate, Hz (default 10)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--thermal", choices=("lumped", "diffusive"), default="lumped")
    parser.add_argument("--quick", action="store_true", help="a 20 x 20 swarm instead of the paper's 60 x 100")
    args = parser.parse_args()
    params = params_for("navigation", args.thermal)
    heating = simulated_run("paper-train", args.seed, args.rate_hz, params)
    test = simulated_run("paper-test", args.seed + 1, args.rate_hz, params)
    swarm = (20, 20) if args.quick else (60, 100)
    options = FitOptions(particles=swarm[0], iterations=swarm[1], c1=2.0, c2=2.0, fitness="train", trend="none",
                         n_jobs=args.jobs, seed=args.seed, progress=False)  # fmt: skip
    config = TrainConfig(inputs=default_inputs(), fit=options, domain_guard=False)
    prepared = prepare([heating], config)
    trained = {}
    for label, method in METHODS:
        config.method = method
        trained[label] = train([heating], config, prepared)
    before = next(iter(trained.values())).before
    print(f"Navigation-grade gyro ({args.thermal} coil), paper-train heating run at {args.rate_hz:g} Hz, seed {args.seed}; "
          f"inputs T and eq. 16 rate; PSO {swarm[0]} x {swarm[1]}, c1 = c2 = 2, training-RMSE fitness, no trend\n")
    print("Table 3: fit on the heating run (100 s block means)\n")
    print("| Model | RMSE (deg/h) | max error (deg/h) | error removed |")
    print("|---|---:|---:|---:|")
    print(f"| Before compensation | {before.rmse_dph:.3e} | {before.max_dph:.3e} | |")
    for label, model in trained.items():
        after: ErrorStats = model.after
        print(f"| {label} | {after.rmse_dph:.3e} | {after.max_dph:.3e} | {100 * (1 - after.rmse_dph / before.rmse_dph):.1f} % |")
    print("\nTable 4: the 0-30 C test run, not used for training (block means about the run's mean, after 600 s)\n")
    print("| Model | RMSE (deg/h) | max error (deg/h) | error removed |")
    print("|---|---:|---:|---:|")
    tables = {label: replay_table(test, replay(model.model, test), 100.0) for label, model in trained.items()}
    first = next(iter(tables.values()))
    print(f"| Before compensation | {first.before.rmse_dph:.3e} | {first.before.max_dph:.3e} | |")
    for label, table in tables.items():
        print(f"| {label} | {table.after.rmse_dph:.3e} | {table.after.max_dph:.3e} | "
              f"{100 * (1 - table.after.rmse_dph / first.before.rmse_dph):.1f} % |")
    print(f"| Best possible (true error removed) | {first.best.rmse_dph:.3e} | {first.best.max_dph:.3e} | "
          f"{100 * (1 - first.best.rmse_dph / first.before.rmse_dph):.1f} % |")


if __name__ == "__main__":
    main()
