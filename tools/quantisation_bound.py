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
"""

from __future__ import annotations

import argparse

import numpy as np

from fogd.calibration.replay import block_grid
from fogd.core.columns import BLOCK_S
from fogd.core.errorstats import detrended_stats
from fogd.core.runio import Run
from fogd.simulation.profiles import builtin
from fogd.simulation.simulator import params_for, simulate

HELD_OUT = ("paper-test", "cool-40-to-0", "fast-ramp", "soak-after-ramp", "fast-cycle")  # as accuracy_table.py
THERMALS = ("lumped", "diffusive")


def ramp_starts_s(profile_name: str) -> list[float]:
    """Times at which the setpoint starts to move after holding still."""
    profile = builtin(profile_name)
    targets = [profile.start_c] + [target for _, target in profile.segments]
    knots_s = np.cumsum([0.0] + [duration for duration, _ in profile.segments])
    return [float(knots_s[k]) for k in range(1, len(targets) - 1)
            if targets[k] == targets[k - 1] and targets[k + 1] != targets[k]]  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--resolution-c", type=float, default=1.0, help="sensor resolution, C (default 1: a KVH)")
    parser.add_argument("--sensor-hz", type=float, default=1.0, help="sensor report rate, Hz (default 1)")
    parser.add_argument("--rate-hz", type=float, default=10.0, help="simulated gyro rate, Hz (default 10)")
    parser.add_argument("--seed", type=int, default=1, help="seed of the first held-out run, +100 as accuracy_table.py")
    args = parser.parse_args()
    print(f"# sensor {args.resolution_c:g} C at {args.sensor_hz:g} Hz; navigation-grade gyro, {args.rate_hz:g} Hz\n")
    print("| coil | run | ramp starts at | reading blind for | true error moved | x noise floor |")
    print("|---|---|---:|---:|---:|---:|")
    bounds: dict[str, list[float]] = {}
    for thermal in THERMALS:
        params = params_for("navigation", thermal, sensor_resolution_c=args.resolution_c, sensor_rate_hz=args.sensor_hz)
        for number, name in enumerate(HELD_OUT):
            run = simulate(builtin(name), args.rate_hz, args.seed + 100 + number, params)
            # the accuracy table's metric on its grid: 100 s block means after the settling, about their mean
            grid = block_grid(Run(name, run.t_s, run.rate_dph, run.temp_c, args.rate_hz, "", {}),
                              np.zeros(run.t_s.size, dtype=np.uint16), BLOCK_S)  # fmt: skip
            drift = lambda values: detrended_stats(grid.means(values)).rmse_dph  # noqa: E731
            floor = drift(run.rate_dph - run.true_error_dph)
            ideal = run.true_error_dph.copy()
            for start_s in ramp_starts_s(name):
                first = int(start_s * args.rate_hz)
                changed = np.flatnonzero(run.temp_c[first:] != run.temp_c[first])
                last = first + (int(changed[0]) if changed.size else run.temp_c.size - first)
                moved = run.true_error_dph[first:last] - run.true_error_dph[first]
                ideal[first:last] -= moved / 2.0  # the minimax guess between "still soaking" and "ramping"
                worst = float(np.max(np.abs(moved))) if moved.size else 0.0
                print(f"| {thermal} | {name} | {start_s:.0f} s | {(last - first) / args.rate_hz:.0f} s | "
                      f"{worst * 1e3:.1f} mdeg/h | {worst / floor:.1f} |")  # fmt: skip
            bounds.setdefault(thermal, []).append(drift(run.rate_dph - ideal) / floor)
    print("\nLower bound on held-out drift / noise floor (" + ", ".join(HELD_OUT) + "):")
    for thermal, values in bounds.items():
        print(f"  {thermal:9s} " + " / ".join(f"{value:.2f}" for value in values) + f"   (worst {max(values):.2f})")


if __name__ == "__main__":
    main()
