"""The ring buffer between the reader thread and the compensation loop: a bounded queue of frame batches,
one producer and one consumer, counted in frames.

Each entry is one read's decoded `Frame`s with the time that read returned; the frames are handed over as
the lexer made them (no per-frame copy into and out of a numpy record). The producer never waits: frames that
do not fit in the `capacity` left are dropped (the newest) and counted as overruns. The consumer can block in
`wait` until a batch arrives (a C-level lock in `queue.SimpleQueue`, no Python `Condition` per frame) and pops
batches up to a frame count, splitting a batch when it must, so order is kept and nothing is lost or doubled.
The frame count `pushed - popped` has one writer per counter, so no lock is needed for it. `wake` makes a
wait return at once, from a signal handler too: CPython 3.11's `SimpleQueue.get(timeout=...)`, when a signal
handler runs inside it and the deadline passes meanwhile, goes on waiting with no deadline (a stop with no
frames arriving would never return); the handler's own `wake` is what the wait then returns with.
"""

from __future__ import annotations

import queue
from collections import deque

from fogd.protocols.base import Frame

KIND_NAMES = ("imu", "rate", "temp", "other")  # how the reader counts frames in ('comp' frames are 'other')
COUNT_NAMES = {kind: kind for kind in KIND_NAMES[:3]}  # counted under their own kind; the rest under 'other'
RATE_KINDS = frozenset(("imu", "rate"))  # frames carrying a gyro rate the daemon compensates
TEMP_KINDS = frozenset(("imu", "temp"))  # frames whose temperature the daemon holds


class Ring:
    """Single-producer, single-consumer ring of frame batches holding at most `capacity` frames."""

    def __init__(self, capacity: int) -> None:
        if capacity < 1:
            raise ValueError(f"ring capacity must be at least 1, not {capacity}")
        self.capacity = capacity
        self._queue: queue.SimpleQueue[tuple[float, list[Frame]]] = queue.SimpleQueue()
        self._taken: deque[tuple[float, list[Frame]]] = deque()  # off the queue, not yet popped (consumer only)
        self.pushed = 0  # frames ever stored (written by the producer only): empty while pushed == popped
        self.popped = 0  # frames ever popped (written by the consumer only)
        self.overruns = 0  # frames dropped because the ring was full (producer only)

    def __len__(self) -> int:
        return self.pushed - self.popped

    def push(self, frames: list[Frame], t_rx_s: float) -> int:
        """Append as many of one read's `frames` as fit; the rest is dropped and counted. Returns the number
        stored. `t_rx_s` is the monotonic time the read that completed them returned."""
        free = self.capacity - (self.pushed - self.popped)
        count = len(frames)
        if count > free:
            self.overruns += count - max(free, 0)
            count = max(free, 0)
            frames = frames[:count]
        if count == 0:
            return 0
        self.pushed += count  # counted before it is visible: a pop never makes the length negative
        self._queue.put((t_rx_s, frames))
        return count

    def wake(self) -> None:
        """Make the consumer's current (or next) `wait` return True at once; safe in a signal handler
        (`SimpleQueue.put` is reentrant). It queues an empty batch, which `pop` passes over."""
        self._queue.put((0.0, []))

    def wait(self, timeout_s: float) -> bool:
        """Block until a batch can be popped or `timeout_s` passes; True if one can."""
        if self._taken:
            return True
        try:
            self._taken.append(self._queue.get(timeout=timeout_s))
        except queue.Empty:
            return False
        return True

    def pop(self, max_count: int | None = None) -> tuple[list[Frame], list[float]]:
        """Remove up to `max_count` of the oldest frames, oldest first, with each one's receive time."""
        limit = self.capacity if max_count is None else max_count
        taken, pending = self._taken, self._queue
        if len(taken) == 1 and len(taken[0][1]) <= limit and pending.empty():  # the usual pop: one read's
            t_rx_s, batch = taken.popleft()  # frames, waited for, nothing behind them: handed on as they are
            self.popped += len(batch)
            return batch, [t_rx_s] * len(batch)
        frames: list[Frame] = []
        times: list[float] = []
        while len(frames) < limit:
            if taken:
                t_rx_s, batch = taken.popleft()
            elif not pending.empty():
                t_rx_s, batch = pending.get_nowait()
            else:
                break
            room = limit - len(frames)
            if len(batch) > room:  # the rest stays first in line
                taken.appendleft((t_rx_s, batch[room:]))
                batch = batch[:room]
            frames += batch
            times += [t_rx_s] * len(batch)
        self.popped += len(frames)
        return frames, times
