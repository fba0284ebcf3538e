"""The suite's shared set-up: one BLAS thread per process, and the simulated IMU runs several modules train on,
written once per session (per xdist worker).

pyproject.toml runs the suite on two xdist workers, a file to a worker (`-n 2 --dist loadfile`: a module's
fixtures are built once and its tests may share fixed paths, such as the README's /tmp/fog0); `-n 0` runs it in
one process. OpenBLAS's own threads on top of two workers on two CPUs multiply the CPU time rather than divide
the wall time: an ls-poly fit of tests/test_models_fit.py took 6.9 CPU s with its threads on a loaded 2-CPU
machine, 0.8 with one. The variables are set before numpy loads, so the daemons and commands the tests start
inherit them; threadpoolctl covers a numpy some plugin loaded first."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

BLAS_THREADS = {name: "1" for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
for _name, _value in BLAS_THREADS.items():
    os.environ.setdefault(_name, _value)
if "numpy" in sys.modules:  # loaded before this file: its pool already has its threads
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)


@pytest.fixture(scope="session")
def imu_runs(tmp_path_factory) -> dict[str, Path]:
    """Three simulated IMU chamber runs (tests/imu_runs.py): heating, cooling, and a cycle to check on. Read only:
    a test that changes one copies it first."""
    from imu_runs import write_imu_run

    out = tmp_path_factory.mktemp("imu-runs")
    return {
        "heat": write_imu_run(out / "heat.csv", "fast-ramp", 1),
        "cool": write_imu_run(out / "cool.csv", "cool-40-to-0", 2),
        "check": write_imu_run(out / "check.csv", "fast-cycle", 3),
    }
