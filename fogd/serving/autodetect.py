"""`protocol: auto` on the daemon's port: read it until fogd.protocols.detect names the protocol, before the
reader starts. The bytes read meanwhile are returned whole: the reader frames them first with the protocol
found (as it does the settings query's), so no frame seen during detection is lost.

fogd says in one line which protocol it found and the rate it measured; when nothing is recognised within
`WARN_AFTER_S`, it says once what the bytes look like and which protocols it tried, and keeps listening (a unit
switched on later, or set to the right output format, is then found). systemd is told READY and the watchdog
is kept fed meanwhile: a daemon waiting for its unit is up, not stuck starting.
"""

from __future__ import annotations

import logging
import os
import select
import threading
import time
from collections.abc import Callable, Sequence

from fogd.errors import DeviceError
from fogd.protocols import Protocol
from fogd.protocols.detect import Detector, Found
from fogd.serving.sdnotify import Notifier

log = logging.getLogger("fogd.daemon")

WARN_AFTER_S = 3.0
POLL_S = 0.1
READ_MAX_BYTES = 1 << 16


def detect(port, path: str, candidates: Sequence[Protocol], *, stopping: threading.Event, received: bytes = b"",
           notifier: Notifier | None = None, warn_after_s: float = WARN_AFTER_S, until_s: float | None = None,
           clock: Callable[[], float] = time.monotonic) -> tuple[Found, bytes] | None:  # fmt: skip
    """(what was found, every byte read) once a candidate is recognised; None when `stopping` is set or the
    clock reaches `until_s` (the daemon's duration) first. Raises DeviceError when the port goes away first."""
    detector = Detector(candidates)
    tried = ", ".join(detector.names)
    if notifier is not None:
        notifier.send("READY=1", f"STATUS=detecting the protocol on {path} ({tried})")
    poller = select.poll()
    poller.register(port.fd, select.POLLIN)
    start_s = clock()
    warned = False
    data: bytes | None = received
    lost = ""
    while not stopping.is_set() and (until_s is None or clock() < until_s):
        # a verdict when a read brings a long enough run, or when the bytes pause (nothing came in POLL_S) or
        # stop (the port went away: the reader reopens it) after a run too short to measure
        found = detector.feed(data, clock()) if data else detector.settle()
        if found is None and data is None:
            raise DeviceError(f"{path}: port lost while detecting its protocol ({lost})")
        if found is not None:
            log.log(logging.WARNING if warned else logging.INFO,  # after the warning, at its level
                    "protocol auto: %s on %s (%d valid frames in a row, %.2f s of the stream; %s)", found.name, path,
                    found.frames, found.span_s, rate_text(found))  # fmt: skip
            return found, detector.held
        if not warned and clock() - start_s >= warn_after_s:
            warned = True
            if detector.bytes_seen:
                log.warning("protocol auto: nothing recognised on %s in %g s: %s (%d bytes read); tried %s; still "
                            "listening. Set --protocol, or check --baud and the unit's output format",
                            path, warn_after_s, detector.describe(), detector.bytes_seen, tried)  # fmt: skip
            else:
                log.warning("protocol auto: nothing read from %s in %g s; still listening for %s. Is the unit on, "
                            "streaming, and on this port?", path, warn_after_s, tried)  # fmt: skip
        if notifier is not None:
            notifier.send("WATCHDOG=1")
        try:
            data = _read(poller, port)
        except OSError as error:
            data, lost = None, error.strerror or "hang-up"
    return None


def rate_text(found: Found) -> str:
    if found.rate_hz is None:
        return "rate not measured: the frames came all at once and carry no time"
    source = "by the device's clock" if found.rate_from == "device time" else "as they arrived"
    return f"{found.rate_hz:.4g} samples/s {source}"


def _read(poller: select.poll, port) -> bytes:
    """What arrived within POLL_S (b'' if nothing); OSError when the port is gone."""
    if not poller.poll(1000.0 * POLL_S):
        return b""
    try:
        data = os.read(port.fd, READ_MAX_BYTES)
    except BlockingIOError:
        return b""
    if not data:
        raise OSError(0, "hang-up")
    return data
