"""Issue 35 items 7-9 with the real daemon on real ptys: an output device that goes away and comes back is
reopened; stdout's reader closing the pipe ends fogd; a reader that reconnects to `--out pty:PATH` gets the
header and live frames, never the frames sent while nobody held it."""

from __future__ import annotations

import os
import select
import subprocess
import threading
import time
from pathlib import Path

import pytest
from stopping import stop
from test_daemon_e2e import FOGD, Fogd, Pty, gyro, model_path, start_fogd  # noqa: F401  (fixtures)

from fogd.protocols import get
from fogd.protocols.base import ALL_AXES, Frame

KVH = get("kvh-a")
NEWLINE = b"\n"
WAIT_S = 60.0  # generous: these wait on progress, never assert how long it took


class Feeder(threading.Thread):
    """Sends KVH frames to the gyro pty, 10 every 10 ms (about 1,000/s), until `done` is set; `sent` counts them."""

    def __init__(self, port: Pty) -> None:
        super().__init__(name="feeder", daemon=True)
        self.port, self.sent, self.done = port, 0, threading.Event()

    def run(self) -> None:
        while not self.done.is_set():
            data = b"".join(KVH.encode(Frame("kvh-a", "imu", "A", (self.sent + i) % 128, None, (1.0, -1.0, 3.0),
                                             ALL_AXES, ALL_AXES, 25.0)) for i in range(10))  # fmt: skip
            try:
                os.write(self.port.master, data)
            except OSError:
                return
            self.sent += 10
            time.sleep(0.01)


@pytest.fixture
def feeder(gyro):  # noqa: F811
    thread = Feeder(gyro)
    yield thread
    thread.done.set()
    if thread.is_alive():
        thread.join(5.0)


def read_lines(fd: int, count: int, into: bytearray | None = None) -> list[bytes]:
    """At least `count` whole lines from `fd` (waiting on progress up to WAIT_S)."""
    data = into if into is not None else bytearray()
    deadline = time.monotonic() + WAIT_S
    while data.count(b"\n") < count:
        assert time.monotonic() < deadline, f"only {bytes(data).count(NEWLINE)} lines: {bytes(data[-300:])!r}"
        ready, _, _ = select.select([fd], [], [], 0.2)
        if ready:
            try:
                data.extend(os.read(fd, 65536))
            except (BlockingIOError, OSError):
                time.sleep(0.01)
    return bytes(data).split(b"\n")[:-1]


def test_stdout_closed_by_its_reader_ends_fogd(tmp_path, gyro, model_path, feeder):  # noqa: F811
    """`fogd --out - | head -3` ran on forever after EPIPE, counting every frame dropped and feeding the watchdog."""
    stderr_path = tmp_path / "fogd.stderr"
    with open(stderr_path, "wb") as stderr:
        process = subprocess.Popen([*FOGD, "--port", gyro.path, "--model", str(model_path), "--protocol", "kvh-a",
                                    "--rate-hz", "1000", "--out", "-", "--out-format", "csv", "--status-interval-s", "60"],
                                   stdout=subprocess.PIPE, stderr=stderr)  # fmt: skip
    try:
        feeder.start()
        for _ in range(3):  # head -3
            assert process.stdout.readline()
        process.stdout.close()
        status = process.wait(WAIT_S)
    finally:
        if process.poll() is None:
            stop(process, stderr_path.read_text)
    text = stderr_path.read_text()
    assert status in (0, 74), text
    assert "Traceback" not in text
    assert [line for line in text.splitlines() if "broken pipe" in line.lower()] == [
        "fogd.daemon: output stdout closed by its reader (broken pipe); stopping"]


def relink(link: Path, target: str) -> None:
    temporary = link.with_name(link.name + ".new")
    os.symlink(target, temporary)
    os.replace(temporary, link)


def test_an_output_device_that_comes_back_is_reopened(tmp_path, gyro, model_path, feeder):  # noqa: F811
    """A consumer's pty closed and re-created behind the same link (a USB-serial output replugged): fogd used to
    drop every later frame as a write error and never write to it again."""
    link = tmp_path / "out-link"
    consumer = Pty()
    relink(link, consumer.path)
    fogd = start_fogd(tmp_path, gyro.path, model_path, "--protocol", "kvh-a", "--out", str(link), "--out-format", "csv")
    replugged = None
    try:
        feeder.start()
        read_lines(consumer.master, 5)
        consumer.close()  # unplugged: fogd's writes fail
        time.sleep(0.3)  # (frames flow meanwhile: the writes fail and are counted)
        replugged = Pty()
        relink(link, replugged.path)
        rows = read_lines(replugged.master, 20)
        assert all(row.count(b",") == 6 for row in rows[1:])
        status, _ = fogd.terminate()
    finally:
        fogd.kill()
        if replugged is not None:
            replugged.close()
    assert status == 0, fogd.stderr
    counters = fogd.counters()
    assert counters["writer"]["reopens"] >= 1
    assert counters["writer"]["frames_dropped_error"] > 0
    assert counters["balance"]["adds_up"], counters["balance"]
    assert "reopened after" in fogd.stderr


def test_a_reader_reconnecting_to_a_pty_output_gets_no_stale_frames(tmp_path, gyro, model_path, feeder):  # noqa: F811
    """After 6 s away a reader used to get 1,040 stale rows before live data (KVH frames carry no time)."""
    link = tmp_path / "fog-out"
    fogd = start_fogd(tmp_path, gyro.path, model_path, "--protocol", "kvh-a", "--out", f"pty:{link}", "--out-format", "csv")
    try:
        feeder.start()
        reader = os.open(link, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
        first = read_lines(reader, 10)
        assert first[0].startswith(b"t_s,")
        os.close(reader)
        away_from = feeder.sent
        while feeder.sent < away_from + 1000:  # a second of frames while nobody holds the pty
            time.sleep(0.05)
        back_at = feeder.sent
        reader = os.open(link, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
        again = read_lines(reader, 5)
        os.close(reader)
        status, _ = fogd.terminate()
    finally:
        fogd.kill()
    assert status == 0, fogd.stderr
    assert again[0].startswith(b"t_s,"), again[:3]  # the header first, for the new reader
    first_t_s = float(again[1].split(b",")[0])
    # t_s counts samples at 1,000 Hz: the first row after the reconnect is one sent after it (a few in flight)
    assert first_t_s * 1000 >= back_at - 50, (first_t_s, away_from, back_at)
    counters = fogd.counters()
    assert counters["writer"]["frames_dropped_no_reader"] >= 900
    assert counters["balance"]["adds_up"], counters["balance"]


def test_the_watchdog_is_not_fed_while_the_output_takes_nothing(tmp_path, gyro, model_path):  # noqa: F811
    """The output gone for longer than the watchdog's interval: the daemon is alive but useless, so the ping
    stops and systemd restarts it (it used to be fed all along). Time is injected into `healthy`."""
    from fogd.core import modelfile
    from fogd.protocols.lexer import Lexer
    from fogd.serving.daemon import Daemon
    from fogd.serving.outputs import Chunk, Formatter, Writer, open_sink
    from fogd.serving.reader import Reader
    from fogd.serving.ring import Ring
    from fogd.serving.sdnotify import Notifier
    from fogd.serving.serialio import PortOpener, open_port

    link, consumer = tmp_path / "out-link", Pty()
    relink(link, consumer.path)
    daemon = Daemon(reader=Reader(PortOpener(gyro.path, 921600), Lexer(KVH), Ring(1024), port=open_port(gyro.path, 921600)),
                    writer=Writer(open_sink(str(link), 921600)), formatter=Formatter("csv", KVH, 2),
                    model=modelfile.load(model_path), rate_hz=1000.0, axis=2, temp_stale_s=2.0, status_interval_s=60.0,
                    notifier=Notifier({"WATCHDOG_USEC": "1000000"}))  # fmt: skip
    daemon.writer.start()
    daemon.reader.start()
    replugged = None
    try:
        daemon.writer.submit(Chunk(b"row\n", [4]))
        assert read_lines(consumer.master, 1) == [b"row"]
        consumer.close()
        deadline = time.monotonic() + WAIT_S
        while daemon.writer.counters.frames_dropped_error == 0:  # writes fail from now on
            assert time.monotonic() < deadline
            daemon.writer.submit(Chunk(b"row\n", [4]))
            time.sleep(0.02)
        now_s = time.monotonic()
        assert daemon.healthy(now_s)  # within WatchdogSec (1 s): still fed, the output may come back
        assert not daemon.healthy(now_s + 1.5)  # (a reader is stuck only after READER_STALL_S, 2 s)
        replugged = Pty()
        relink(link, replugged.path)
        while daemon.writer.counters.reopens == 0:
            assert time.monotonic() < deadline
            daemon.writer.submit(Chunk(b"row\n", [4]))
            time.sleep(0.02)
        read_lines(replugged.master, 1)
        assert daemon.healthy(time.monotonic() + 1.5)
    finally:
        daemon.reader.stop()
        daemon.writer.close(1.0)
        if replugged is not None:
            replugged.close()
