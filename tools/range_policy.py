"""Outside the calibrated range: what fogd-train's default leaves on runs that leave it, under each policy the
model file can hold today.

Trains on two runs over a narrow span (5 -> 35 C heating and 35 -> 5 C cooling, 24 C/h, 2.25 h each) and replays
three runs with other seeds: paper-train (-15 -> 50 C) and cooling (50 -> -10 C), which leave the span, and
paper-test (0 -> 30 C), nearly inside it. Policies: `clamp` (the default: inputs clamped to the calibrated range
and flagged CLAMPED), `guard` (`--domain-guard`: beyond the range by a margin, the linear fit on the same inputs,
flagged OUT_OF_DOMAIN), and `linear` (IEEE 952's linear model, clamped likewise). Both sensors: fine (0.0625 C)
and whole degrees. Each cell is the std of 100 s block means after compensation as a multiple of the noise floor
(the same run with its true thermal error removed), and the share of samples flagged.

    python tools/range_policy.py [--rate-hz 2]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from bench_common import machine, print_table

from fogd.calibration.replay import replay, replay_table
from fogd.core import modelfile
from fogd.core.flags import Flag
from fogd.core.runio import read_run

BIN = Path(sys.executable).parent
NARROW = {"heat": [[1800, 5], [4500, 35], [1800, 35]], "cool": [[1800, 35], [4500, 5], [1800, 5]]}
HELD_OUT = {"paper-train": 3, "cooling": 4, "paper-test": 5}
POLICIES = {"clamp": (), "guard": ("--domain-guard",), "linear": ("--method", "linear", "--inputs", "paper")}


def tool(name: str) -> str:
    return str(BIN / name)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rate-hz", type=float, default=2.0)
    args = parser.parse_args(argv)
    print(machine(), flush=True)
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for sensor, options in (("fine", ()), ("whole", ("--sensor-resolution-c", "1"))):
            sim = [tool("fogd-sim"), "--rate-hz", f"{args.rate_hz:g}", "--noise", "navigation", *options]
            train_runs = []
            for seed, (name, segments) in enumerate(NARROW.items(), start=1):
                profile = Path(folder, f"{name}.yaml")
                profile.write_text("".join(f"- [{d}, {t}]\n" for d, t in segments))
                train_runs.append(os.path.join(folder, f"{sensor}-{name}.csv"))
                subprocess.run([*sim, "--profile", str(profile), "--seed", str(seed), "-o", train_runs[-1]], check=True,
                               stderr=subprocess.DEVNULL)  # fmt: skip
            held = {}
            for name, seed in HELD_OUT.items():
                held[name] = os.path.join(folder, f"{sensor}-{name}.csv")
                subprocess.run([*sim, "--profile", name, "--seed", str(seed), "-o", held[name]], check=True,
                               stderr=subprocess.DEVNULL)  # fmt: skip
            for policy, extra in POLICIES.items():
                model_path = os.path.join(folder, f"{sensor}-{policy}.json")
                subprocess.run([tool("fogd-train"), *train_runs, "-o", model_path, "-q", "--force", *extra], check=True,
                               capture_output=True)  # fmt: skip
                model = modelfile.load(model_path)
                cells = []
                for name, path in held.items():
                    run = read_run(path)
                    result = replay(model, run)
                    table = replay_table(run, result, 100.0)
                    flagged = ((result.flags & int(Flag.CLAMPED | Flag.OUT_OF_DOMAIN)) != 0).mean()
                    cells.append(f"{table.after.rmse_dph / table.best.rmse_dph:.2f}x ({100 * flagged:.0f} %)")
                rows.append([sensor, policy, model.method, *cells])
                print(f"{sensor} {policy}: {' | '.join(cells)}", flush=True)
    print_table("Outside the calibrated range: held-out drift / noise floor (share of samples flagged)",
                ["sensor", "policy", "model", *HELD_OUT], rows)  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
