"""systemd's notify protocol without the systemd package: datagrams such as `READY=1`, `STATUS=...` and
`WATCHDOG=1` sent to the unix socket named by `$NOTIFY_SOCKET` (a path, or '@name' for the abstract
namespace). Outside systemd (no `NOTIFY_SOCKET`) every call does nothing. Sends never block: a message the
manager's queue cannot take is dropped (logged once). The watchdog interval is half of
`$WATCHDOG_USEC`, as sd_watchdog_enabled(3) advises, and only when `$WATCHDOG_PID` is unset or is this process.
"""

from __future__ import annotations

import logging
import os
import socket

log = logging.getLogger("fogd.systemd")


class Notifier:
    """One process's channel to its service manager; `send` never raises."""

    def __init__(self, environ: dict[str, str] | None = None) -> None:
        environ = os.environ if environ is None else environ
        address = environ.get("NOTIFY_SOCKET", "")
        self.address = "\0" + address[1:] if address.startswith("@") else address
        self.watchdog_interval_s = _watchdog_interval_s(environ)
        self._socket: socket.socket | None = None
        self._failed = False
        if self.address:
            self._socket = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)

    @property
    def enabled(self) -> bool:
        return self._socket is not None

    def send(self, *fields: str) -> bool:
        """Send `KEY=value` fields in one datagram; False (logged once) if the manager cannot be reached."""
        if self._socket is None:
            return False
        try:
            # never wait: a service manager that stops reading must not stall the compensation loop
            self._socket.sendto("\n".join(fields).encode("utf-8", "replace"), socket.MSG_DONTWAIT, self.address)
        except OSError as error:
            if not self._failed:
                log.warning("cannot notify the service manager at %r: %s", self.address.replace("\0", "@"), error)
                self._failed = True
            return False
        self._failed = False
        return True

    def close(self) -> None:
        if self._socket is not None:
            self._socket.close()
            self._socket = None


def _watchdog_interval_s(environ: dict[str, str]) -> float | None:
    """Half of WATCHDOG_USEC, or None when no watchdog is asked of this process."""
    try:
        usec = int(environ.get("WATCHDOG_USEC", ""))
    except ValueError:
        return None
    pid = environ.get("WATCHDOG_PID")
    if usec <= 0 or (pid and pid != str(os.getpid())):
        return None
    return usec / 2e6
