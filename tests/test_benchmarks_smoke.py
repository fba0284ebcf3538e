"""Every benchmark in tools/ still runs, in its tiny --quick mode. No timing is asserted: the numbers of a
quick run on a shared machine mean nothing; the benchmarks themselves are what show speed."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

TOOLS = Path(__file__).resolve().parent.parent / "tools"


@pytest.mark.parametrize(
    "script, table",
    [
        ("bench_point.py", "1. Per-point compensation cost"),
        ("bench_replay.py", "2a. Replay compensation"),
        ("bench_daemon.py", "3b-d. Latency"),
        ("bench_train.py", "4. Training wall time"),
    ],
)
def test_benchmark_runs_in_quick_mode(script, table):
    done = subprocess.run(
        [sys.executable, "-W", "ignore", str(TOOLS / script), "--quick"], capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert table in done.stdout
    assert "Traceback" not in done.stderr


def test_bench_runs_the_sections_it_is_given():
    done = subprocess.run(
        [sys.executable, str(TOOLS / "bench.py"), "--quick", "--only", "point"], capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert "1. Per-point compensation cost" in done.stdout and "== point: ok" in done.stdout
