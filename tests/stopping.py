"""Stopping a daemon subprocess the way systemd does, for the end-to-end tests: SIGTERM, and if it hangs,
SIGABRT, which fogd answers (faulthandler) by writing every thread's stack to its stderr, so a test that fails
on a hung stop says where each thread was. A hang is judged on progress, not on the clock: no CPU used for
`timeout_s` (blocked for good), or more than CPU_BUDGET_S used since the SIGTERM (spinning), so a loaded
machine only makes the stop slower. How prompt a stop was is the time the daemon slept in it, not the clock's."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from collections.abc import Callable

from progress import cpu_ticks

ABORT_WAIT_S = 5.0
MIN_STALL_S = 30.0  # longer than any wait of fogd's own at stop (a stuck output's write timeout)
CPU_BUDGET_S = 30.0  # a stop takes well under a CPU second: this much is a loop that never ends
TICK_S = 1.0 / os.sysconf("SC_CLK_TCK")


def schedstat_s(pid: int) -> float:
    """Seconds a process's main thread has run or waited for a CPU (/proc/PID/schedstat; readable until reaped)."""
    try:
        with open(f"/proc/{pid}/schedstat") as file:
            run_ns, runqueue_ns = file.read().split()[:2]
    except (OSError, ValueError):
        return 0.0
    return (int(run_ns) + int(runqueue_ns)) / 1e9


def exited(process: subprocess.Popen) -> bool:
    """Whether `process` has exited, leaving it unreaped (its /proc entry stays readable)."""
    if process.returncode is not None:
        return True
    return os.waitid(os.P_PID, process.pid, os.WEXITED | os.WNOWAIT | os.WNOHANG) is not None


def stop_timed(process: subprocess.Popen, stderr: Callable[[], str], timeout_s: float = 10.0) -> tuple[int, float]:
    """SIGTERM `process`; its exit status and the seconds its main thread slept between the signal and its exit
    (neither running nor waiting for a CPU: what a stop waiting on a timeout costs, whatever the load). An
    AssertionError with its stderr (the threads' stacks) when, still running, it has used no CPU for
    `timeout_s` (at least MIN_STALL_S), or CPU_BUDGET_S in all."""
    stall_s = max(timeout_s, MIN_STALL_S)
    process.send_signal(signal.SIGTERM)
    signalled_s, scheduled_s = time.monotonic(), schedstat_s(process.pid)
    start = last = cpu_ticks(process.pid)
    since = signalled_s
    while not exited(process):
        time.sleep(0.02)
        ticks = cpu_ticks(process.pid)
        if ticks != last:
            last, since = ticks, time.monotonic()
        if time.monotonic() - since > stall_s or (ticks - start) * TICK_S > CPU_BUDGET_S:
            break
    else:
        slept_s = time.monotonic() - signalled_s - (schedstat_s(process.pid) - scheduled_s)
        return process.wait(), max(0.0, slept_s)
    process.send_signal(signal.SIGABRT)
    try:
        process.wait(ABORT_WAIT_S)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()
    used_s = (last - start) * TICK_S
    raise AssertionError(f"still running after SIGTERM ({used_s:.1f} CPU s since, none for the last "
                         f"{time.monotonic() - since:.0f} s); stacks and log:\n{stderr()[-8000:]}")  # fmt: skip


def stop(process: subprocess.Popen, stderr: Callable[[], str], timeout_s: float = 10.0) -> int:
    """SIGTERM `process` and return its exit status (see stop_timed)."""
    return stop_timed(process, stderr, timeout_s)[0]
