"""The reader thread: it only reads the gyro's port, frames the bytes with the lexer and pushes the decoded
samples into the ring. It never evaluates the model and never waits for the writer.

Each read waits (poll) up to the port's read timeout for bytes, then takes everything that has arrived in
one `os.read`: a whole frame (or several) per read and per lexer call, not one byte and then the rest
(pyserial's `read(in_waiting or 1)` costs two wake-ups, two reads and two lexer calls per frame). When the
port disappears (a USB unplug: readable with no data, an error or a hang-up) the reader logs it once, drops the
half-received frame, and reopens the same path until it comes back, so a device that returns behind the same
symlink is picked up too. It looks for the path every `PRESENCE_POLL_S` (a stat costs nothing) and opens it as
soon as it appears; opens that fail while the path exists (busy, permission) back off exponentially up to
`BACKOFF_MAX_S`. The rate estimator's state is kept across the gap: the compensator treats the samples after
the gap as following on from those before it (a chamber temperature moves little in a few seconds).

At high frame rates (a small read soon after the one before, `COALESCE_GAP_S`) the reader sleeps half a
millisecond before it reads again, so frames reach the loop several at a time: at 5,000 frames/s that took
fogd's CPU from 22.5-24.8 % of a core to 10.5-13.2 % (tools/bench_daemon.py --design 2, idle machine), below
the single-thread prototype's 15.4-18.0 %, with nothing lost; at 1,000 frames/s it never applies.

A frame costs one wake-up of one thread where it can: `inline`, when the daemon sets it, is offered each read's
frames first and may compensate and write them on this thread (fogd.serving.daemon's `take_inline`: only a few
frames, only when nothing waits in the ring before them and the loop is not busy); what it declines goes into
the ring as before, so a slow step never stops the reading.

`heartbeat_s` is the monotonic time the thread last came round its loop (a read returned, even empty after
the read timeout, or a reopen attempt was made); the daemon's watchdog uses it to tell a hung reader from a
quiet port.
"""

from __future__ import annotations

import logging
import os
import select
import threading
import time
from dataclasses import dataclass, field
from typing import Callable

import serial

from fogd.errors import DeviceError
from fogd.protocols.lexer import Lexer
from fogd.serving.ring import COUNT_NAMES, KIND_NAMES, Ring

log = logging.getLogger("fogd.reader")

BACKOFF_FIRST_S = 0.05
BACKOFF_MAX_S = 2.0
PRESENCE_POLL_S = 0.2
READ_MAX_BYTES = 1 << 16
# At high frame rates, let frames gather: when a small read (a frame or two) came this soon after the one
# before it, the reader sleeps `COALESCE_S` before the next, so each read (and each hand-over to the loop)
# carries several frames instead of one. It never applies at 1,000 frames/s (a frame a millisecond), where
# latency is what counts, nor to large reads, which are batches already; a pty or UART buffer of 4 KiB holds
# a 0.5 ms gather at 50,000 KVH frames/s twice over.
COALESCE_GAP_S = 0.0006
COALESCE_SMALL_BYTES = 256
COALESCE_S = 0.0005
_POLL_IN, _POLL_FAILED = select.POLLIN, select.POLLERR | select.POLLHUP | select.POLLNVAL


@dataclass
class ReaderCounters:
    """What the reader did; the lexer's drop counters are kept by the lexer itself."""

    bytes_in: int = 0
    frames_in: dict[str, int] = field(default_factory=lambda: dict.fromkeys(KIND_NAMES, 0))
    disconnects: int = 0
    reconnects: int = 0
    disconnected_s: float = 0.0  # time without the port: frames sent meanwhile are lost on the wire, uncounted
    # by sequence numbers (KVH's wrap every 128), so the status line estimates them from this and rate_hz


class Reader:
    """Reads `open_port()`'s port into `ring` on its own thread until `stop()`; survives the port going away."""

    def __init__(self, open_port: Callable[[], serial.Serial], lexer: Lexer, ring: Ring, *, port: serial.Serial | None = None,
                 received: bytes = b"") -> None:  # fmt: skip
        """`received`: bytes already read from `port` (fogd.serving.unitquery's), framed before anything else."""
        self._received = received
        self._open_port = open_port
        self.lexer = lexer
        self.ring = ring
        self.port = port
        self.counters = ReaderCounters()
        self.error: BaseException | None = None  # what killed the thread, if anything did
        self.heartbeat_s = time.monotonic()
        self.connected = port is not None
        self._stopping = threading.Event()
        self._lost_at_s = time.monotonic()
        self._thread: threading.Thread | None = None
        # offered each read's frames before the ring; True: handed on already (set by the daemon, see above)
        self.inline: Callable[[list, float], bool] | None = None

    def start(self) -> None:
        """Start (or, after the thread died, restart) reading."""
        self.error = None
        self._thread = threading.Thread(target=self._run, name="fogd-reader", daemon=True)
        self._thread.start()

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def stop(self, timeout_s: float = 1.0) -> None:
        """Ask the thread to finish its current read and stop; closes the port."""
        self._stopping.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
        if not self.alive:
            self._flush_lexer()
        self._close()

    def _run(self) -> None:
        try:
            # each pass frames what the pass before read (first, what unitquery read), then reads: one call
            # fewer a frame than a method to frame each read
            data, self._received = self._received, b""
            t_rx_s = time.monotonic()
            gap_s = 1.0
            poller: select.poll | None = None
            while True:
                if data:
                    self.counters.bytes_in += len(data)
                    frames = self.lexer.feed(data)
                    if frames:
                        self._push(frames, t_rx_s)
                    if gap_s < COALESCE_GAP_S and len(data) < COALESCE_SMALL_BYTES:
                        time.sleep(COALESCE_S)
                if self._stopping.is_set():
                    return
                if self.port is None:
                    if not self._reopen():
                        return
                    poller = None
                if poller is None:
                    poller = select.poll()
                    poller.register(self.port.fd, _POLL_IN)
                    timeout_ms = 1000.0 * (self.port.timeout if self.port.timeout is not None else 0.1)
                try:
                    data = self._read(poller, timeout_ms)
                except (serial.SerialException, OSError) as error:
                    data = b""
                    self._lost(error)
                    continue
                t_rx_s = time.monotonic()
                gap_s, self.heartbeat_s = t_rx_s - self.heartbeat_s, t_rx_s
        except BaseException as error:  # the daemon notices a dead reader through `alive` and `error`
            self.error = error
            raise

    def _read(self, poller: select.poll, timeout_ms: float) -> bytes:
        """Whatever has arrived within the read timeout (b'' if nothing); raises when the port is gone."""
        events = poller.poll(timeout_ms)
        if not events:
            return b""
        if events[0][1] & _POLL_FAILED and not events[0][1] & _POLL_IN:
            raise serial.SerialException("device reports an error or hang-up")
        try:
            data = os.read(self.port.fd, READ_MAX_BYTES)
        except BlockingIOError:  # the port is non-blocking: readiness can be spurious
            return b""
        if not data:  # what pyserial says of a USB adapter pulled out
            raise serial.SerialException("device reports readiness to read but returned no data")
        return data

    def _push(self, frames: list, t_rx_s: float) -> None:
        frames_in, names = self.counters.frames_in, COUNT_NAMES
        for frame in frames:
            frames_in[names.get(frame.kind, "other")] += 1  # 'comp' is 'other': fogd does not re-compensate its own output
        inline = self.inline
        if inline is not None and inline(frames, t_rx_s):
            return
        self.ring.push(frames, t_rx_s)

    def _lost(self, error: BaseException) -> None:
        name = getattr(self.port, "port", "port")
        log.warning("%s: port lost (%s); reopening with backoff", name, error)
        self.counters.disconnects += 1
        self.connected = False
        self._lost_at_s = time.monotonic()
        self._flush_lexer()
        self._close()

    def _flush_lexer(self) -> None:
        """The whole frames still held by the lexer (behind a false header, say) go on; the rest is counted."""
        frames = self.lexer.flush()
        if frames:
            self._push(frames, time.monotonic())

    def _reopen(self) -> bool:
        """Open the port again: at once when its path appears, with backoff while opening it fails; False if
        asked to stop first."""
        delay_s = BACKOFF_FIRST_S
        next_try_s = time.monotonic() + BACKOFF_FIRST_S
        last_message = ""
        path = getattr(self._open_port, "path", None)
        was_present = path is None or os.path.exists(path)
        while not self._stopping.wait(
            min(PRESENCE_POLL_S, max(0.01, next_try_s - time.monotonic())) if was_present else PRESENCE_POLL_S
        ):
            self.heartbeat_s = now_s = time.monotonic()
            present = path is None or os.path.exists(path)
            appeared, was_present = present and not was_present, present
            if not present or (now_s < next_try_s and not appeared):
                continue
            try:
                self.port = self._open_port()
            except DeviceError as error:
                if str(error) != last_message:  # say each new reason once, not once per retry
                    log.info("%s; retrying", error)
                    last_message = str(error)
                next_try_s = time.monotonic() + delay_s
                delay_s = min(2 * delay_s, BACKOFF_MAX_S)
                continue
            self.counters.reconnects += 1
            self.counters.disconnected_s += time.monotonic() - self._lost_at_s
            self.connected = True
            log.warning("%s: port back; reading again", self.port.port)
            return True
        return False

    def _close(self) -> None:
        port, self.port = self.port, None
        if port is not None:
            try:
                port.close()
            except (serial.SerialException, OSError):
                pass
