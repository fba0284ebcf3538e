"""Stopping a daemon subprocess the way systemd does, for the end-to-end tests: SIGTERM, and if it has not
exited in time, SIGABRT, which fogd answers (faulthandler) by writing every thread's stack to its stderr, so
a test that fails on a hung stop says where each thread was."""

from __future__ import annotations

import signal
import subprocess
from collections.abc import Callable

ABORT_WAIT_S = 5.0


def stop(process: subprocess.Popen, stderr: Callable[[], str], timeout_s: float = 10.0) -> int:
    """SIGTERM `process` and return its exit status; AssertionError with its stderr (the threads' stacks)
    when it is still running `timeout_s` later."""
    process.send_signal(signal.SIGTERM)
    try:
        return process.wait(timeout_s)
    except subprocess.TimeoutExpired:
        pass
    process.send_signal(signal.SIGABRT)
    try:
        process.wait(ABORT_WAIT_S)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()
    raise AssertionError(f"still running {timeout_s:g} s after SIGTERM; stacks and log:\n{stderr()[-8000:]}")
