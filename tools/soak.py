"""Soak test (not in the suite): the real daemon for ten minutes at 1 kHz behind fogd-emu with every fault it
can inject, SIGHUPs, unplugs and a consumer that stalls, then whether every frame is accounted for
(in = out + used as input + dropped by reason + pending), whether the consumer got only whole lines, and how
much the daemon's memory grew.

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
import subprocess
import sys
import tempfile
import threading
import time
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
    stalling for `stall_s` every `every_s` until `calm` is set; counts whole and broken lines."""

    def __init__(self, path: str, stall_s: float, every_s: float) -> None:
        super().__init__(name="soak-consumer", daemon=True)
        self.path, self.stall_s, self.every_s = path, stall_s, every_s
        self.lines = self.broken = self.stalls = 0
        self.calm = threading.Event()  # no more stalls: the end of the run
        self.fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)  # before fogd opens it for writing

    def run(self) -> None:
        fd = self.fd
        pending = b""
        next_stall = time.monotonic() + self.every_s
        writer_seen = False
        try:
            while True:
                if time.monotonic() >= next_stall and not self.calm.is_set():
                    self.stalls += 1
                    time.sleep(self.stall_s)
                    next_stall = time.monotonic() + self.every_s
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
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="fogd-soak-"))
    model = work / "model.json"
    shutil.copy(DEMO_MODEL, model)
    link, out = str(work / "fog0"), str(work / "out.fifo")
    os.mkfifo(out)
    consumer = Consumer(out, args.stall_s, args.stall_every_s)
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
    with open(stderr_path, "wb") as stderr:
        fogd = subprocess.Popen(
            [sys.executable, "-m", "fogd.cli.daemon", "--port", link, "--protocol", "fogd", "--rate-hz", str(RATE_HZ),
             "--model", str(model), "--out", out, "--out-format", "jsonl", "--status-interval-s", "60",
             "--stats-file", str(work / "stats.json")],
            stdout=subprocess.DEVNULL, stderr=stderr,
        )  # fmt: skip
    started = time.monotonic()
    hups, rss_start, rss_peak, next_hup = 0, None, 0, started + args.hup_every_s
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
            if now - started >= args.duration_s - args.stall_s - 2.0:
                consumer.calm.set()  # the consumer catches up before the end, so out can be checked line by line
        rss_end = rss_kib(fogd.pid)
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
    print(f"reader: disconnects {reader['disconnects']} reconnects {reader['reconnects']} "
          f"(unplugged {reader['disconnected_s']:.1f} s); reloads {loop['reloads']} refused {loop['reloads_refused']} "
          f"stuck {loop['reloads_stuck']}")  # fmt: skip
    if rss_start is not None:
        print(f"RSS: {rss_start / 1024:.1f} MiB at {WARMUP_S:g} s -> {rss_end / 1024:.1f} MiB at the end "
              f"(growth {(rss_end - rss_start) / 1024:+.1f} MiB, peak {rss_peak / 1024:.1f} MiB)")  # fmt: skip
    ok = balance["adds_up"] and consumer.broken == 0 and consumer.lines == balance["out"] and status == 0
    print("soak: OK" if ok else "soak: FAILED")
    shutil.rmtree(work, ignore_errors=True)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
