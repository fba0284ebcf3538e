"""fogd.serving.placement: the `cpu` setting's words and numbers; the rule for moving off a busy CPU; real
threads pinned, moved off a CPU other processes keep busy and not moved for their own load (the other
processes' load injected into the rule, so the premise holds on a busy machine too); the real daemon keeps its
threads on one CPU by default, on the CPU it is given, or lets the kernel place them (`any`), and moves off a
CPU a real process takes where the machine has a CPU to spare."""

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
from collections.abc import Callable
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st
from progress import wait_until, watching
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
    thread.join()  # pytest-timeout bounds a hang
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


class InjectedLoads:
    """The placement rule's view of /proc/stat, injected: each CPU's busy seconds are what other processes took
    (`others_share` of the injected clock's seconds) plus this process's threads on it, as the scheduler counts
    them. The rule's premise (one CPU busy, another idle) then holds whatever else the machine runs."""

    def __init__(self, others_share: dict[int, float]) -> None:
        self.others_share = others_share
        self.now_s = 0.0

    def busy_s(self, allowed: frozenset[int]) -> dict[int, float]:
        return {cpu: self.others_share.get(cpu, 0.0) * self.now_s + placement.threads_cpu_s(cpu) for cpu in allowed}


def follow_under(kept: Placement, loads: InjectedLoads, window_s: Callable[[], float], monkeypatch) -> None:
    """Two checks of `kept` under injected `loads`: the first opens a window, the second judges it, `window_s()`
    seconds of the injected clock later (asked when the second check is due)."""
    monkeypatch.setattr(placement, "cpu_busy_s", loads.busy_s)
    monkeypatch.setattr(placement, "CHECK_EVERY_S", 0.0)
    kept.follow(loads.now_s)
    loads.now_s += window_s()
    kept.follow(loads.now_s)


@contextlib.contextmanager
def hog_process(cpu: int):
    """Another process keeping `cpu` busy."""
    hog = subprocess.Popen([sys.executable, "-c", f"import os\nos.sched_setaffinity(0, {{{cpu}}})\nwhile True: pass"])
    try:
        yield
    finally:
        hog.kill()
        hog.wait()


@two_cpus
def test_threads_move_off_a_cpu_other_processes_keep_busy(monkeypatch):
    """Other processes took 90 % of the CPU the threads are kept on and 10 % of every other: the thread that
    started the placement and a thread it started are both re-pinned to the least busy other CPU."""

    def body():
        kept = Placement(AUTO)
        kept.start()
        first = kept.cpu
        others = {cpu: 0.9 if cpu == first else 0.1 + 0.01 * cpu for cpu in kept.allowed}
        stop, seen = threading.Event(), {}

        def child() -> None:
            stop.wait()
            seen["cpus"] = os.sched_getaffinity(0)

        started = threading.Thread(target=child)
        started.start()
        try:
            follow_under(kept, InjectedLoads(others), lambda: 1.0, monkeypatch)
        finally:
            stop.set()
            started.join()
        return first, kept.cpu, kept.moves, os.sched_getaffinity(0), seen["cpus"], others

    first, now, moves, own, child, others = in_thread(body)
    assert now == min((cpu for cpu in others if cpu != first), key=lambda cpu: others[cpu]) and moves == 1
    assert own == child == {now}  # the threads themselves were re-pinned, not only the record


@two_cpus
def test_threads_stay_when_other_processes_keep_every_cpu_busy(monkeypatch):
    def body():
        kept = Placement(AUTO)
        kept.start()
        first = kept.cpu
        follow_under(kept, InjectedLoads({cpu: 0.9 if cpu == first else 0.7 for cpu in kept.allowed}), lambda: 1.0,
                     monkeypatch)  # fmt: skip
        return first, kept.cpu, kept.moves, os.sched_getaffinity(0)

    first, now, moves, own = in_thread(body)
    assert (now, moves, own) == (first, 0, {first})


OWN_CPU_S = 0.3  # CPU seconds the daemon's own busy thread takes before the rule judges the window


@two_cpus
def test_the_daemons_own_load_does_not_make_it_move(monkeypatch):
    """A busy thread of this process on the kept CPU, and no other process anywhere: the CPU is fully busy over
    the window the rule judges (the injected clock advances by what the thread took), all of it ours, so the
    threads stay."""

    def body():
        kept = Placement(AUTO)
        kept.start()
        first = kept.cpu
        stop = threading.Event()
        spinner = threading.Thread(target=spin_in_c, args=(stop,))  # started on the pinned thread: inherits its CPU
        spinner.start()
        try:
            start_s = placement.threads_cpu_s(first)

            def ours_s() -> float:  # wait on the spinner's progress, not on the clock
                while placement.threads_cpu_s(first) - start_s < OWN_CPU_S:
                    time.sleep(0.02)
                return placement.threads_cpu_s(first) - start_s

            follow_under(kept, InjectedLoads({}), ours_s, monkeypatch)
        finally:
            stop.set()
            spinner.join()
        return first, kept.cpu, kept.moves, os.sched_getaffinity(0)

    first, now, moves, own = in_thread(body)
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


def stats_when_written(stats: Path, fogd) -> dict:
    """The daemon's stats file, once it has written one."""
    wait_until(stats.exists, watching([stats], [fogd.process]), "the stats file", alive=[fogd.process],
               said=lambda: fogd.stderr)  # fmt: skip
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
        snapshot = stats_when_written(stats, fogd)
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


CLEAR = 0.15  # how far past the rule's thresholds a window this test measures must be to count as the premise
HELD_WINDOWS = 4  # windows of CHECK_EVERY_S in a row with the premise: every check of the daemon's had it
LOOK_WINDOWS = 6  # windows to look for the premise in before skipping


def premise(share: dict[int, float], first: int) -> bool:
    """Over a window this test measured: `first` clearly busier than BUSY_SHARE, another CPU clearly MARGIN less."""
    least = min(share[cpu] for cpu in share if cpu != first)
    return share[first] > BUSY_SHARE + CLEAR and least < share[first] - MARGIN - CLEAR


@two_cpus
def test_the_daemon_moves_off_a_cpu_another_process_takes(tmp_path, model_path):
    """The daemon's loop looks every CHECK_EVERY_S: a process spinning on its CPU moves its threads, with one
    warning that names both CPUs, and every thread goes along. The premise, another CPU clearly less busy,
    is the machine's: the test measures each CPU's load over windows as the daemon does, fails when the premise
    held over HELD_WINDOWS windows in a row and the daemon stayed, and skips when every CPU stays busy."""
    stats, gyro = tmp_path / "stats.json", Pty()
    fogd = start_fogd(tmp_path, gyro.path, model_path, "--stats-file", str(stats))
    windows: list[dict[int, float]] = []
    try:
        first = stats_when_written(stats, fogd)["cpu"]["on"]
        allowed = frozenset(os.sched_getaffinity(0))
        with hog_process(first):
            held, opened = 0, (time.monotonic(), placement.cpu_busy_s(allowed))
            while json.loads(stats.read_text())["cpu"]["moves"] == 0:
                assert fogd.process.poll() is None, fogd.stderr
                time.sleep(0.2)
                now_s = time.monotonic()
                if now_s - opened[0] < placement.CHECK_EVERY_S:
                    continue
                busy_s = placement.cpu_busy_s(allowed)
                windows.append({cpu: (busy_s[cpu] - opened[1][cpu]) / (now_s - opened[0]) for cpu in busy_s})
                held = held + 1 if premise(windows[-1], first) else 0
                opened = (now_s, busy_s)
                assert held < HELD_WINDOWS, f"CPU {first} busy, another idle, and fogd stayed: {windows}"
                if len(windows) >= LOOK_WINDOWS and json.loads(stats.read_text())["cpu"]["moves"] == 0:
                    break
            cpu = json.loads(stats.read_text())["cpu"]
            cpus = thread_cpus(fogd.process.pid)
        assert fogd.terminate()[0] == 0
    finally:
        fogd.kill()
        gyro.close()
    if cpu["moves"] == 0:
        shares = "; ".join(", ".join(f"CPU {c} {100 * s:.0f} %" for c, s in sorted(w.items())) for w in windows)
        pytest.skip(f"every CPU stayed busy (no other CPU {100 * MARGIN:.0f} points less busy than CPU {first} "
                    f"with a process spinning on it), over windows of {placement.CHECK_EVERY_S:g} s: {shares}")  # fmt: skip
    assert cpu["moves"] == 1 and cpu["on"] != first
    assert cpus[fogd.process.pid] == str(cpu["on"]) and str(first) not in cpus.values()
    assert f"CPU {first} busy: other processes took" in fogd.stderr
    assert f"fogd's threads moved to CPU {cpu['on']}" in fogd.stderr
