"""What a new owner trips on in the first hour (issue 14), on the real commands: fogd refuses stdout as a
default output off a terminal and into the journal; `fogd --status` with no daemon is 3; every command has
--version; one-line messages (dashed config keys, missing inputs 66, swapped fogd-replay arguments, a port
that is not a tty, --rate-hz 0, no -0 in CSVs, an emulator without a reader, --allan-plot's path); and
fogd-top as a person sees it in tmux, on the real daemon."""

from __future__ import annotations

import json
import os
import re
import select
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from fogd import __version__
from fogd.errors import ConfigError
from fogd.serving import config

ROOT = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent
DEMO_MODEL = ROOT / "fogd" / "data" / "demo-model.json"
COMMANDS = ("fogd", "fogd-sim", "fogd-train", "fogd-replay", "fogd-emu", "fogd-record", "fogd-top")


def run(*command: str, timeout_s: float = 60, **kwargs) -> subprocess.CompletedProcess:
    result = subprocess.run([str(BIN / command[0]), *command[1:]], capture_output=True, text=True, timeout=timeout_s,
                            **kwargs)  # fmt: skip
    assert "Traceback" not in result.stderr, result.stderr
    return result


def one_line(result: subprocess.CompletedProcess) -> str:
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    return lines[0]


@pytest.fixture
def port():
    """A pty standing in for the gyro's port (nothing is sent on it)."""
    master, slave = os.openpty()
    path = os.ttyname(slave)
    os.close(slave)
    yield path
    os.close(master)


@pytest.mark.parametrize("command", COMMANDS)
def test_every_command_has_a_version(command):
    result = run(command, "--version")
    assert result.returncode == 0 and result.stdout == f"{command} {__version__}\n"


def test_the_default_stdout_is_refused_off_a_terminal_and_the_journal_always(tmp_path, port):
    args = ("fogd", "--port", port, "--model", str(DEMO_MODEL), "--stats-file", "none", "--duration-s", "1")
    refused = run(*args, cwd=tmp_path)  # stdout is a pipe, as a service's is the journal
    assert refused.returncode == 78 and "key 'out' is not set and stdout is not a terminal" in one_line(refused)
    assert "pty:/run/fogd/fog0" in one_line(refused)
    with open(tmp_path / "journal", "w") as journal:
        info = os.fstat(journal.fileno())
        env = {**os.environ, "JOURNAL_STREAM": f"{info.st_dev}:{info.st_ino}"}
        into_journal = subprocess.run([str(BIN / "fogd"), *args[1:], "--out", "-"], stdout=journal,
                                      stderr=subprocess.PIPE, text=True, env=env, timeout=30)  # fmt: skip
    assert into_journal.returncode == 78 and "stdout is the journal" in into_journal.stderr
    assert (tmp_path / "journal").read_bytes() == b""
    assert run(*args, "--out", "-", cwd=tmp_path).returncode == 0  # a pipe, asked for: a consumer downstream
    master, slave = os.openpty()  # a terminal: stdout by default, as the README's table says
    try:
        on_terminal = subprocess.run([str(BIN / "fogd"), *args[1:]], stdout=slave, stderr=subprocess.PIPE,
                                     text=True, timeout=30, cwd=tmp_path)  # fmt: skip
    finally:
        os.close(slave)
        os.close(master)
    assert on_terminal.returncode == 0, on_terminal.stderr


def test_status_with_no_daemon_and_no_stats_file_is_3(tmp_path):
    result = run("fogd", "--status", "--instance", f"nobody-{os.getpid()}")
    assert result.returncode == 3 and "not running" in result.stdout
    assert run("fogd", "--status", "--stats-file", str(tmp_path / "none.json")).returncode == 3
    (tmp_path / "bad.json").write_text("{not json")
    assert run("fogd", "--status", "--stats-file", str(tmp_path / "bad.json")).returncode == 74
    helps = run("fogd", "--help").stdout.replace("\n", " ")
    assert "3 not running" in re.sub(r"\s+", " ", helps) and "0 running; 3 not running" in re.sub(r"\s+", " ", helps)


def test_a_config_key_with_dashes_says_which_key_was_meant(tmp_path):
    path = tmp_path / "fogd.yaml"
    path.write_text("out-format: csv\n")
    with pytest.raises(ConfigError, match=r"unknown key 'out-format' \(did you mean out_format\?"):
        config.load(str(path))
    path.write_text("rate-hz: 200\n")
    with pytest.raises(ConfigError, match=r"did you mean rate_hz\?"):
        config.load(str(path))
    path.write_text("modle: x.json\n")
    with pytest.raises(ConfigError, match=r"did you mean model\?"):
        config.load(str(path))


def test_missing_inputs_exit_66(tmp_path):
    for command in (("fogd-train", "nope.csv", "-o", "m.json"), ("fogd-replay", str(DEMO_MODEL), "nope.csv"),
                    ("fogd-replay", "nope.json", "run.csv"), ("fogd-sim", "--profile", "nope.yaml", "-o", "x.csv"),
                    ("fogd-emu", "--csv", "nope.csv")):  # fmt: skip
        result = run(*command, cwd=tmp_path)
        assert result.returncode == 66 and "nope" in one_line(result), (command, result.stderr)


def write_run(path: Path, temp_c: np.ndarray) -> None:
    rows = "".join(f"{i * 0.1:.1f},{0.01 * np.sin(i / 50):.6f},{float(t)!r}\n" for i, t in enumerate(temp_c))
    path.write_text("t_s,rate_dph,temp_c\n" + rows)


def test_replay_swapped_arguments_no_negative_zero_and_the_allan_path(tmp_path):
    run_csv = tmp_path / "run.csv"
    write_run(run_csv, np.where(np.arange(2000) % 2, -0.0, 0.0))  # a sensor at 0 C, sometimes from below
    swapped = run("fogd-replay", str(run_csv), str(DEMO_MODEL))
    assert swapped.returncode == 2
    assert "look swapped" in one_line(swapped) and "usage fogd-replay MODEL.json RUN.csv" in one_line(swapped)
    result = run("fogd-replay", str(DEMO_MODEL), str(run_csv), "-o", str(tmp_path / "out.csv"),
                 "--allan-plot", str(tmp_path / "adir"))  # fmt: skip
    assert result.returncode == 0, result.stderr
    fields = [field for line in (tmp_path / "out.csv").read_text().splitlines()[1:] for field in line.split(",")]
    assert "-0" not in fields and "0" in fields
    assert (tmp_path / "adir").stat().st_size > 0 and not (tmp_path / "adir.png").exists()
    assert f"wrote {tmp_path / 'adir'}\n" in result.stderr


def test_a_port_that_is_not_a_tty_and_a_zero_rate_say_so(tmp_path):
    (tmp_path / "notatty").write_text("")
    result = run("fogd", "--port", str(tmp_path / "notatty"), "--model", str(DEMO_MODEL), "--out", os.devnull)
    assert result.returncode == 74 and "not a serial port" in one_line(result)
    assert "ioctl" not in result.stderr
    result = run("fogd", "--rate-hz", "0")
    assert result.returncode == 2 and "'0' must be above 0 and at most 100000 Hz" in one_line(result)


def test_the_emulator_says_when_nobody_reads_and_counts_the_wait(tmp_path):
    emu = subprocess.Popen([str(BIN / "fogd-emu"), "--profile", "paper-test", "--rate-hz", "1000"],
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)  # fmt: skip
    said = b""
    deadline = time.monotonic() + 30
    while b"no reader" not in said and time.monotonic() < deadline:  # a pty holds a few kB: full at once
        if select.select([emu.stderr], [], [], 1.0)[0]:
            said += os.read(emu.stderr.fileno(), 4096)
    time.sleep(1.5)  # blocked, with no reader, until the stop
    emu.send_signal(signal.SIGTERM)
    stderr = (said + emu.communicate(timeout=10)[1]).decode()
    assert emu.returncode == 0
    assert stderr.count("no reader on /dev/pts/") == 1, stderr
    waited_s = float(re.search(r"backpressure ([\d.]+) s", stderr).group(1))
    assert waited_s >= 1.5, stderr


needs_tmux = pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux not installed")


@needs_tmux
def test_fogd_top_in_tmux_shows_the_running_daemon(tmp_path):
    stats = tmp_path / "stats.json"
    socket_name = f"fogd-test-{os.getpid()}"
    daemon = subprocess.Popen([str(BIN / "fogd"), "--demo", "--stats-file", str(stats), "--duration-s", "40"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    tmux = ["tmux", "-L", socket_name]
    env = {**os.environ, "LANG": "C.UTF-8", "LC_ALL": "C.UTF-8"}
    try:
        subprocess.run([*tmux, "-u", "new-session", "-d", "-x", "110", "-y", "30",
                        f"{BIN / 'fogd-top'} --stats-file {stats}"], check=True, env=env, timeout=10)  # fmt: skip
        screen = ""
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            time.sleep(1.0)
            screen = subprocess.run([*tmux, "capture-pane", "-p"], capture_output=True, text=True, timeout=10).stdout
            points = re.search(r"one point a second \((\d+) points\)", screen)
            if points and int(points.group(1)) >= 7 and "  running  " in screen:
                break
        lines = screen.splitlines()
        assert lines[0].startswith(f"fogd-top  fogd {__version__}  pid {daemon.pid}  running"), screen
        assert any(line.startswith("frames   in rate ") for line in lines), screen  # the demo: fogd frames
        assert any(line.startswith("latency  last ") and " ms" in line for line in lines), screen
        spark = next(line for line in lines if line.startswith("T        "))
        assert re.search(r"[▁▂▃▄▅▆▇█]{5,}", spark) and re.search(r"\(-?[\d.]+ \.\. -?[\d.]+ C\)", spark), screen
        assert re.search(r"^flags    [.CWSROTH]{5,}", screen, flags=re.M), screen  # H: WARMING, the demo starts cold
        assert "\x1b" not in screen and "^[" not in screen  # what a person sees: no stray escapes
        daemon.send_signal(signal.SIGTERM)
        assert daemon.wait(10) == 0
        deadline = time.monotonic() + 15
        while "NOT RUNNING" not in screen and time.monotonic() < deadline:
            time.sleep(1.0)
            screen = subprocess.run([*tmux, "capture-pane", "-p"], capture_output=True, text=True, timeout=10).stdout
        assert "NOT RUNNING" in screen.splitlines()[0], screen
        subprocess.run([*tmux, "send-keys", "C-c"], check=True, timeout=10)  # Ctrl-C quits, no traceback
        time.sleep(1.0)
        alive = subprocess.run([*tmux, "list-panes", "-F", "#{pane_dead}"], capture_output=True, text=True, timeout=10)
        assert alive.returncode != 0 or alive.stdout.strip() in ("", "1")  # the pane's program ended
    finally:
        subprocess.run([*tmux, "kill-server"], capture_output=True, timeout=10)
        if daemon.poll() is None:
            daemon.kill()
            daemon.wait()


def test_fogd_top_to_a_pipe_writes_plain_frames_and_count_says_not_running(tmp_path):
    missing = run("fogd-top", "--stats-file", str(tmp_path / "none.json"), "--count", "1")
    assert missing.returncode == 3 and "not running" in missing.stdout
    snapshot = {"version": __version__, "pid": 999999999, "running": True, "time_unix_s": time.time() - 60,
                "history": {"temp_c": [20.0, 20.5, None, 21.0], "temp_rate_cps": [0.0] * 4, "comp_dph": [0.1] * 4,
                            "flags": [0, 2, 0, 33]}}  # fmt: skip
    (tmp_path / "stats.json").write_text(json.dumps(snapshot))
    stale = run("fogd-top", "--stats-file", str(tmp_path / "stats.json"), "--count", "2", "--interval-s", "0.1")
    assert stale.returncode == 3 and "\x1b" not in stale.stdout and stale.stdout.count("fogd-top  fogd") == 2
    assert "NOT RUNNING" in stale.stdout
    assert re.search(r"^T        .{60}  \(20\.00 \.\. 21\.00 C\)$", stale.stdout, flags=re.M), stale.stdout
    assert re.search(r"^flags    \.C\.O ", stale.stdout, flags=re.M), stale.stdout
