"""Baselines for tools/bench_daemon.py on the same ptys: a do-nothing relay that copies bytes from one tty to
another as they come (no framing, no model), and with --threads the same copy split over two Python threads
the way fogd splits it (a reader thread polls and reads, hands each read over through a queue, the main thread
writes): what the hand-over between two threads costs before any work is done.

With --hold-us N the one-thread relay holds each read N microseconds (spinning, the CPU kept busy as work
would keep it) before writing it on: a bare relay that answers as late as a process doing N us of work.

Usage: python tools/bench_relay.py [--threads | --hold-us N] IN_TTY OUT_TTY  (stops on SIGTERM or when the input
closes)
"""

from __future__ import annotations

import os
import queue
import select
import signal
import sys
import threading
import time
import tty


def write_all(sink: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(sink, view) :]


def main(argv: list[str]) -> int:
    threads = argv[:1] == ["--threads"]
    hold_s = float(argv[1]) * 1e-6 if argv[:1] == ["--hold-us"] else 0.0
    source_path, sink_path = argv[-2:]
    source = os.open(source_path, os.O_RDONLY | os.O_NOCTTY)
    sink = os.open(sink_path, os.O_WRONLY | os.O_NOCTTY)
    for fd in (source, sink):
        tty.setraw(fd)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    if not threads:
        clock = time.perf_counter
        while data := os.read(source, 65536):
            if hold_s:
                until = clock() + hold_s
                while clock() < until:
                    pass
            write_all(sink, data)
        return 0
    reads: queue.SimpleQueue[bytes] = queue.SimpleQueue()

    def reader() -> None:
        poller = select.poll()
        poller.register(source, select.POLLIN)
        while True:
            if poller.poll(100):
                reads.put(os.read(source, 65536))

    threading.Thread(target=reader, daemon=True).start()
    while True:
        try:
            write_all(sink, reads.get(timeout=0.05))
        except queue.Empty:
            continue


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
