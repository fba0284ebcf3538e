"""A do-nothing relay: copies bytes from one tty to another as they come, the baseline fogd's latency is
measured against in tools/bench_daemon.py (same ptys, same harness, no framing, no model).

Usage: python tools/bench_relay.py IN_TTY OUT_TTY  (stops on SIGTERM or when the input closes)
"""

from __future__ import annotations

import os
import signal
import sys
import tty


def main(argv: list[str]) -> int:
    source = os.open(argv[0], os.O_RDONLY | os.O_NOCTTY)
    sink = os.open(argv[1], os.O_WRONLY | os.O_NOCTTY)
    for fd in (source, sink):
        tty.setraw(fd)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    while True:
        data = os.read(source, 65536)
        if not data:
            return 0
        view = memoryview(data)
        while view:
            view = view[os.write(sink, view) :]


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
