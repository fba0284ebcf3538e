"""How well can any causal compensator do with a whole-degree temperature? A lower bound on the held-out runs.

After a soak, the chamber starts to move and the gyro's thermal error follows the housing at once, but a
sensor that reports whole degrees shows nothing until the housing has moved half a degree. Until that first
change, the readings of "the soak went on" and "a ramp began" are the same, so no compensator that sees only
the readings (and the past) can tell them apart: on one of the two histories it errs by at least half of what
the true error moved in that blind window. This tool simulates `tools/accuracy_table.py`'s held-out runs
with a whole-degree sensor and prints, for each start of a ramp after a soak, how long the reading stayed
blind and how far the true error moved meanwhile; then the accuracy table's metric (std of 100 s block means
after 600 s over the noise floor) for an ideal compensator that is exact everywhere except that half-error
in each blind window. A compensator that scores below it on one of these runs scores above it on the same
run with its soak held longer (the same readings until the first change): no model is below it on both.

    python tools/quantisation_bound.py                   # whole degrees at 1 Hz, both coil structures
    python tools/quantisation_bound.py --resolution-c 0.0625 --sensor-hz 4   # a fine sensor, for contrast
    python tools/quantisation_bound.py --hindsight       # and the default fitted on the held-out runs too

`--hindsight` separates the two gaps between the default and the bound: fogd-train's default trained on the
calibration runs and on the held-out runs themselves shows what its inputs can carry when the fit has seen
every history; what is left above the bound then is the inputs' (the dequantised estimate's), not the fit's.
"""

from __future__ import annotations

import argparse

import numpy as np

from fogd.calibration.replay import block_grid
from fogd.core.columns import BLOCK_S, TRUE_ERROR_COLUMN
from fogd.core.errorstats import detrended_stats
from fogd.core.runio import Run
from fogd.simulation.profiles import builtin
from fogd.simulation.simulator import params_for, simulate

CALIBRATION = ("paper-train", "cooling", "cycle")  # as accuracy_table.py
HELD_OUT = ("paper-test", "cool-40-to-0", "fast-ramp", "soak-after-ramp", "fast-cycle")
THERMALS = ("lumped", "diffusive")


def ramp_starts_s(profile_name: str) -> list[float]:
    """Times at which the setpoint starts to move after holding still."""
    profile = builtin(profile_name)
    targets = [profile.start_c] + [target for _, target in profile.segments]
    knots_s = np.cumsum([0.0] + [duration for duration, _ in profile.segments])
    return [float(knots_s[k]) for k in range(1, len(targets) - 1)
            if targets[k] == targets[k - 1] and targets[k + 1] != targets[k]]  # fmt: skip


def run_bounds(thermal: str, resolution_c: float, sensor_hz: float, rate_hz: float, seed: int,
               rows: list[str] | None = None, **overrides: float) -> list[float]:
    """The bound (drift / noise floor of the ideal compensator) on each of HELD_OUT, simulated as
    `tools/accuracy_table.py` simulates them; a table row per blind window is appended to `rows` if given."""
    params = params_for("navigation", thermal, sensor_resolution_c=resolution_c, sensor_rate_hz=sensor_hz, **overrides)
    bounds = []
    for number, name in enumerate(HELD_OUT):
        run = simulate(builtin(name), rate_hz, seed + 100 + number, params)
        # the accuracy table's metric on its grid: 100 s block means after the settling, about their mean
        grid = block_grid(Run(name, run.t_s, run.rate_dph, run.temp_c, rate_hz, "", {}),
                          np.zeros(run.t_s.size, dtype=np.uint16), BLOCK_S)  # fmt: skip

        def drift(values: np.ndarray, grid=grid) -> float:
            return detrended_stats(grid.means(values)).rmse_dph

        floor = drift(run.rate_dph - run.true_error_dph)
        ideal = run.true_error_dph.copy()
        for start_s in ramp_starts_s(name):
            first = int(start_s * rate_hz)
            changed = np.flatnonzero(run.temp_c[first:] != run.temp_c[first])
            last = first + (int(changed[0]) if changed.size else run.temp_c.size - first)
            moved = run.true_error_dph[first:last] - run.true_error_dph[first]
            ideal[first:last] -= moved / 2.0  # the minimax guess between "still soaking" and "ramping"
            worst = float(np.max(np.abs(moved))) if moved.size else 0.0
            if rows is not None:
                rows.append(f"| {thermal} | {name} | {start_s:.0f} s | {(last - first) / rate_hz:.0f} s | "
                            f"{worst * 1e3:.1f} mdeg/h | {worst / floor:.1f} |")  # fmt: skip
        bounds.append(drift(run.rate_dph - ideal) / floor)
    return bounds


def hindsight_fit(thermal: str, resolution_c: float, sensor_hz: float, rate_hz: float, seed: int) -> list[float]:
    """fogd-train's default (its inputs dequantised for a coarse sensor, PSO 10 x 10) trained on the accuracy
    table's calibration runs and on the held-out runs themselves, then replayed on the held-out runs: what the
    default's inputs can carry of the error when the fit has seen every history. Where it stays far above the
    bound, the inputs (the dequantised estimate), not the choice of calibration runs, hold the run there."""
    from fogd.calibration.models import FitOptions
    from fogd.calibration.replay import replay, replay_table
    from fogd.calibration.training import TrainConfig, train

    params = params_for("navigation", thermal, sensor_resolution_c=resolution_c, sensor_rate_hz=sensor_hz)
    named = [(name, seed + i) for i, name in enumerate(CALIBRATION)] + [(name, seed + 100 + i) for i, name in enumerate(HELD_OUT)]
    runs = []
    for name, run_seed in named:
        sim = simulate(builtin(name), rate_hz, run_seed, params)
        runs.append(Run(f"{name}.csv", sim.t_s, sim.rate_dph, sim.temp_c, rate_hz, f"{name}-{run_seed}",
                        {TRUE_ERROR_COLUMN: sim.true_error_dph}))  # fmt: skip
    options = FitOptions(particles=10, iterations=10, n_jobs=1, seed=seed, progress=False)
    trained = train(runs, TrainConfig(fit=options))
    tables = [replay_table(run, replay(trained.model, run), BLOCK_S) for run in runs[len(CALIBRATION):]]
    return [table.after.rmse_dph / table.best.rmse_dph for table in tables]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--resolution-c", type=float, default=1.0, help="sensor resolution, C (default 1: a KVH)")
    parser.add_argument("--sensor-hz", type=float, default=1.0, help="sensor report rate, Hz (default 1)")
    parser.add_argument("--rate-hz", type=float, default=10.0, help="simulated gyro rate, Hz (default 10)")
    parser.add_argument("--seed", type=int, default=1, help="seed of the first held-out run, +100 as accuracy_table.py")
    parser.add_argument("--hindsight", action="store_true",
                        help="also fogd-train's default fitted on the held-out runs themselves (hindsight_fit; ~1 min)")
    args = parser.parse_args()
    print(f"# sensor {args.resolution_c:g} C at {args.sensor_hz:g} Hz; navigation-grade gyro, {args.rate_hz:g} Hz\n")
    rows: list[str] = []
    bounds = {thermal: run_bounds(thermal, args.resolution_c, args.sensor_hz, args.rate_hz, args.seed, rows)
              for thermal in THERMALS}  # fmt: skip
    print("| coil | run | ramp starts at | reading blind for | true error moved | x noise floor |")
    print("|---|---|---:|---:|---:|---:|")
    print("\n".join(rows))
    print("\nLower bound on held-out drift / noise floor (" + ", ".join(HELD_OUT) + "):")
    for thermal, values in bounds.items():
        print(f"  {thermal:9s} " + " / ".join(f"{value:.2f}" for value in values) + f"   (worst {max(values):.2f})")
    if args.hindsight:
        print("\nfogd-train's default fitted with hindsight (calibration and held-out runs), on the held-out runs:")
        for thermal in THERMALS:
            values = hindsight_fit(thermal, args.resolution_c, args.sensor_hz, args.rate_hz, args.seed)
            print(f"  {thermal:9s} " + " / ".join(f"{value:.2f}" for value in values) + f"   [hindsight worst {max(values):.2f}]",
                  flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
