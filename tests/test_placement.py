"""fogd.serving.placement: the `cpu` setting's words and numbers; the rule for moving off a busy CPU; real
threads pinned, moved off a CPU another process keeps busy, and not moved for their own load; the real daemon
keeps its threads on one CPU by default, on the CPU it is given, or lets the kernel place them (`any`)."""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import os
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st
from test_daemon_e2e import SAMPLES, Pty, run_samples, start_fogd, wait_for_rows, wire_frames
from test_hardening import model_document

from fogd.core import modelfile
from fogd.errors import ConfigError
from fogd.serving import config, placement, statsfile
from fogd.serving.placement import ANY, AUTO, BUSY_SHARE, MARGIN, Placement, better_cpu, cpu_setting

linux_only = pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="CPU affinity is Linux's")
two_cpus = pytest.mark.skipif(not hasattr(os, "sched_setaffinity") or len(os.sched_getaffinity(0)) < 2,
                              reason="needs two CPUs this process may use")  # fmt: skip


@pytest.mark.parametrize("text, setting", [("auto", AUTO), (" Auto ", AUTO), ("any", ANY), ("none", ANY), ("OFF", ANY)])
def test_words_are_auto_or_any(text, setting):
    assert cpu_setting(text) == setting


@linux_only
def test_every_allowed_cpu_is_a_setting_and_others_are_refused():
    allowed = os.sched_getaffinity(0)
    for cpu in allowed:
        assert cpu_setting(str(cpu)) == cpu
    for cpu in (max(allowed) + 1, 4096, -1):
        with pytest.raises(argparse.ArgumentTypeError, match="not one this process may run on"):
            cpu_setting(str(cpu))


@given(st.text(max_size=12))
def test_any_text_is_a_setting_or_one_usage_error(text):
    try:
        setting = cpu_setting(text)
    except argparse.ArgumentTypeError as error:
        assert str(error)
        return
    assert setting in (AUTO, ANY) or (isinstance(setting, int) and setting in placement.allowed_cpus())


@pytest.mark.parametrize("text, message", [("cpu: true\n", "must be auto, any or a CPU number"),
                                           ("cpu: [0]\n", "must be auto, any or a CPU number"),
                                           ("cpu: 4096\n", "not one this process may run on"),
                                           ("cpu: fast\n", "not auto, any or a CPU number"),
                                           ("cpu: null\n", "needs a value")])  # fmt: skip
def test_a_bad_cpu_in_the_config_names_the_key(tmp_path, text, message):
    path = tmp_path / "fogd.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message) as caught:
        config.load(str(path))
    assert "key 'cpu'" in str(caught.value)


@linux_only
def test_a_cpu_number_and_the_words_load_from_yaml(tmp_path):
    path = tmp_path / "fogd.yaml"
    cpu = min(os.sched_getaffinity(0))
    path.write_text(f"cpu: {cpu}\n")
    assert config.load(str(path)) == {"cpu": cpu}
    path.write_text("cpu: any\n")
    assert config.load(str(path)) == {"cpu": ANY}


shares = st.dictionaries(st.integers(0, 7), st.floats(0.0, 1.0), min_size=1, max_size=8)


@given(shares, st.data())
def test_better_cpu_moves_only_off_a_busy_cpu_to_a_clearly_less_busy_one(others, data):
    current = data.draw(st.sampled_from(sorted(others)))
    target = better_cpu(current, others)
    least = min(others.values())
    if others[current] > BUSY_SHARE and least <= others[current] - MARGIN:
        assert target is not None and target != current
        assert others[target] == least
    else:
        assert target is None


def spin_in_c(stop: threading.Event) -> None:
    """CPU work that releases the GIL (hashing a large buffer), so the test's own thread keeps running."""
    block = bytes(1 << 22)
    while not stop.is_set():
        hashlib.sha256(block).digest()


def in_thread(function):
    """Run `function` on a thread of its own (affinity is per thread: the test's thread is never pinned)."""
    result: dict = {}

    def run() -> None:
        try:
            result["value"] = function()
        except BaseException as error:  # handed to the test's thread
            result["error"] = error

    thread = threading.Thread(target=run)
    thread.start()
    thread.join(30)
    if "error" in result:
        raise result["error"]
    return result.get("value")


@two_cpus
def test_start_pins_the_thread_and_threads_it_starts_inherit_the_cpu():
    def body():
        kept = Placement(AUTO)
        kept.start()
        seen = {}
        child = threading.Thread(target=lambda: seen.update(cpus=os.sched_getaffinity(0)))
        child.start()
        child.join()
        return kept.cpu, os.sched_getaffinity(0), seen["cpus"]

    cpu, own, child = in_thread(body)
    assert cpu in os.sched_getaffinity(0)
    assert own == child == {cpu}
    assert len(os.sched_getaffinity(0)) > 1  # the test's own thread was left alone


@two_cpus
def test_any_leaves_threads_where_the_kernel_puts_them():
    allowed = os.sched_getaffinity(0)

    def body():
        free = Placement(ANY)
        free.start()
        return free.cpu, os.sched_getaffinity(0)

    assert in_thread(body) == (None, allowed)


def follow_for(kept: Placement, seconds: float, monkeypatch) -> None:
    """Two checks `seconds` apart: the first opens a window, the second judges it."""
    monkeypatch.setattr(placement, "CHECK_EVERY_S", 0.0)
    start_s = time.monotonic()
    kept.follow(start_s)
    time.sleep(seconds)
    kept.follow(time.monotonic())


@contextlib.contextmanager
def hog_process(cpu: int):
    """Another process keeping `cpu` busy."""
    hog = subprocess.Popen([sys.executable, "-c", f"import os\nos.sched_setaffinity(0, {{{cpu}}})\nwhile True: pass"])
    try:
        yield
    finally:
        hog.kill()
        hog.wait()


@contextlib.contextmanager
def own_busy_thread(cpu: int):
    """A busy thread of this process, started on the pinned thread: it inherits `cpu` (fogd's own load)."""
    stop = threading.Event()
    spinner = threading.Thread(target=spin_in_c, args=(stop,))
    spinner.start()
    try:
        yield
    finally:
        stop.set()
        spinner.join()


def followed_under(load, monkeypatch) -> tuple[int, int, int, set[int]]:
    """A thread kept on a CPU by `auto`, with `load` on that CPU through two checks: (its first CPU, its CPU
    now, moves, the thread's own affinity now)."""

    def body():
        kept = Placement(AUTO)
        kept.start()
        first = kept.cpu
        with load(first):
            time.sleep(0.3)  # the load is running
            follow_for(kept, 1.5, monkeypatch)
        return first, kept.cpu, kept.moves, os.sched_getaffinity(0)

    return in_thread(body)


@two_cpus
def test_threads_move_off_a_cpu_another_process_keeps_busy(monkeypatch):
    first, now, moves, own = followed_under(hog_process, monkeypatch)
    assert now != first and moves == 1
    assert own == {now}  # the thread itself was re-pinned, not only the record


@two_cpus
def test_the_daemons_own_load_does_not_make_it_move(monkeypatch):
    first, now, moves, own = followed_under(own_busy_thread, monkeypatch)
    assert (now, moves, own) == (first, 0, {first})


def thread_cpus(pid: int) -> dict[int, str]:
    """Each thread's Cpus_allowed_list of a running process, by thread id."""
    lists = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        for line in (task / "status").read_text().splitlines():
            if line.startswith("Cpus_allowed_list:"):
                lists[int(task.name)] = line.split(":", 1)[1].strip()
    return lists


@pytest.fixture
def model_path(tmp_path) -> Path:
    """The end-to-end tests' linear model (test_daemon_e2e's)."""
    path = tmp_path / "model.json"
    modelfile.save(path, model_document(name="e2e-linear"))
    return path


def stats_when_written(stats: Path, timeout_s: float = 10.0) -> dict:
    """The daemon's stats file, once it has written one."""
    deadline = time.monotonic() + timeout_s
    while not stats.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    return json.loads(stats.read_text())


def run_daemon(tmp_path: Path, model: Path, *args: str) -> tuple[int, dict[int, str], dict]:
    """The real daemon on a pty with frames flowing: its pid, every thread's CPU list and the stats file's
    `cpu`."""
    gyro, out, stats = Pty(), tmp_path / "out.csv", tmp_path / "stats.json"
    fogd = start_fogd(tmp_path, gyro.path, model, "--out", str(out), "--out-format", "csv", "--stats-file", str(stats),
                      *args)  # fmt: skip
    try:
        gyro.write(b"".join(wire_frames("kvh-a", run_samples("kvh-a"))))
        wait_for_rows(out, SAMPLES + 1)
        cpus = thread_cpus(fogd.process.pid)
        snapshot = stats_when_written(stats)
        assert fogd.terminate()[0] == 0
    finally:
        fogd.kill()
        gyro.close()
    return fogd.process.pid, cpus, snapshot


@two_cpus
@pytest.mark.parametrize("setting", [None, "last", ANY])
def test_the_daemon_keeps_its_threads_on_one_cpu_unless_told_any(tmp_path, model_path, setting):
    allowed = os.sched_getaffinity(0)
    args = [] if setting is None else ["--cpu", str(max(allowed)) if setting == "last" else setting]
    pid, cpus, snapshot = run_daemon(tmp_path, model_path, *args)
    singles = {str(cpu) for cpu in allowed}
    told = statsfile.describe(snapshot)
    if setting == ANY:
        assert "threads on CPU" not in told
        assert snapshot["cpu"] == {"setting": ANY, "on": None, "moves": 0}
        assert len(cpus) >= 3 and not singles & set(cpus.values())  # no thread narrowed to one CPU
        return
    on = snapshot["cpu"]["on"]
    assert on in allowed
    assert f"threads on CPU {on} (" in told  # fogd --status says where
    assert cpus[pid] == str(on)  # the loop (the main thread)
    kept = [tid for tid, cpu_list in cpus.items() if cpu_list == str(on)]
    assert len(kept) >= 3  # the loop, the reader and the writer
    # what is left is a library's idle thread started at import, before the daemon ran (OpenBLAS's pool)
    assert all(cpus[tid] not in singles for tid in cpus if tid not in kept)
    if setting == "last":
        assert snapshot["cpu"] == {"setting": max(allowed), "on": max(allowed), "moves": 0}
    else:
        assert snapshot["cpu"]["setting"] == AUTO


@linux_only
def test_a_refused_affinity_is_one_warning_and_the_kernel_places_the_threads(monkeypatch, caplog):
    """A container or seccomp policy that refuses sched_setaffinity (EPERM) costs a log line, never the start."""

    def refuse(pid, cpus):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setaffinity", refuse)
    kept = Placement(AUTO)
    with caplog.at_level("WARNING", logger="fogd.placement"):
        kept.start()
        kept.follow(time.monotonic() + 3600)
    assert kept.cpu is None and kept.describe()["on"] is None
    messages = [record.getMessage() for record in caplog.records]
    assert len(messages) == 1
    assert re.fullmatch(r"cannot keep fogd's threads on CPU \d+ \(Operation not permitted\); the kernel places them",
                        messages[0])  # fmt: skip


@linux_only
def test_the_daemon_refuses_a_cpu_it_may_not_use_in_one_line(tmp_path):
    outside = max(os.sched_getaffinity(0)) + 1
    done = subprocess.run([sys.executable, "-m", "fogd.cli.daemon", "--port", str(tmp_path / "tty"), "--cpu", str(outside)],
                          capture_output=True, text=True, timeout=60)  # fmt: skip
    assert done.returncode == 2
    assert f"CPU {outside} is not one this process may run on" in done.stderr
    assert "Traceback" not in done.stderr and len(done.stderr.strip().splitlines()) <= 3


@two_cpus
def test_the_daemon_moves_off_a_cpu_another_process_takes(tmp_path, model_path):
    """The daemon's loop looks every CHECK_EVERY_S: a process spinning on its CPU moves its threads, with one
    warning that names both CPUs, and every thread goes along."""
    stats, gyro = tmp_path / "stats.json", Pty()
    fogd = start_fogd(tmp_path, gyro.path, model_path, "--stats-file", str(stats))
    try:
        first = stats_when_written(stats)["cpu"]["on"]
        with hog_process(first):
            deadline = time.monotonic() + 4 * placement.CHECK_EVERY_S
            while json.loads(stats.read_text())["cpu"]["moves"] == 0 and time.monotonic() < deadline:
                time.sleep(0.2)
            cpu = json.loads(stats.read_text())["cpu"]
            cpus = thread_cpus(fogd.process.pid)
        assert fogd.terminate()[0] == 0
    finally:
        fogd.kill()
        gyro.close()
    assert cpu["moves"] == 1 and cpu["on"] != first
    assert cpus[fogd.process.pid] == str(cpu["on"]) and str(first) not in cpus.values()
    assert f"CPU {first} busy: other processes took" in fogd.stderr
    assert f"fogd's threads moved to CPU {cpu['on']}" in fogd.stderr
