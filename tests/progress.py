"""Waiting in the end-to-end tests on progress, not on the clock: a wait fails when nothing it watches has moved
for `STALL_S` (a file that stopped growing, a process that stopped using CPU: a hang), however long the whole
wait took, so a loaded machine makes a test slower, never wrong. A process that spins forever is left to
pytest-timeout (pyproject.toml)."""

from __future__ import annotations

import os
import subprocess
import time
from collections.abc import Callable, Iterable
from pathlib import Path

STALL_S = 120.0  # nothing watched moved for this long: a hang, not a slow machine
POLL_S = 0.05


def cpu_ticks(pid: int) -> int:
    """CPU time a process has used so far, in clock ticks (utime + stime in /proc/PID/stat); 0 once it is gone."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as file:
            stat = file.read()
    except OSError:
        return 0
    fields = stat[stat.rindex(b")") + 2 :].split()
    return int(fields[11]) + int(fields[12])


def size(path: Path | str) -> int:
    try:
        return os.stat(path).st_size
    except OSError:
        return -1


def watching(files: Iterable[Path | str] = (), processes: Iterable[subprocess.Popen] = ()) -> Callable[[], tuple]:
    """Progress as the sizes of `files` and the CPU time of `processes`."""
    files, processes = list(files), list(processes)
    return lambda: (*(size(path) for path in files), *(cpu_ticks(process.pid) for process in processes))


def wait_until(done: Callable[[], bool], progress: Callable[[], object], what: str, stall_s: float = STALL_S,
               alive: Iterable[subprocess.Popen] = (), said: Callable[[], str] = lambda: "") -> None:  # fmt: skip
    """Return once `done()`; AssertionError naming `what` (and `said()`, e.g. a log) when `progress()` has not
    changed for `stall_s`, or when a process in `alive` has exited first."""
    alive = list(alive)
    last, since = progress(), time.monotonic()
    while not done():
        for process in alive:
            assert process.poll() is None, f"{what}: {process.args[:3]} exited ({process.returncode}) first\n{said()}"
        time.sleep(POLL_S)
        now = progress()
        if now != last:
            last, since = now, time.monotonic()
        else:
            assert time.monotonic() - since < stall_s, f"{what}: no progress in {stall_s:g} s ({now})\n{said()}"


def wait_for_exit(process: subprocess.Popen, what: str, stall_s: float = STALL_S, watch: Callable[[], tuple] = tuple,
                  said: Callable[[], str] = lambda: "") -> int:  # fmt: skip
    """`process`'s exit status once it ends by itself, while it (or `watch`) makes progress."""
    progress = watching(processes=[process])
    wait_until(lambda: process.poll() is not None, lambda: (progress(), watch()), what, stall_s, said=said)
    return process.wait()
