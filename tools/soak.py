"""Soak test (the suite runs it shortened): the real daemon for ten minutes at 1 kHz behind fogd-emu with every
fault it can inject, SIGHUPs, unplugs, a consumer that stalls and one that goes away and comes back (the output
replugged: fogd reopens its FIFO), metrics clients that reset their connections, then whether every frame is
accounted for (in = out + used as input + dropped by reason + pending), whether the consumer got only whole
lines, and how much the daemon's memory grew. Last, a second daemon writing to stdout whose reader closes the
pipe after three lines (`fogd --out - | head -3`) must exit 0 with one line saying so.

    .venv/bin/python tools/soak.py                 # 600 s
    .venv/bin/python tools/soak.py --duration-s 60 # a quick look
"""

from __future__ import annotations

import argparse
import json
import os
import select
import shutil
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DEMO_MODEL = ROOT / "fogd" / "data" / "demo-model.json"
RATE_HZ = 1000
FAULTS = ["--garbage", "0.002", "--bitflip", "0.002", "--drop", "0.002", "--repeat", "0.002", "--nan", "0.002",
          "--clear-status", "0.002", "--split", "0.002"]  # fmt: skip
WARMUP_S = 60.0  # RSS growth is measured from here (imports, buffers and the estimator's window are settled)


def rss_kib(pid: int) -> int:
    with open(f"/proc/{pid}/status") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    return 0


class Consumer(threading.Thread):
    """Reads fogd's jsonl output from a FIFO (whose writer's last bytes are read before EOF, unlike a pty's),
    stalling for `stall_s` every `every_s` and going away for `away_s` every `replug_every_s` (closing its end:
    fogd's next write fails, EPIPE, and fogd reopens the FIFO once it is back) until `calm` is set; counts
    whole and broken lines, and the bytes of a line it was in the middle of when it went away (`cut`)."""

    def __init__(self, path: str, stall_s: float, every_s: float, replug_every_s: float, away_s: float) -> None:
        super().__init__(name="soak-consumer", daemon=True)
        self.path, self.stall_s, self.every_s = path, stall_s, every_s
        self.replug_every_s, self.away_s = replug_every_s, away_s
        self.lines = self.broken = self.stalls = self.replugs = self.cut = 0
        self.calm = threading.Event()  # no more stalls: the end of the run
        self.fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)  # before fogd opens it for writing

    def run(self) -> None:
        fd = self.fd
        pending = b""
        next_stall = time.monotonic() + self.every_s
        next_replug = time.monotonic() + self.replug_every_s
        writer_seen = False
        try:
            while True:
                if time.monotonic() >= next_stall and not self.calm.is_set():
                    self.stalls += 1
                    time.sleep(self.stall_s)
                    next_stall = time.monotonic() + self.every_s
                if time.monotonic() >= next_replug and writer_seen and not self.calm.is_set():  # (fogd opened it)
                    os.close(fd)  # gone: what the pipe held is lost with it (fogd counted it written)
                    self.cut += bool(pending)
                    pending = b""
                    time.sleep(self.away_s)
                    fd = self.fd = os.open(self.path, os.O_RDONLY | os.O_NONBLOCK)
                    self.replugs += 1
                    next_replug = time.monotonic() + self.replug_every_s
                ready, _, _ = select.select([fd], [], [], 0.2)
                if not ready:
                    continue
                try:
                    data = os.read(fd, 1 << 16)
                except BlockingIOError:
                    continue
                if not data:
                    if writer_seen:
                        break  # fogd closed its end
                    time.sleep(0.05)  # no writer yet
                    continue
                writer_seen = True
                lines = (pending + data).split(b"\n")
                pending = lines.pop()
                for line in lines:
                    try:
                        json.loads(line)
                        self.lines += 1
                    except ValueError:
                        self.broken += 1
        finally:
            os.close(fd)
            if pending:
                self.broken += 1


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration-s", type=float, default=600.0)
    parser.add_argument("--hup-every-s", type=float, default=5.0)
    parser.add_argument("--unplug-every-s", type=float, default=20.0)
    parser.add_argument("--stall-s", type=float, default=4.0)
    parser.add_argument("--stall-every-s", type=float, default=30.0)
    parser.add_argument("--replug-every-s", type=float, default=45.0, help="the consumer goes away this often")
    parser.add_argument("--away-s", type=float, default=2.0, help="for this long")
    parser.add_argument("--reset-every-s", type=float, default=3.0, help="a metrics client resets its connection")
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="fogd-soak-"))
    model = work / "model.json"
    shutil.copy(DEMO_MODEL, model)
    link, out = str(work / "fog0"), str(work / "out.fifo")
    os.mkfifo(out)
    consumer = Consumer(out, args.stall_s, args.stall_every_s, args.replug_every_s, args.away_s)
    consumer.start()
    emu = subprocess.Popen(
        [sys.executable, "-m", "fogd.cli.emu", "--profile", "paper-test", "--rate-hz", str(RATE_HZ), "--protocol",
         "fogd", "--temp-rate-hz", "10", "--loop", "--duration-s", str(args.duration_s + 30), "--link", link,
         "--wait-reader", "--unplug-every-s", str(args.unplug_every_s), "--unplug-for-s", "1", *FAULTS],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    while not os.path.exists(link):
        time.sleep(0.05)
    stderr_path = work / "fogd.stderr"
    metrics_port = free_port()
    with open(stderr_path, "wb") as stderr:
        fogd = subprocess.Popen(
            [sys.executable, "-m", "fogd.cli.daemon", "--port", link, "--protocol", "fogd", "--rate-hz", str(RATE_HZ),
             "--model", str(model), "--out", out, "--out-format", "jsonl", "--status-interval-s", "60",
             "--stats-file", str(work / "stats.json"), "--metrics-port", str(metrics_port)],
            stdout=subprocess.DEVNULL, stderr=stderr,
        )  # fmt: skip
    started = time.monotonic()
    hups, rss_start, rss_peak, next_hup = 0, None, 0, started + args.hup_every_s
    resets, next_reset = 0, started + args.reset_every_s
    try:
        while time.monotonic() - started < args.duration_s:
            time.sleep(0.5)
            if fogd.poll() is not None:
                print(f"soak: fogd exited early ({fogd.returncode}):\n{stderr_path.read_text()[-2000:]}")
                return 1
            now = time.monotonic()
            rss = rss_kib(fogd.pid)
            rss_peak = max(rss_peak, rss)
            if rss_start is None and now - started >= WARMUP_S:
                rss_start = rss
            if now >= next_hup:
                if hups % 2:  # half of the reloads read a freshly replaced model file
                    temporary = model.with_suffix(".tmp")
                    shutil.copy(DEMO_MODEL, temporary)
                    os.replace(temporary, model)
                fogd.send_signal(signal.SIGHUP)
                hups += 1
                next_hup = now + args.hup_every_s
            if now >= next_reset:
                resets += reset_metrics_client(metrics_port)
                next_reset = now + args.reset_every_s
            if now - started >= args.duration_s - args.stall_s - 2.0:
                consumer.calm.set()  # the consumer catches up before the end, so out can be checked line by line
        rss_end = rss_kib(fogd.pid)
        metrics_errors = metrics_client_errors(metrics_port)
        fogd.send_signal(signal.SIGTERM)
        status = fogd.wait(30)
    finally:
        if fogd.poll() is None:
            fogd.kill()
        emu.send_signal(signal.SIGTERM)
        try:
            _, emu_err = emu.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            emu.kill()
            _, emu_err = emu.communicate()
        consumer.join(10)
    text = stderr_path.read_text()
    counters = json.loads(next(line for line in text.splitlines() if line.startswith("fogd.status: counters ")).split("counters ", 1)[1])
    balance, lexer, loop, reader = counters["balance"], counters["lexer"], counters["loop"], counters["reader"]
    dropped = {key: value for key, value in balance["dropped"].items() if value}
    pending = {key: value for key, value in balance["pending"].items() if value}
    print(f"soak: {args.duration_s:g} s at {RATE_HZ} Hz (protocol fogd, out jsonl to a FIFO), faults {' '.join(FAULTS)}, "
          f"unplug every {args.unplug_every_s:g} s for 1 s, SIGHUP every {args.hup_every_s:g} s ({hups} sent), "
          f"consumer stalls {args.stall_s:g} s every {args.stall_every_s:g} s ({consumer.stalls} stalls)")  # fmt: skip
    print(f"emulator: {emu_err.strip().splitlines()[-1] if emu_err.strip() else '-'}")
    print(f"fogd exit {status}; in {balance['in']} = out {balance['out']} + used as input {balance['used_as_input']} "
          f"+ dropped {dropped or 0} + pending {pending or 0}: {'adds up' if balance['adds_up'] else 'DOES NOT ADD UP'}")  # fmt: skip
    print(f"consumer: {consumer.lines} whole lines (fogd counted {balance['out']} written), {consumer.broken} broken")
    print("lexer: " + ", ".join(f"{key} {value}" for key, value in lexer.items() if value))
    writer = counters["writer"]
    lost_at_replugs = balance["out"] - consumer.lines
    print(f"output replugs: the consumer went away {consumer.replugs} times for {args.away_s:g} s, fogd reopened the "
          f"FIFO {writer.get('reopens', 0)} times; {lost_at_replugs} lines written into the pipe it had left "
          f"({consumer.cut} of them cut), lost with it")  # fmt: skip
    print(f"metrics: {resets} clients reset their connections, fogd counted {metrics_errors:g} failed connections; "
          f"tracebacks in the log: {text.count('Traceback')}")  # fmt: skip
    print(f"reader: disconnects {reader['disconnects']} reconnects {reader['reconnects']} "
          f"(unplugged {reader['disconnected_s']:.1f} s); reloads {loop['reloads']} refused {loop['reloads_refused']} "
          f"stuck {loop['reloads_stuck']}")  # fmt: skip
    if rss_start is not None:
        print(f"RSS: {rss_start / 1024:.1f} MiB at {WARMUP_S:g} s -> {rss_end / 1024:.1f} MiB at the end "
              f"(growth {(rss_end - rss_start) / 1024:+.1f} MiB, peak {rss_peak / 1024:.1f} MiB)")  # fmt: skip
    epipe_status, epipe_lines = stdout_closed_by_its_reader(work, model)
    print(f"fogd --out - | head -3: exit {epipe_status}, its log's lines about it: {epipe_lines}")
    # every line written reached the consumer, but those in the pipe each time it went away (at most a pipe's
    # 64 KiB of 150-byte lines, 437, per replug)
    ok = (balance["adds_up"] and consumer.broken == 0 and status == 0
          and 0 <= lost_at_replugs <= 437 * consumer.replugs and writer.get("reopens", 0) >= consumer.replugs > 0
          and metrics_errors >= resets > 0 and "Traceback" not in text
          and epipe_status == 0 and len(epipe_lines) == 1)  # fmt: skip
    print("soak: OK" if ok else "soak: FAILED")
    shutil.rmtree(work, ignore_errors=True)
    return 0 if ok else 1


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def reset_metrics_client(port: int) -> int:
    """A client that sends half a request and resets the connection (RST): 1, or 0 if it could not connect."""
    try:
        client = socket.create_connection(("127.0.0.1", port), timeout=2)
    except OSError:
        return 0
    client.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    try:
        client.sendall(b"GET /metrics HTTP/1.1\r\n")
    except OSError:
        pass
    client.close()
    return 1


def metrics_client_errors(port: int) -> float:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=10) as response:
        text = response.read().decode()
    parts = text.split("\nfogd_metrics_client_errors_total ")
    return float(parts[1].split()[0]) if len(parts) > 1 else float("nan")  # NaN: a fogd that does not count them


def stdout_closed_by_its_reader(work: Path, model: Path) -> tuple[int | None, list[str]]:
    """`fogd --out - | head -3` behind a fresh emulator: fogd's exit status and its log lines about the pipe."""
    link = str(work / "fog1")
    emu = subprocess.Popen([sys.executable, "-m", "fogd.cli.emu", "--profile", "paper-test", "--rate-hz", str(RATE_HZ),
                            "--protocol", "fogd", "--loop", "--duration-s", "120", "--link", link, "--wait-reader"],
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    try:
        while not os.path.exists(link):
            time.sleep(0.05)
        fogd = subprocess.Popen([sys.executable, "-m", "fogd.cli.daemon", "--port", link, "--protocol", "fogd",
                                 "--rate-hz", str(RATE_HZ), "--model", str(model), "--out", "-", "--out-format", "csv"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
        for _ in range(3):
            fogd.stdout.readline()
        fogd.stdout.close()
        try:
            status = fogd.wait(60)
        except subprocess.TimeoutExpired:
            fogd.kill()
            fogd.wait()
            status = None
        log = fogd.stderr.read()
        fogd.stderr.close()
    finally:
        emu.kill()
        emu.wait()
    return status, [line for line in log.splitlines() if "broken pipe" in line.lower() or "Traceback" in line]


if __name__ == "__main__":
    sys.exit(main())
