"""fogd as a service, on the real daemon process and real ptys: sd_notify (READY=1, STATUS=, WATCHDOG=1) to a
socket the test owns; SIGTERM within 2 s; SIGHUP swaps the model between batches with no frame lost (a bad
model refused, the old one kept); SIGUSR1 logs the counters; the stats file, `fogd --status` and the metrics
endpoint; 20 unplug/replug cycles survived; a hung reader withholds the watchdog; a pickle model refused
without running it; bytes sent before the port is opened are kept; the running shares of samples that took the
domain guard's fallback or were clamped, in the status line, the snapshot and the metrics."""

from __future__ import annotations

import json
import os
import pickle
import signal
import socket
import subprocess
import sys
import threading
import time
import tty
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from progress import STALL_S, watching
from stopping import stop_timed
from test_daemon_e2e import (  # noqa: F401
    FOGD,
    RATE_HZ,
    Emu,
    Fogd,
    model_path,
    run_samples,
    start_fogd,
    wait_for_rows,
    write_run,
)

from fogd.core import modelfile
from fogd.core.estimator import EstimatorSettings
from fogd.core.inputs import default_inputs
from fogd.protocols import get
from fogd.protocols.base import ALL_AXES, Frame
from fogd.protocols.lexer import Lexer
from fogd.serving.daemon import READER_STALL_S, Daemon
from fogd.serving.outputs import Formatter, Writer, open_sink
from fogd.serving.reader import Reader
from fogd.serving.ring import Ring
from fogd.serving.serialio import PortOpener, open_port


def linear_model(path: Path, intercept_dph: float, name: str) -> Path:
    """The e2e model with another intercept: same inputs, so the estimator state carries over a swap."""
    doc = modelfile.document(
        name=name, method="linear", inputs=default_inputs(EstimatorSettings(window_s=0.5, average_s=0.05)),
        x_mean=np.zeros(2), x_scale=np.ones(2), y_mean=0.0, y_scale=1.0,
        domain_min=np.array([-40.0, -5.0]), domain_max=np.array([80.0, 5.0]),
        params={"coef": [0.05, 30.0], "intercept": intercept_dph}, reference_dph=0.0, training={}, metrics={},
        created_utc="2024-01-01T00:00:00Z",
    )  # fmt: skip
    modelfile.save(path, doc)
    return path


def replace_file(path: Path, source: Path) -> None:
    temporary = path.with_suffix(".tmp")
    temporary.write_bytes(source.read_bytes())
    os.replace(temporary, path)


def rows(path: Path) -> int:
    return path.read_bytes().count(b"\n") - 1 if path.exists() else 0


def test_port_keeps_bytes_sent_before_it_is_opened():
    master, slave = os.openpty()
    tty.setraw(slave)
    path = os.ttyname(slave)
    os.close(slave)
    try:
        os.write(master, b"frame bytes already on the wire")
        port = open_port(path, 921600)
        try:
            assert port.read(31) == b"frame bytes already on the wire"  # pyserial's own open() would flush them
        finally:
            port.close()
    finally:
        os.close(master)


def test_notify_status_metrics_and_sigterm(tmp_path, model_path):
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    name = f"fogd-test-{os.getpid()}-{time.monotonic_ns()}"
    listener.bind("\0" + name)  # the abstract namespace, as systemd often uses
    listener.settimeout(0.2)
    samples = run_samples("kvh-a")
    write_run(tmp_path / "run.csv", samples)
    emu = Emu(tmp_path, tmp_path / "run.csv", "kvh-a", "--speed", "1", "--loop")
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        metrics_port = probe.getsockname()[1]
    stats = tmp_path / "fogd.json"
    env = {**os.environ, "NOTIFY_SOCKET": "@" + name, "WATCHDOG_USEC": "400000"}
    stderr_path = tmp_path / "fogd.stderr"
    with open(stderr_path, "wb") as stderr:
        process = subprocess.Popen(
            [*FOGD, "--port", emu.path, "--model", str(model_path), "--rate-hz", str(RATE_HZ), "--out", os.devnull,
             "--stats-file", str(stats), "--metrics-port", str(metrics_port)],
            stdout=subprocess.DEVNULL, stderr=stderr, env=env,
        )  # fmt: skip
    messages: list[str] = []
    try:
        progress, moved = watching([stderr_path], [process]), time.monotonic()  # wait on progress, not a deadline
        last = progress()
        while sum(m == "WATCHDOG=1" for m in messages) < 4 or not any(m.startswith("STATUS=") and "samples" in m and not m.startswith("STATUS=0 ") for m in messages):
            assert time.monotonic() - moved < STALL_S and process.poll() is None, (messages, stderr_path.read_text())
            try:
                messages += listener.recv(4096).decode().split("\n")
                moved = time.monotonic()
            except TimeoutError:
                if progress() != last:
                    last, moved = progress(), time.monotonic()
        assert "READY=1" in messages
        assert messages.index("READY=1") < messages.index("WATCHDOG=1")
        status = subprocess.run([*FOGD, "--status", "--stats-file", str(stats)], capture_output=True, text=True, timeout=30)
        assert status.returncode == 0 and " running" in status.stdout and "connected" in status.stdout, status
        with urllib.request.urlopen(f"http://127.0.0.1:{metrics_port}/metrics", timeout=5) as response:
            metrics = response.read().decode()
        assert 'fogd_frames_in_total{kind="imu"}' in metrics and "fogd_connected 1.0" in metrics
        status, slept_s = stop_timed(process, stderr_path.read_text, 5)
        assert status == 0 and slept_s < 2.0  # prompt: asleep, not waiting for a CPU on a busy machine
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
        emu.kill()
        listener.close()
    snapshot = json.loads(stats.read_text())
    assert snapshot["running"] is False and snapshot["counters"]["writer"]["frames_written"] > 0
    status = subprocess.run([*FOGD, "--status", "--stats-file", str(stats)], capture_output=True, text=True, timeout=30)
    assert status.returncode == 3 and "NOT running" in status.stdout


def test_sighup_swaps_the_model_between_batches_and_loses_no_frame(tmp_path, model_path):
    samples = run_samples("kvh-a")
    write_run(tmp_path / "run.csv", samples)
    model = tmp_path / "live-model.json"
    replace_file(model, model_path)
    other = linear_model(tmp_path / "b.json", 100.5, "model-b")  # model_path's intercept is 0.5
    broken = tmp_path / "broken.json"
    broken.write_text('{"format": "fogd-model"')
    out = tmp_path / "out.csv"
    emu = Emu(tmp_path, tmp_path / "run.csv", "kvh-a", "--speed", "1")
    try:
        fogd = start_fogd(tmp_path, emu.path, model, "--out-format", "csv", "--out", str(out))
        try:
            wait_for_rows(out, 600)
            replace_file(model, other)
            fogd.process.send_signal(signal.SIGHUP)
            fogd.wait_for("reloaded: model model-b")
            replace_file(model, broken)
            fogd.process.send_signal(signal.SIGHUP)
            fogd.wait_for("reload refused")
            fogd.process.send_signal(signal.SIGUSR1)
            fogd.wait_for("| counters {")
            emu.finish()
            wait_for_rows(out, len(samples["t_s"]) + 1)
            assert fogd.terminate()[0] == 0
        finally:
            fogd.kill()
    finally:
        emu.kill()
    from test_daemon_e2e import replayed

    output = np.loadtxt(out, delimiter=",", skiprows=1, ndmin=2)
    reference = replayed(tmp_path, model_path, samples)
    assert output.shape == reference.shape  # every frame once: none lost, none doubled at the swap
    np.testing.assert_allclose(output[:, 3], reference[:, 3], rtol=1e-9, atol=1e-12)  # estimator state kept
    step = np.round(output[:, 4] - reference[:, 4], 6)
    swap = int(np.argmax(step != 0))
    assert 0 < swap and set(step[:swap]) == {0.0} and set(step[swap:]) == {100.0}
    assert output[:, 6].tolist() == reference[:, 6].tolist()  # no second warm-up after the swap
    log = fogd.stderr
    assert "estimator state kept" in log and log.count("reload refused") == 1 and "Traceback" not in log


def test_twenty_unplugs_and_replugs(tmp_path, model_path):
    samples = run_samples("fogd")
    write_run(tmp_path / "run.csv", samples)
    out = tmp_path / "out.csv"
    emu = Emu(tmp_path, tmp_path / "run.csv", "fogd", "--speed", "1", "--loop", "--unplug-every-s", "0.35",
              "--unplug-for-s", "0.15")  # fmt: skip
    replugs = 0
    try:
        fogd = start_fogd(tmp_path, emu.path, model_path, "--protocol", "fogd", "--out-format", "csv", "--out", str(out))
        try:
            while replugs < 20:  # each replug is the emulator's progress
                assert emu.process.stdout.readline(), emu.process.stderr.read()
                replugs += 1
                assert fogd.process.poll() is None
            time.sleep(0.3)  # frames of the last connection
            emu.process.send_signal(signal.SIGTERM)
            ledger = emu.finish()
            time.sleep(0.3)
            assert fogd.process.poll() is None
            assert fogd.terminate()[0] == 0
        finally:
            fogd.kill()
    finally:
        emu.kill()
    segments, current = [], []
    for line in ledger:
        if line["sent"] and line["kind"] == "rate":
            current.append(line["t_s"])
        elif not line["sent"] and "unplugged" in line["faults"] and current:
            segments.append(current)
            current = []
    segments.append(current)
    output_t_s = set(np.round(np.loadtxt(out, delimiter=",", skiprows=1, ndmin=2)[:, 0], 6).tolist())
    flowing = [bool(output_t_s & set(np.round(segment, 6).tolist())) for segment in segments if segment]
    assert len(flowing) >= 21 and all(flowing), flowing  # frames after every replug
    log = fogd.stderr
    assert log.count("port lost") >= 20 and log.count("port back") >= 20 and "Traceback" not in log


def test_a_hung_reader_withholds_the_watchdog(tmp_path, model_path):
    release = threading.Event()

    class HangingOpener(PortOpener):
        def __call__(self):  # like a driver stuck in open(): the reader thread never comes back
            release.wait()
            return super().__call__()

    master, slave = os.openpty()
    tty.setraw(slave)
    path = os.ttyname(slave)
    os.close(slave)
    model = modelfile.load(model_path)

    def daemon(reader: Reader) -> Daemon:
        return Daemon(reader=reader, writer=Writer(open_sink(os.devnull, 921600)), formatter=Formatter("csv", get("kvh-a"), 2),
                      model=model, rate_hz=RATE_HZ, axis=2, temp_stale_s=2.0, status_interval_s=60.0)  # fmt: skip

    live = daemon(Reader(PortOpener(path, 921600), Lexer(get("kvh-a")), Ring(1024), port=open_port(path, 921600)))
    (tmp_path / "ttyHANG").touch()  # present, so the reader tries to open it (a missing port is waited for)
    hung = daemon(Reader(HangingOpener(str(tmp_path / "ttyHANG"), 921600), Lexer(get("kvh-a")), Ring(1024)))
    for each in (live, hung):
        each.writer.start()
        each.reader.start()
    try:
        time.sleep(READER_STALL_S + 0.5)
        assert live.healthy(time.monotonic())
        assert hung.reader.alive and not hung.healthy(time.monotonic())
    finally:
        release.set()
        for each in (live, hung):
            each.reader.stop()
            each.writer.close(1.0)
        os.close(master)


class Payload:
    """Unpickling this would create a file: the proof that nothing was executed."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def test_pickle_model_is_refused_without_running_it(tmp_path):
    master, slave = os.openpty()
    tty.setraw(slave)
    path = os.ttyname(slave)
    os.close(slave)
    marker = tmp_path / "payload-ran"
    evil = tmp_path / "model.pkl"
    evil.write_bytes(pickle.dumps(Payload(marker)))
    try:
        result = subprocess.run([*FOGD, "--port", path, "--model", str(evil)], capture_output=True, text=True, timeout=30)
    finally:
        os.close(master)
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 65 and len(lines) == 1 and "pickle" in lines[0], result.stderr
    assert not marker.exists()


def test_shares_of_fallback_and_clamping_in_status_stats_and_metrics(tmp_path):
    """Running counts of OUT_OF_DOMAIN and CLAMPED samples, frame by frame and in one large batch, equal the
    flags the compensator returned; the status line, the snapshot and the metrics carry them."""
    from fogd.serving.prometheus import render

    doc = modelfile.document(
        name="guarded", method="linear", inputs=default_inputs(EstimatorSettings(window_s=0.5, average_s=0.05)),
        x_mean=np.zeros(2), x_scale=np.array([1.0, 0.01]), y_mean=0.0, y_scale=1.0,
        domain_min=np.array([-40.0, -10.0]), domain_max=np.array([24.0, 10.0]),  # clamped above 24 C
        params={"coef": [0.05, 30.0], "intercept": 0.5}, reference_dph=0.0, training={}, metrics={},
        created_utc="2024-01-01T00:00:00Z",
        domain_guard={"points": [[t, 0.0] for t in np.linspace(15.0, 30.0, 31)], "threshold": 0.5,
                      "fallback": {"method": "linear", "params": {"coef": [0.05, 0.0], "intercept": 0.5}}},
    )  # fmt: skip
    (tmp_path / "ttyNONE").touch()
    daemon = Daemon(reader=Reader(PortOpener(str(tmp_path / "ttyNONE"), 921600), Lexer(get("kvh-a")), Ring(1024)),
                    writer=Writer(open_sink(os.devnull, 921600)), formatter=Formatter("csv", get("kvh-a"), 2),
                    model=modelfile.from_document(doc), rate_hz=RATE_HZ, axis=2, temp_stale_s=2.0,
                    status_interval_s=60.0)  # fmt: skip
    assert "| fallback - clamped - |" in daemon.status_line()
    samples = 2000
    # steady at 20 C, then a ramp of 5 C/s (far from the guard's points, which have no rate) up past 24 C
    temps_c = np.r_[np.full(800, 20.0), np.linspace(20.0, 26.0, 1200)].tolist()
    frames = [Frame("kvh-a", "imu", "A", None, None, (0.0, 0.0, 0.0), ALL_AXES, ALL_AXES, t) for t in temps_c]
    t_rx_s = [time.monotonic()] * samples
    one_by_one = [daemon.compensate(frames[i : i + 1], t_rx_s[i : i + 1]).comp.flags for i in range(1800)]
    flags = np.concatenate([*one_by_one, daemon.compensate(frames[1800:], t_rx_s[1800:]).comp.flags]).astype(int)
    out_of_domain, clamped = int(((flags & 32) != 0).sum()), int(((flags & 2) != 0).sum())
    assert 0 < out_of_domain < samples and 0 < clamped < samples
    for part in (flags[:1800], flags[1800:]):  # both flags seen by the per-frame path and the batch path
        assert ((part & 32) != 0).any() and ((part & 2) != 0).any()
    loop = daemon.counters
    assert (loop.samples_compensated, loop.samples_out_of_domain, loop.samples_clamped) == (samples, out_of_domain, clamped)
    shares = f"fallback {100 * (out_of_domain / samples):.1f} % clamped {100 * (clamped / samples):.1f} %"
    assert f"| {shares} | model guarded" in daemon.status_line()
    snapshot = daemon.snapshot()
    assert snapshot["domain_shares"] == {"out_of_domain": out_of_domain / samples, "clamped": clamped / samples}
    assert snapshot["counters"]["loop"]["samples_clamped"] == clamped
    metrics = render(snapshot)
    assert f'fogd_samples_flagged_total{{flag="out_of_domain"}} {float(out_of_domain)!r}' in metrics
    assert f'fogd_samples_flagged_total{{flag="clamped"}} {float(clamped)!r}' in metrics
    assert f'fogd_samples_flagged_share{{flag="clamped"}} {clamped / samples!r}' in metrics


def test_every_request_a_signal_handler_makes_wakes_the_loop_at_once(tmp_path, model_path):
    """SIGTERM, SIGHUP and SIGUSR1 handlers end the loop's wait for frames, so a silent gyro cannot hold a stop,
    a reload or a counters line back (CPython 3.11 can leave that wait with no deadline after a handler)."""
    (tmp_path / "ttyNONE").touch()
    daemon = Daemon(reader=Reader(PortOpener(str(tmp_path / "ttyNONE"), 921600), Lexer(get("kvh-a")), Ring(1024)),
                    writer=Writer(open_sink(os.devnull, 921600)), formatter=Formatter("csv", get("kvh-a"), 2),
                    model=modelfile.load(model_path), rate_hz=RATE_HZ, axis=2, temp_stale_s=2.0,
                    status_interval_s=60.0)  # fmt: skip
    for request in (daemon.request_counters, daemon.request_reload, daemon.stop):
        assert not daemon.ring.wait(0.0)
        request()
        assert daemon.ring.wait(60.0)  # at once: no frame will ever come
        assert daemon.ring.pop() == ([], [])
