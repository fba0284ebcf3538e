"""The reader thread on a real pty: whatever has arrived is read at once (frames written together reach the
ring as one read's batch, in order), a frame split across writes is still one frame, and a port that goes
away is noticed and counted, not read in a loop."""

from __future__ import annotations

import os
import time
import tty
from pathlib import Path

from fogd.protocols import get
from fogd.protocols.base import ALL_AXES, Frame
from fogd.protocols.lexer import Lexer
from fogd.serving.reader import Reader
from fogd.serving.ring import Ring
from fogd.serving.serialio import open_port

KVH = get("kvh-a")


def kvh_frame(seq: int) -> bytes:
    return KVH.encode(Frame("kvh-a", "imu", "A", seq, None, (1.0, 2.0, 3.0 + seq), ALL_AXES, ALL_AXES, 20.0))


def wait_for(condition, timeout_s: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.01)
    return False


def pty_reader(link: Path | None = None) -> tuple[int, str, Reader]:
    """A reader on a new pty; it reopens through `link` (made to point at the pty) when given: a /dev/pts number
    is reused by the next pty anyone opens, and other tests run beside this one."""
    master, slave = os.openpty()
    tty.setraw(master)
    path = os.ttyname(slave)
    port = open_port(path, 921600)
    os.close(slave)  # the reader's port is the only slave left open
    if link is not None:
        link.symlink_to(path)
    reopen = str(link or path)
    reader = Reader(lambda: open_port(reopen, 921600), Lexer(KVH), Ring(64), port=port)
    return master, path, reader


def test_frames_written_together_arrive_as_one_read_in_order():
    master, _, reader = pty_reader()
    try:
        reader.start()
        os.write(master, b"".join(kvh_frame(seq) for seq in range(5)))
        assert wait_for(lambda: len(reader.ring) == 5)
        head = kvh_frame(5)
        os.write(master, head[:10])  # a frame split across two writes is one frame
        time.sleep(0.05)
        os.write(master, head[10:])
        assert wait_for(lambda: len(reader.ring) == 6)
        frames, t_rx_s = reader.ring.pop()
        assert [frame.seq for frame in frames] == list(range(6))
        assert len(set(t_rx_s[:5])) == 1 and t_rx_s[5] > t_rx_s[0]  # the first five came in one read
        assert reader.counters.frames_in["imu"] == 6 and reader.counters.bytes_in == 6 * len(head)
        assert reader.lexer.counters.garbage_bytes == 0
    finally:
        reader.stop()
        os.close(master)


def test_a_port_that_goes_away_is_counted_once_and_the_reader_waits_for_it(tmp_path):
    link = tmp_path / "gyro"
    master, _, reader = pty_reader(link)
    try:
        reader.start()
        os.write(master, kvh_frame(0))
        assert wait_for(lambda: len(reader.ring) == 1)
        link.unlink()  # the device is gone, its link too (its /dev/pts number may be another pty's next)
        os.close(master)  # the slave reads EIO or hang-up
        master = -1
        assert wait_for(lambda: reader.counters.disconnects == 1)
        time.sleep(0.3)
        assert reader.counters.disconnects == 1 and not reader.connected and reader.alive
    finally:
        reader.stop()
        if master >= 0:
            os.close(master)


def test_bytes_read_before_the_reader_started_are_framed_first():
    """What the start-up settings query read (frames on the way, and the unit's reply lines) is not lost: its
    frames reach the ring before any frame read later, and the reply counts as garbage bytes."""
    master, path, plain = pty_reader()
    reply = b"?DR,200\r\n"
    early = kvh_frame(0) + reply + kvh_frame(1)
    reader = Reader(lambda: open_port(path, 921600), Lexer(KVH), Ring(64), port=plain.port, received=early)
    try:
        reader.start()
        os.write(master, kvh_frame(2))
        assert wait_for(lambda: len(reader.ring) == 3)
        frames, _ = reader.ring.pop()
        assert [frame.seq for frame in frames] == [0, 1, 2]
        assert reader.counters.frames_in["imu"] == 3 and reader.counters.bytes_in == len(early) + len(kvh_frame(2))
        assert reader.lexer.counters.garbage_bytes == len(reply)
    finally:
        reader.stop()
        os.close(master)
