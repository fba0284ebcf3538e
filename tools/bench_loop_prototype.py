"""A minimal single-thread fogd for tools/bench_daemon.py --design: the question whether the daemon's loop
should read the port itself (one poll loop, no reader thread, as gpsd does) before the daemon is changed.

One thread: poll the input fd; read all that has arrived; lex it (fogd's Lexer); compensate its rate frames
(fogd's Daemon.compensate: temperature hold, Compensator, sample clock); encode (fogd's Formatter, 'same');
one non-blocking write of the output. No ring, no reader thread, no writer thread, no duties (status, stats,
watchdog): the floor of that design with fogd's real per-frame work.

With --upto STAGE the loop stops its work after a stage and writes the bytes read as they came (poll: no
lexing; lex: frames decoded, raw bytes out; compensate: compensated but raw bytes out; encode: the whole
prototype, the default): what each stage costs in situ, cold caches and all, beside the relay.

With --upto floor it is the least Python that does fogd's job on the common stream (Format A frames, one a read,
the demo model's z axis): check the CRC, unpack, the model's own per-sample code (Compensator.sample on its
InputBank: the lags, the play, the SVR), pack the compensated rate, a fresh CRC, one write; no Frame, no lexer,
no counters, no clock, no WARMING. A frame it cannot take whole is written on as it came. What fogd cannot get
below in CPython on this machine, whatever its threads and objects: the floor its CPU is judged against.

Usage: python tools/bench_loop_prototype.py [--upto poll|lex|compensate|encode|floor] MODEL IN_TTY OUT_TTY
  (stops on SIGTERM or when the input closes)
"""

from __future__ import annotations

import os
import select
import signal
import sys
import time
import tty
from collections.abc import Iterator
from types import SimpleNamespace


def main(argv: list[str]) -> int:
    upto = "encode"
    if argv[0] == "--upto":
        upto, argv = argv[1], argv[2:]
    stages = ("poll", "lex", "compensate", "encode")
    model_path, source_path, sink_path = argv
    if upto == "floor":
        return floor(model_path, source_path, sink_path)
    depth = stages.index(upto)
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
    source, sink = _open(source_path, sink_path)
    for data in _reads(source):
        if depth > 0:
            t_rx_s = time.monotonic()
            frames = lexer.feed(data)
            if not frames:
                continue
            if depth > 1:
                batch = daemon.compensate(frames, [t_rx_s] * len(frames))
                data = formatter.encode(batch).data if depth == 3 else data
        _write_all(sink, data)
    return 0


def floor(model_path: str, source_path: str, sink_path: str) -> int:
    """--upto floor: the fused loop (see the module docstring)."""
    import binascii
    import struct

    from fogd.core import modelfile
    from fogd.core.compensator import Compensator
    from fogd.protocols.crc import MIRRORED_BYTES
    from fogd.protocols.kvh import DPH_PER_RAD_S, HEADER_A

    compensator = Compensator(modelfile.load(model_path), 1000.0)
    sample, bank = compensator.sample, compensator.bank
    body, gyro = struct.Struct(">3f3fBBh"), struct.Struct(">f")
    source, sink = _open(source_path, sink_path)
    for data in _reads(source):
        if len(data) == 36 and data[:4] == HEADER_A and binascii.crc32(data.translate(MIRRORED_BYTES)) == 0xFFFFFFFF:
            x, y, z, ax, ay, az, status, seq, temp = body.unpack_from(data, 4)
            rate_comp_dph = sample(bank, z * DPH_PER_RAD_S, float(temp), True, False)[3]
            out = bytearray(data)
            gyro.pack_into(out, 12, rate_comp_dph / DPH_PER_RAD_S)
            reflected = binascii.crc32(out[:-4].translate(MIRRORED_BYTES)) ^ 0xFFFFFFFF
            out[-4:] = reflected.to_bytes(4, "little").translate(MIRRORED_BYTES)
            data = bytes(out)
        _write_all(sink, data)
    return 0


def _reads(source: int) -> Iterator[bytes]:
    """Each read of what has arrived on `source`, until it closes."""
    poller = select.poll()
    poller.register(source, select.POLLIN)
    while True:
        if not poller.poll(100):
            continue
        try:
            data = os.read(source, 1 << 16)
        except BlockingIOError:
            continue
        if not data:
            return
        yield data


def _write_all(sink: int, data: bytes) -> None:
    """The harness always reads: a short write is rare (it would be the writer's backlog)."""
    while data:
        try:
            data = data[os.write(sink, data) :]
        except BlockingIOError:
            select.select([], [sink], [], 0.1)


def _open(source_path: str, sink_path: str) -> tuple[int, int]:
    source = os.open(source_path, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
    sink = os.open(sink_path, os.O_WRONLY | os.O_NOCTTY | os.O_NONBLOCK)
    for fd in (source, sink):
        tty.setraw(fd)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    return source, sink


if __name__ == "__main__":
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    raise SystemExit(main(sys.argv[1:]))
