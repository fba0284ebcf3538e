"""Shared pieces of the benchmarks: the machine description, simulated runs in memory, models trained the way
fogd-train trains them, a timer that takes the best of a few repeats, and the table printer.

Every benchmark reports ratios against a baseline measured in the same process and the same minute: this
machine is shared and noisy, so absolute times move while ratios hold.
"""

from __future__ import annotations

import os
import platform
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # run as `python tools/bench_x.py` from anywhere

from fogd.calibration.models import FitOptions  # noqa: E402
from fogd.calibration.training import TrainConfig, Trained, train  # noqa: E402
from fogd.core.inputs import default_inputs, parse_inputs  # noqa: E402
from fogd.core.runio import Run  # noqa: E402
from fogd.simulation import profiles  # noqa: E402
from fogd.simulation.simulator import Simulation  # noqa: E402


def machine() -> str:
    """nproc, CPU model, Python and numpy versions: the line every table is printed under."""
    cpu = "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return (
        f"machine: {os.cpu_count()} CPUs ({cpu}), Linux {platform.release()}, Python {platform.python_version()}, "
        f"numpy {np.__version__}"
    )


def sim_run(profile: str, rate_hz: float, seed: int = 1, rows: int | None = None, start_s: float = 0.0) -> Run:
    """A fogd-sim run held in memory as a `Run` (`rows` rows from `start_s` if given)."""
    simulation = Simulation(profiles.builtin(profile), rate_hz, seed)
    start = int(round(start_s * rate_hz))
    columns = simulation.columns(start, None if rows is None else start + rows)
    return Run(
        path=f"<sim {profile} {rate_hz:g} Hz>",
        t_s=columns["t_s"],
        rate_dph=columns["rate_dph"],
        temp_c=columns["temp_c"],
        rate_hz=rate_hz,
        sha256="",
        extra={"true_error_dph": columns["true_error_dph"]},
    )


def trained_model(run: Run, method: str, *, particles: int = 20, iterations: int = 20, fitness: str = "train",
                  trend: bool | str = False, seed: int = 0, inputs: str | None = None) -> Trained:  # fmt: skip
    """A model fitted as fogd-train fits it, on the paper's inputs (temperature and its eq. 16 rate) unless
    `inputs` (the --inputs syntax) says otherwise; pso-svr defaults to the paper's plain SVR with its fitness."""
    options = FitOptions(particles=particles, iterations=iterations, fitness=fitness, trend=trend, seed=seed, progress=False)
    specs = default_inputs() if inputs is None else parse_inputs(inputs)
    return train([run], TrainConfig(method=method, inputs=specs, fit=options, name=f"bench-{method}"))


def best_time(function: Callable[[], object], repeats: int = 3) -> float:
    """Seconds of the fastest of `repeats` calls (the least disturbed by other load)."""
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        best = min(best, time.perf_counter() - start)
    return best


def print_table(title: str, header: list[str], rows: list[list[object]]) -> None:
    """A plain aligned table (markdown pipes, so it pastes into the README)."""
    cells = [header] + [[str(cell) for cell in row] for row in rows]
    widths = [max(len(row[i]) for row in cells) for i in range(len(header))]
    print(f"\n{title}")
    for number, row in enumerate(cells):
        print("| " + " | ".join(cell.ljust(width) for cell, width in zip(row, widths)) + " |")
        if number == 0:
            print("|" + "|".join("-" * (width + 2) for width in widths) + "|")
    sys.stdout.flush()


def verdict(ok: bool) -> str:
    return "met" if ok else "MISSED"


def us(seconds: float) -> str:
    return f"{seconds * 1e6:.2f}"
