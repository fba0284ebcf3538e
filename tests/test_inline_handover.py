"""The reader hands a read's few frames on itself (Daemon.take_inline) when nothing waits in the ring and the
loop is not busy, else through the ring: whatever the interleaving of reads, busy loops and drains, the output
is the same bytes in the same order as when every frame goes through the ring, and every frame is accounted
for. The reader and the daemon are the real classes; the reads are real KVH Format A bytes through the real
lexer; the output is a real pipe. The test's thread plays both threads' parts, one step at a time."""

from __future__ import annotations

import os
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st

import fogd
from fogd.core import modelfile
from fogd.protocols.base import ALL_AXES, Frame
from fogd.protocols.kvh import KvhProtocol
from fogd.protocols.lexer import Lexer
from fogd.serving.daemon import INLINE_MAX, Daemon
from fogd.serving.outputs import Formatter, Sink, Writer
from fogd.serving.reader import Reader
from fogd.serving.ring import Ring

MODEL = modelfile.load(str(Path(fogd.__file__).parent / "data" / "demo-model.json"))
FRAME_BYTES = 36


def _stream(count: int) -> bytes:
    protocol = KvhProtocol()
    return b"".join(
        protocol.encode(Frame("kvh-a", "imu", "A", i % 128, None, (1.0, -2.0, 15.0 + 0.01 * i), ALL_AXES, ALL_AXES,
                              20.0 + (i // 40) % 3))  # fmt: skip
        for i in range(count)
    )


class Rig:
    """A daemon whose reader is fed by the test, writing to a pipe the test reads."""

    def __init__(self) -> None:
        self.out_r, out_w = os.pipe()
        os.set_blocking(out_w, False)
        protocol = KvhProtocol(comp_axes=(2,))
        self.writer = Writer(Sink("pipe", out_w, blocking=False, on_close=lambda: os.close(out_w)))
        self.reader = Reader(lambda: None, Lexer(protocol), Ring(1 << 12))
        self.daemon = Daemon(reader=self.reader, writer=self.writer, formatter=Formatter("same", protocol, 2),
                             model=MODEL, rate_hz=1000.0, axis=2, temp_stale_s=2.0, status_interval_s=3600.0)  # fmt: skip
        self.writer.start(b"")
        self.reader.inline = self.daemon.take_inline
        self.clock_s = 0.0

    def read(self, data: bytes) -> None:
        """What the reader thread does with one read."""
        self.clock_s += 0.001
        frames = self.reader.lexer.feed(data)
        if frames:
            self.reader._push(frames, self.clock_s)

    def drain(self) -> None:
        """What the loop thread does when the ring has frames."""
        with self.daemon._handing_on:
            self.daemon._drain()

    def finish(self) -> bytes:
        self.drain()
        assert self.writer.close(5.0)
        chunks = []
        while chunk := os.read(self.out_r, 1 << 16):
            chunks.append(chunk)
        os.close(self.out_r)
        return b"".join(chunks)


def _through_the_ring(data: bytes, reads: list[int]) -> bytes:
    """The reference: the loop busy at every read, so every frame goes through the ring."""
    rig = Rig()
    offset = 0
    for size in reads:
        with rig.daemon._handing_on:
            rig.read(data[offset : offset + size])
        rig.drain()
        offset += size
    return rig.finish()


def test_a_few_frames_with_an_idle_loop_are_handed_on_by_the_reader_and_the_rest_wait_in_the_ring():
    data = _stream(3 * INLINE_MAX)
    rig = Rig()
    rig.read(data[:FRAME_BYTES])
    assert len(rig.reader.ring) == 0 and rig.daemon.counters.samples_compensated == 1  # handed on at once
    with rig.daemon._handing_on:  # the loop busy (its duties, say): the reader must not wait for it
        rig.read(data[FRAME_BYTES : 2 * FRAME_BYTES])
    assert len(rig.reader.ring) == 1 and rig.daemon.counters.samples_compensated == 1
    rig.read(data[2 * FRAME_BYTES : 3 * FRAME_BYTES])  # the loop idle, but a frame waits before this one
    assert len(rig.reader.ring) == 2 and rig.daemon.counters.samples_compensated == 1
    rig.drain()
    big = data[3 * FRAME_BYTES : (3 + INLINE_MAX + 1) * FRAME_BYTES]
    rig.read(big)  # a large read is a batch for the loop's array path
    assert len(rig.reader.ring) == INLINE_MAX + 1
    out = rig.finish()
    assert len(out) == (4 + INLINE_MAX) * FRAME_BYTES
    seqs = [out[i + 29] for i in range(0, len(out), FRAME_BYTES)]
    assert seqs == list(range(4 + INLINE_MAX))
    assert rig.daemon.balance()["adds_up"]


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.integers(1, 2 * INLINE_MAX), st.booleans(), st.booleans()), min_size=1, max_size=40))
def test_any_interleaving_gives_the_bytes_the_ring_alone_gives_in_order_and_accounts_for_every_frame(steps):
    """steps: (frames in the read, the loop busy during it, the loop drains after it)."""
    total = sum(size for size, _, _ in steps)
    data = _stream(total)
    reads = [size * FRAME_BYTES for size, _, _ in steps]
    rig = Rig()
    offset = 0
    for (size, busy, drains), length in zip(steps, reads):
        if busy:
            with rig.daemon._handing_on:
                rig.read(data[offset : offset + length])
        else:
            rig.read(data[offset : offset + length])
        if drains:
            rig.drain()
        offset += length
    out = rig.finish()
    assert out == _through_the_ring(data, reads)
    assert len(out) == total * FRAME_BYTES
    balance = rig.daemon.balance()
    assert balance["adds_up"] and balance["out"] == total
