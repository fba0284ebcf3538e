"""Issue 35.11: fogd-record on a full disk crashed with chained tracebacks (exit 1) and left a cut last row that
fogd-replay refused. Now: one line naming the file, exit 74, and the file ends at its last whole row.

The disk fills for real: a 32 KiB tmpfs mounted in a private mount namespace (`unshare -m`, where the test may
mount), and everywhere a file-size limit (RLIMIT_FSIZE: the kernel writes what fits, then EFBIG). The frames
are real ascii lines written by the test to a real pty."""

from __future__ import annotations

import math
import os
import resource
import shutil
import subprocess
import sys
import time
import tty
from pathlib import Path

import pytest

from fogd.core.runio import read_run
from fogd.protocols import get
from fogd.protocols.base import Frame

LIMIT_BYTES = 32 * 1024
ASCII = get("ascii")
RECORD = [sys.executable, "-m", "fogd.cli.record", "--protocol", "ascii", "-q"]
GIVE_UP_S = 120.0  # a safety net against a hang, not the thing tested


def lines(start: int, count: int) -> bytes:
    return b"".join(
        ASCII.encode(Frame("ascii", "imu", "I", None, n / 1000, (math.nan, math.nan, 0.001 * (n % 97)),
                           (False, False, True), (False, False, True), 20.0 + n / 1e5))  # fmt: skip
        for n in range(start, start + count)
    )


def feed_until_exit(process: subprocess.Popen, master: int) -> None:
    """Write frames to the pty until fogd-record stops (when the disk is full)."""
    sent, pending, deadline = 0, b"", time.monotonic() + GIVE_UP_S
    while process.poll() is None and time.monotonic() < deadline:
        if not pending:
            pending, sent = lines(sent, 50), sent + 50
        try:
            pending = pending[os.write(master, pending) :]
        except BlockingIOError:
            pass
        time.sleep(0.01)
    if process.poll() is None:
        process.kill()


def can_mount_in_a_namespace() -> bool:
    if shutil.which("unshare") is None:
        return False
    probe = subprocess.run(["unshare", "-m", "sh", "-c", "mount -t tmpfs -o size=4k none /mnt"], capture_output=True)
    return probe.returncode == 0


@pytest.mark.parametrize("mechanism", ["tmpfs", "rlimit"])
def test_record_on_a_full_disk_says_one_line_exits_74_and_keeps_whole_rows(tmp_path, mechanism):
    if mechanism == "tmpfs" and not can_mount_in_a_namespace():
        pytest.skip("no mount namespace here (unshare -m and mount need CAP_SYS_ADMIN)")
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    port = os.ttyname(slave)
    kept = tmp_path / "rec.csv"
    try:
        if mechanism == "tmpfs":
            disk = tmp_path / "disk"
            disk.mkdir()
            script = ('mount -t tmpfs -o size=$1 none "$2" || exit 99; shift 3; "$@"; status=$?; '
                      'cp "$0/rec.csv" "$0.rec.csv"; exit $status')  # fmt: skip
            command = ["unshare", "-m", "sh", "-c", script, str(disk), str(LIMIT_BYTES), str(disk), "--",
                       *RECORD, "--port", port, "-o", str(disk / "rec.csv")]  # fmt: skip
            process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
            output, expected_reason = disk / "rec.csv", "No space left on device"
        else:

            def limited() -> None:
                resource.setrlimit(resource.RLIMIT_FSIZE, (LIMIT_BYTES, LIMIT_BYTES))

            command = [*RECORD, "--port", port, "-o", str(kept)]
            process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, preexec_fn=limited)
            output, expected_reason = kept, "File too large"
        feed_until_exit(process, master)
        stderr = process.stderr.read().decode()
        process.stderr.close()
    finally:
        os.close(master)
        os.close(slave)
    if mechanism == "tmpfs":
        (tmp_path / "disk.rec.csv").rename(kept)
    assert process.returncode == 74, stderr
    assert stderr.strip().splitlines() == [f"fogd-record: cannot write {output}: {expected_reason}; stopped, the file "
                                           "ends at its last whole row"]  # fmt: skip
    data = kept.read_bytes()
    assert data.endswith(b"\n") and 0 < len(data) <= LIMIT_BYTES
    run = read_run(kept)  # what fogd-replay and fogd-train read: no cut last row
    assert run.rows == data.count(b"\n") - 1 and run.rows > 100
