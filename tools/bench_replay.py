"""Replay throughput: fogd-replay's compensation of a 10^6-row run, and its CSV reading against numpy's reader.

  - compensation: `fogd.calibration.replay.replay()` (the daemon's compensator, chunked) on a run already in memory, per
    model, in rows/s; kernel models are also timed without the exact distinct-row reuse in fogd.core.frozen
    (every row evaluated), the baseline it is measured against. Target: > 10^6 rows/s.
  - reading: `fogd.core.runio.read_run` (numpy's C reader plus fogd's checks and the file's sha256) against
    `np.loadtxt` on the same file alone, and pandas.read_csv if pandas happens to be installed. Target:
    read_run not slower than np.loadtxt (ratio <= 1, within the noise of a shared machine).

Usage: python tools/bench_replay.py [--quick] [--rows N]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

import numpy as np
from bench_common import (
    best_time,
    machine,
    print_table,
    sim_run,
    trained_model,
    verdict,
)

import fogd.core.frozen as frozen
from fogd.calibration.replay import replay
from fogd.core.runio import read_run, write_csv

METHODS = ("ls-poly", "rbf-nn", "pso-svr")
TARGET_ROWS_S = 1e6


def compensation_rows(run, trained: dict, repeats: int) -> tuple[list[list[object]], bool]:
    rows, ok_all = [], True
    for method, model in trained.items():
        results = {}
        seconds = best_time(lambda: results.setdefault("out", replay(model.model, run)), repeats)
        reference_s, exact = None, ""
        if isinstance(model.model.evaluator, (frozen.Polynomial, frozen.Svr, frozen.RbfNetwork)):
            saved = frozen._UNIQUE_MIN_ROWS
            frozen._UNIQUE_MIN_ROWS = 1 << 62  # every row evaluated: the path before distinct-row reuse
            try:
                plain = {}
                reference_s = best_time(lambda: plain.setdefault("out", replay(model.model, run)), 1)
            finally:
                frozen._UNIQUE_MIN_ROWS = saved
            same = np.array_equal(plain["out"].comp_dph, results["out"].comp_dph)
            exact = "bit-identical" if same else "DIFFERENT"
            ok_all &= same
        distinct = len(frozen.unique_rows(np.column_stack((results["out"].temp_c, results["out"].temp_rate_cps)))[0])
        rate = run.rows / seconds
        ok = rate > TARGET_ROWS_S
        ok_all &= ok
        rows.append([
            method, _size(model), f"{rate / 1e6:.2f}M", f"{run.rows / reference_s / 1e6:.2f}M" if reference_s else "-",
            f"{reference_s / seconds:.1f}x" if reference_s else "-", f"{distinct}", exact or "-", verdict(ok),
        ])  # fmt: skip
    return rows, ok_all


def _size(trained) -> str:
    params = trained.document["params"]
    return {"pso-svr": f"{len(params.get('support_vectors', []))} SVs", "rbf-nn": f"{len(params.get('centres', []))} centres"}.get(
        trained.model.method, f"{len(params.get('coef', []))} terms"
    )


def reading_rows(run, repeats: int) -> tuple[list[list[object]], bool]:
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, "run.csv")
        write_csv(path, {"t_s": run.t_s, "rate_dph": run.rate_dph, "temp_c": run.temp_c},
                  {"t_s": "%.6f", "rate_dph": "%.6f", "temp_c": "%.4f"})  # fmt: skip
        size_mb = os.path.getsize(path) / 1e6
        loadtxt_s = best_time(lambda: np.loadtxt(path, delimiter=",", skiprows=1), repeats)
        read_s = best_time(lambda: read_run(path), repeats)
        rows = [
            ["np.loadtxt (baseline)", f"{loadtxt_s:.2f}", f"{run.rows / loadtxt_s / 1e6:.2f}M", "1.00"],
            ["fogd read_run", f"{read_s:.2f}", f"{run.rows / read_s / 1e6:.2f}M", f"{read_s / loadtxt_s:.2f}"],
        ]
        try:
            import pandas  # noqa: F401  (only if already installed; fogd does not depend on it)
        except ImportError:
            rows.append(["pandas.read_csv", "not installed", "-", "-"])
        else:
            pandas_s = best_time(lambda: pandas.read_csv(path), repeats)
            rows.append(["pandas.read_csv", f"{pandas_s:.2f}", f"{run.rows / pandas_s / 1e6:.2f}M", f"{pandas_s / loadtxt_s:.2f}"])
    print(f"CSV: {run.rows} rows, {size_mb:.1f} MB")
    return rows, read_s <= 1.1 * loadtxt_s


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--strict", action="store_true", help="exit 1 when a target is missed")
    parser.add_argument("--quick", action="store_true", help="a small run and tiny swarm (smoke test)")
    parser.add_argument("--rows", type=int, default=None, help="rows replayed (default 10^6; quick 20000)")
    args = parser.parse_args(argv)
    rows = args.rows or (20_000 if args.quick else 1_000_000)
    repeats = 1 if args.quick else 3
    print(machine())
    calibration = sim_run("cooling", 5.0 if args.quick else 50.0)
    swarm = (4, 3) if args.quick else (20, 20)
    trained = {method: trained_model(calibration, method, particles=swarm[0], iterations=swarm[1]) for method in METHODS}
    run = sim_run("cooling", 200.0, seed=2, rows=rows, start_s=1800.0)  # from half an hour in: the ramp
    print(f"replaying {run.rows} rows of {run.path}; models fitted on {calibration.path} (PSO {swarm[0]}x{swarm[1]}, "
          f"fitness train, plain SVR)")  # fmt: skip
    start = time.perf_counter()
    comp_rows, comp_ok = compensation_rows(run, trained, repeats)
    print_table(
        "2a. Replay compensation (replay() on a run in memory, no CSV I/O), rows/s; target > 1M rows/s",
        ["model", "size", "rows/s", "rows/s, every row evaluated", "speedup", "distinct input rows", "same output", "target"],
        comp_rows,
    )  # fmt: skip
    read_rows, read_ok = reading_rows(run, repeats)
    print_table("2b. CSV reading, seconds; target read_run / np.loadtxt <= 1 (1.1 allowed for noise)",
                ["reader", "seconds", "rows/s", "ratio to np.loadtxt"], read_rows)  # fmt: skip
    print(f"(section 2 took {time.perf_counter() - start:.0f} s)")
    return 1 if args.strict and not (comp_ok and read_ok) else 0


if __name__ == "__main__":
    raise SystemExit(main())
