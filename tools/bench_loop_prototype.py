"""A minimal single-thread fogd for tools/bench_daemon.py --design: the question whether the daemon's loop
should read the port itself (one poll loop, no reader thread, as gpsd does) before the daemon is changed.

One thread: poll the input fd; read all that has arrived; lex it (fogd's Lexer); compensate its rate frames
(fogd's Daemon.compensate: temperature hold, Compensator, sample clock); encode (fogd's Formatter, 'same');
one non-blocking write of the output. No ring, no reader thread, no writer thread, no duties (status, stats,
watchdog): the floor of that design with fogd's real per-frame work.

With --upto STAGE the loop stops its work after a stage and writes the bytes read as they came (poll: no
lexing; lex: frames decoded, raw bytes out; compensate: compensated but raw bytes out; encode: the whole
prototype, the default): what each stage costs in situ, cold caches and all, beside the relay.

Usage: python tools/bench_loop_prototype.py [--upto poll|lex|compensate|encode] MODEL IN_TTY OUT_TTY
  (stops on SIGTERM or when the input closes)
"""

from __future__ import annotations

import os
import select
import signal
import sys
import time
import tty
from types import SimpleNamespace


def main(argv: list[str]) -> int:
    upto = "encode"
    if argv[0] == "--upto":
        upto, argv = argv[1], argv[2:]
    stages = ("poll", "lex", "compensate", "encode")
    depth = stages.index(upto)
    model_path, source_path, sink_path = argv
    from fogd.core import modelfile
    from fogd.protocols.kvh import KvhProtocol
    from fogd.protocols.lexer import Lexer
    from fogd.serving.daemon import Daemon
    from fogd.serving.outputs import Formatter

    protocol = KvhProtocol(comp_axes=(2,))
    lexer = Lexer(protocol)
    formatter = Formatter("same", protocol, 2)
    daemon = Daemon(reader=SimpleNamespace(ring=None), writer=None, formatter=formatter, model=modelfile.load(model_path),
                    rate_hz=1000.0, axis=2, temp_stale_s=2.0, status_interval_s=3600.0)  # fmt: skip
    source = os.open(source_path, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
    sink = os.open(sink_path, os.O_WRONLY | os.O_NOCTTY | os.O_NONBLOCK)
    for fd in (source, sink):
        tty.setraw(fd)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    poller = select.poll()
    poller.register(source, select.POLLIN)
    pending = b""
    while True:
        if not poller.poll(100):
            continue
        try:
            data = os.read(source, 1 << 16)
        except BlockingIOError:
            continue
        if not data:
            return 0
        if depth == 0:
            pending += data
        else:
            t_rx_s = time.monotonic()
            frames = lexer.feed(data)
            if not frames:
                continue
            if depth == 1:
                pending += data
            else:
                batch = daemon.compensate(frames, [t_rx_s] * len(frames))
                pending += formatter.encode(batch).data if depth == 3 else data
        while pending:  # the harness always reads: a short write is rare (it would be the writer's backlog)
            try:
                pending = pending[os.write(sink, pending) :]
            except BlockingIOError:
                select.select([], [sink], [], 0.1)


if __name__ == "__main__":
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    raise SystemExit(main(sys.argv[1:]))
