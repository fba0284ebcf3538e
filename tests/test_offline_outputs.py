"""Issue 35.1: what the offline tools' outputs (`fogd-sim -o`, `fogd-replay -o`, `fogd-train -o` and --report)
do with each kind of path. A regular file or a new name is replaced by temp-and-rename; a FIFO, a character
device (here a real pty's slave) or stdout by any name is written as a stream and stays what it was; a directory,
a socket or a block device is refused with one line, exit 74; a missing directory is never created; and all of it
is checked before the training or simulation, not after."""

from __future__ import annotations

import os
import resource
import shutil
import select
import socket
import stat
import subprocess
import sys
import threading
import tty
from pathlib import Path

import json

import numpy as np
import pytest

from fogd.cli import replay as replay_cli
from fogd.cli import sim as sim_cli
from fogd.cli import train as train_cli
from fogd.core import modelfile
from fogd.core.estimator import EstimatorSettings
from fogd.core.inputs import default_inputs

SHORT_YAML = "- [60, 20]\n- [120, 22]\n"
SIM = ["--rate-hz", "2", "--seed", "3"]


@pytest.fixture
def profile(tmp_path: Path) -> Path:
    path = tmp_path / "short.yaml"
    path.write_text(SHORT_YAML)
    return path


def write_model(path: Path) -> Path:
    doc = modelfile.document(
        name="outputs", method="linear", inputs=default_inputs(EstimatorSettings(window_s=0.5, average_s=0.05)),
        x_mean=np.zeros(2), x_scale=np.ones(2), y_mean=0.0, y_scale=1.0,
        domain_min=np.array([-40.0, -5.0]), domain_max=np.array([80.0, 5.0]),
        params={"coef": [0.05, 30.0], "intercept": 0.5}, reference_dph=0.0, training={}, metrics={},
        created_utc="2024-01-01T00:00:00Z",
    )  # fmt: skip
    path.write_text(json.dumps(doc))
    return path


def write_small_run(path: Path, rows: int = 400) -> Path:
    lines = ["t_s,rate_dph,temp_c"] + [f"{n / 10:.1f},{0.01 * (n % 7)!r},{20 + n / 1000:.4f}" for n in range(rows)]
    path.write_text("\n".join(lines) + "\n")
    return path


def simulated(tmp_path: Path, profile: Path) -> bytes:
    """What fogd-sim writes to a regular file: what every stream must receive too."""
    path = tmp_path / "reference.csv"
    assert sim_cli.main(["--profile", str(profile), "-o", str(path), *SIM]) == 0
    return path.read_bytes()


def drain(fd: int, stop: threading.Event, into: bytearray) -> threading.Thread:
    """Read `fd` on a thread until `stop` is set and nothing more is waiting."""

    def run() -> None:
        while True:
            ready, _, _ = select.select([fd], [], [], 0.05)
            if ready:
                chunk = os.read(fd, 65536)
                if not chunk:
                    return
                into.extend(chunk)
            elif stop.is_set():
                return

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def test_sim_writes_a_fifo_as_a_stream_and_leaves_it_a_fifo(tmp_path, profile):
    expected = simulated(tmp_path, profile)
    fifo = tmp_path / "out.fifo"
    os.mkfifo(fifo)
    received = bytearray()
    reader = threading.Thread(target=lambda: received.extend(fifo.read_bytes()), daemon=True)
    reader.start()
    assert sim_cli.main(["--profile", str(profile), "-o", str(fifo), *SIM]) == 0
    reader.join(timeout=60)
    assert bytes(received) == expected
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert sorted(path.name for path in tmp_path.iterdir()) == ["out.fifo", "reference.csv", "short.yaml"]


def test_replay_writes_a_character_device_as_a_stream_and_leaves_it_a_device(tmp_path, capsys):
    """The device is a real pty's slave, named through a link (as /dev/ttyUSB0 through /dev/serial/by-id)."""
    run = write_small_run(tmp_path / "run.csv")
    model = write_model(tmp_path / "m.json")
    reference = tmp_path / "reference.csv"
    assert replay_cli.main([str(model), str(run), "-o", str(reference)]) == 0
    master, slave = os.openpty()
    try:
        tty.setraw(slave)  # bytes as written, no newline translation
        device = os.ttyname(slave)
        link = tmp_path / "tty-link"
        link.symlink_to(device)
        received, stop = bytearray(), threading.Event()
        reader = drain(master, stop, received)
        assert replay_cli.main([str(model), str(run), "-o", str(link)]) == 0
        stop.set()
        reader.join(timeout=60)
        assert bytes(received) == reference.read_bytes()
        assert stat.S_ISCHR(os.stat(device).st_mode) and link.is_symlink()
    finally:
        os.close(master)
        os.close(slave)
    assert "cannot write" not in capsys.readouterr().err


@pytest.mark.parametrize("name", ["/dev/stdout", "-"])
def test_sim_writes_stdout_by_any_name(tmp_path, profile, name):
    """`-o /dev/stdout` failed: its real path is /proc/<pid>/fd/pipe:[N], where no temporary file can be made."""
    expected = simulated(tmp_path, profile)
    result = subprocess.run(
        [sys.executable, "-m", "fogd.cli.sim", "--profile", str(profile), "-o", name, *SIM],
        capture_output=True, timeout=300,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert result.stdout == expected


def refused(capsys, status: int) -> str:
    assert status == 74
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    return lines[0]


def test_a_directory_a_socket_and_a_block_device_are_refused_before_simulating(tmp_path, profile, capsys, monkeypatch):
    def never(*args, **kwargs):
        raise AssertionError("simulated before checking its output")

    monkeypatch.setattr(sim_cli, "Simulation", never)
    directory = tmp_path / "dir"
    directory.mkdir()
    assert "a directory" in refused(capsys, sim_cli.main(["--profile", str(profile), "-o", str(directory), *SIM]))
    server = socket.socket(socket.AF_UNIX)
    server.bind(str(tmp_path / "sock"))
    try:
        line = refused(capsys, sim_cli.main(["--profile", str(profile), "-o", str(tmp_path / "sock"), *SIM]))
        assert "sock" in line and "socket" in line
        assert stat.S_ISSOCK(os.lstat(tmp_path / "sock").st_mode)
    finally:
        server.close()
    try:
        os.mknod(tmp_path / "blk", stat.S_IFBLK | 0o600, os.makedev(7, 200))
    except PermissionError:
        return  # not root: no block device to name
    line = refused(capsys, sim_cli.main(["--profile", str(profile), "-o", str(tmp_path / "blk"), *SIM]))
    assert "block device" in line and stat.S_ISBLK(os.lstat(tmp_path / "blk").st_mode)


def test_a_missing_directory_is_not_created_and_is_refused_before_training(tmp_path, capsys, monkeypatch):
    """`-o /nonexistent/dir/m.json` created /nonexistent (as root) after the training."""

    def never(*args, **kwargs):
        raise AssertionError("trained before checking its output")

    monkeypatch.setattr(train_cli, "fit_channels", never)
    run = write_small_run(tmp_path / "run.csv")
    missing = tmp_path / "nonexistent" / "dir" / "m.json"
    line = refused(capsys, train_cli.main([str(run), "-o", str(missing), "-q"]))
    assert str(missing) in line and "no directory" in line
    assert not (tmp_path / "nonexistent").exists()


def test_replay_to_a_missing_directory_creates_nothing(tmp_path, capsys):
    run = write_small_run(tmp_path / "run.csv")
    model = write_model(tmp_path / "m.json")
    missing = tmp_path / "nonexistent" / "out.csv"
    line = refused(capsys, replay_cli.main([str(model), str(run), "-o", str(missing)]))
    assert str(missing) in line
    assert not missing.parent.exists()


def test_report_naming_an_existing_file_is_refused_before_training(tmp_path, capsys, monkeypatch):
    """Issue 35.14: `--report EXISTING_FILE` wrote the model, then exited 65."""

    def never(*args, **kwargs):
        raise AssertionError("trained before checking the report directory")

    monkeypatch.setattr(train_cli, "fit_channels", never)
    run = write_small_run(tmp_path / "run.csv")
    blocker = tmp_path / "notes.txt"
    blocker.write_text("keep me\n")
    line = refused(capsys, train_cli.main([str(run), "-o", str(tmp_path / "m.json"), "--report", str(blocker), "-q"]))
    assert str(blocker) in line and "not a directory" in line
    assert not (tmp_path / "m.json").exists() and blocker.read_text() == "keep me\n"


def can_mount_in_a_namespace() -> bool:
    if shutil.which("unshare") is None:
        return False
    probe = subprocess.run(["unshare", "-m", "sh", "-c", "mount -t tmpfs -o size=4k none /mnt"], capture_output=True)
    return probe.returncode == 0


@pytest.mark.parametrize("mechanism", ["tmpfs", "rlimit"])
def test_no_space_left_is_74_naming_the_path_and_the_old_output_stays_whole(tmp_path, mechanism):
    """Issue 35.14: no space left gave 65 and a message without the path. The disk fills for real: an 8 KiB
    tmpfs in a private mount namespace, or a file-size limit (RLIMIT_FSIZE) where mounting is not allowed."""
    run = write_small_run(tmp_path / "run.csv")
    model = write_model(tmp_path / "m.json")
    old = b"t_s,rate_dph,temp_c\n0.0,0.0,20.0\n"
    replay = [sys.executable, "-m", "fogd.cli.replay", str(model), str(run), "-o"]
    if mechanism == "tmpfs":
        if not can_mount_in_a_namespace():
            pytest.skip("no mount namespace here (unshare -m and mount need CAP_SYS_ADMIN)")
        disk = tmp_path / "disk"
        disk.mkdir()
        (tmp_path / "old.csv").write_bytes(old)
        output = disk / "out.csv"
        script = ('mount -t tmpfs -o size=8k none "$0" || exit 99; cp "$0.old" "$0/out.csv"; "$@"; status=$?; '
                  'ls -A "$0" > "$0.listing"; cp "$0/out.csv" "$0.out"; exit $status')  # fmt: skip
        (tmp_path / "disk.old").write_bytes(old)
        result = subprocess.run(["unshare", "-m", "sh", "-c", script, str(disk), *replay, str(output)],
                                capture_output=True, text=True, timeout=300)  # fmt: skip
        left, kept = (tmp_path / "disk.listing").read_text().split(), (tmp_path / "disk.out").read_bytes()
        reason = "No space left on device"
    else:
        output = tmp_path / "out" / "out.csv"
        output.parent.mkdir()
        output.write_bytes(old)

        def limited() -> None:
            resource.setrlimit(resource.RLIMIT_FSIZE, (8192, 8192))

        result = subprocess.run([*replay, str(output)], capture_output=True, text=True, timeout=300, preexec_fn=limited)
        left, kept = os.listdir(output.parent), output.read_bytes()
        reason = "File too large"
    assert result.returncode == 74, result.stderr
    assert result.stderr.strip().splitlines() == [f"fogd-replay: cannot write {output}: {reason}"]
    assert kept == old and left == ["out.csv"]  # the old file whole, no temporary left behind


def test_the_emulators_ledger_in_a_directory_is_74_naming_it(tmp_path):
    """fogd-emu's ledger is a stream written as it goes: a directory named as it is one line, exit 74 (was 65)."""
    run = write_small_run(tmp_path / "run.csv")
    result = subprocess.run(
        [sys.executable, "-m", "fogd.cli.emu", "--csv", str(run), "--link", str(tmp_path / "gyro"),
         "--ledger", str(tmp_path)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert result.returncode == 74, result.stderr
    assert result.stderr.strip().splitlines() == [f"fogd-emu: cannot write ledger {tmp_path}: a directory; an output "
                                                  "is a regular file, a FIFO, a character device or '-'"]  # fmt: skip
    assert not os.path.lexists(tmp_path / "gyro")
