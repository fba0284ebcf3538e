"""The reader-to-compensator ring of frame batches: order, splitting, overruns, receive times, and any
interleaving of pushes and pops, also with the producer on another thread."""

import subprocess
import sys
import threading

from hypothesis import given, settings
from hypothesis import strategies as st

from fogd.protocols.base import Frame
from fogd.protocols.kvh import KvhProtocol
from fogd.protocols.lexer import Lexer
from fogd.serving.reader import Reader
from fogd.serving.ring import Ring


def numbered(start: int, count: int) -> list[Frame]:
    return [Frame("fogd", "rate", "rate", seq=value) for value in range(start, start + count)]


def seqs(popped: tuple[list[Frame], list[float]]) -> list[int]:
    return [frame.seq for frame in popped[0]]


def test_pop_returns_pushed_frames_in_order_with_their_read_times():
    ring = Ring(8)
    assert ring.push(numbered(0, 3), 1.0) == 3
    assert ring.push(numbered(3, 2), 2.0) == 2
    frames, times = ring.pop(4)  # splits the second read's batch
    assert [frame.seq for frame in frames] == [0, 1, 2, 3] and times == [1.0, 1.0, 1.0, 2.0]
    assert ring.pop() == ([Frame("fogd", "rate", "rate", seq=4)], [2.0])
    assert ring.pop() == ([], [])
    assert len(ring) == 0


def test_full_ring_drops_the_newest_and_counts_overruns():
    ring = Ring(4)
    assert ring.push(numbered(0, 6), 0.0) == 4
    assert ring.overruns == 2 and len(ring) == 4
    assert ring.push(numbered(6, 1), 0.0) == 0
    assert ring.overruns == 3
    assert seqs(ring.pop()) == [0, 1, 2, 3]
    assert ring.push(numbered(7, 4), 0.0) == 4  # room again once popped


def test_wait_times_out_empty_and_returns_at_once_with_a_batch():
    ring = Ring(4)
    assert not ring.wait(0.01)
    ring.push(numbered(0, 1), 0.0)
    assert ring.wait(10.0) and ring.wait(10.0)  # the batch taken by the first wait stays poppable
    assert seqs(ring.pop()) == [0] and len(ring) == 0


def test_the_reader_counts_comp_frames_as_other():
    reader = Reader(lambda: None, Lexer(KvhProtocol()), Ring(16))
    reader._push([Frame("fogd", kind) for kind in ("imu", "rate", "temp", "comp", "other", "imu")], 1.0)
    assert reader.counters.frames_in == {"imu": 2, "rate": 1, "temp": 1, "other": 2}


@settings(max_examples=300, deadline=None)
@given(
    st.integers(1, 16),
    st.lists(st.tuples(st.sampled_from(("push", "pop", "wait")), st.integers(0, 20)), max_size=60),
)
def test_any_interleaving_loses_nothing_and_counts_every_drop(capacity, steps):
    ring = Ring(capacity)
    pushed, popped, next_value = [], [], 0
    for action, count in steps:
        if action == "push":
            stored = ring.push(numbered(next_value, count), float(next_value))
            assert stored == min(count, capacity - (len(pushed) - len(popped)))
            pushed.extend(range(next_value, next_value + stored))
            next_value += count
        elif action == "pop":
            frames, times = ring.pop(count or None)
            assert len(frames) <= (count or capacity) and len(times) == len(frames)
            assert all(t <= frame.seq for frame, t in zip(frames, times))  # each frame keeps its read's time
            popped.extend(frame.seq for frame in frames)
        else:
            assert ring.wait(0.0) == (len(pushed) > len(popped))
        assert len(ring) == len(pushed) - len(popped)
    popped.extend(seqs(ring.pop()))
    assert popped == pushed
    assert ring.overruns == next_value - len(pushed)


def test_a_producer_thread_and_a_consumer_keep_order_and_account_for_every_frame():
    ring = Ring(64)
    total, reads = 20000, 7

    def produce() -> None:
        for start in range(0, total, reads):
            ring.push(numbered(start, min(reads, total - start)), float(start))

    producer = threading.Thread(target=produce)
    producer.start()
    got: list[int] = []
    while producer.is_alive() or len(ring):
        if ring.wait(0.01):
            got.extend(seqs(ring.pop(50)))
    producer.join()
    got.extend(seqs(ring.pop()))
    assert got == sorted(got) and len(set(got)) == len(got)
    assert len(got) + ring.overruns == total


def test_a_wake_makes_the_wait_return_and_pop_passes_over_it():
    ring = Ring(8)
    ring.wake()
    assert ring.wait(60.0)  # at once: nothing else would end a minute's wait here
    assert ring.pop() == ([], []) and len(ring) == 0
    ring.push(numbered(0, 2), 1.0)
    ring.wake()
    ring.push(numbered(2, 1), 2.0)
    assert seqs(ring.pop()) == [0, 1, 2] and len(ring) == 0


# A main thread waiting on the ring while a signal handler (fogd's SIGTERM, SIGHUP, SIGUSR1) runs in the wait and
# ends past its deadline: with CPython 3.11's SimpleQueue the wait then went on with no deadline at all.
SIGNALLED_WAITS = """
import signal, time
from fogd.serving.ring import Ring
ring = Ring(8)
def handler(*_):
    time.sleep(0.08)  # longer than the wait's 50 ms
    ring.wake()
signal.signal(signal.SIGALRM, handler)
woken = 0
for _ in range(20):
    signal.setitimer(signal.ITIMER_REAL, 0.02)  # inside the wait
    woken += ring.wait(0.05)
    ring.pop()
print(woken)
"""


def test_a_wait_that_a_waking_signal_handler_runs_past_its_deadline_returns():
    done = subprocess.run([sys.executable, "-c", SIGNALLED_WAITS], capture_output=True, text=True, timeout=30)
    assert done.returncode == 0 and int(done.stdout) == 20, done.stderr
