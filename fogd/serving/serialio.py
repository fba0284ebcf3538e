"""Opening the gyro's serial port: pyserial with an exclusive lock, the baud rate, no input flush at open,
best-effort low-latency mode, and failures as one-line `DeviceError`s an operator can act on (no such port, busy, no permission).

Low latency (the kernel's ASYNC_LOW_LATENCY flag via TIOCSSERIAL) makes USB-serial drivers hand bytes over
at once instead of every 16 ms; ptys and many drivers refuse it, which costs only latency, so a refusal is
logged at debug level and ignored.
"""

from __future__ import annotations

import errno
import logging
import os

import serial

from fogd.errors import DeviceError

log = logging.getLogger("fogd.serial")

READ_TIMEOUT_S = 0.1  # how long a read waits for a first byte, so the reader notices a stop request quickly


class _Serial(serial.Serial):
    """pyserial's port without the input flush its open() ends with: bytes the gyro sent between our open()
    and that flush would be thrown away, a lost frame at every start and every reconnect (and a race with
    any sender that starts once the port is opened, such as fogd-emu --wait-reader). Bytes sent before the
    port was configured can only be garbage, which the lexer counts and skips."""

    _opening = False

    def open(self) -> None:
        self._opening = True
        try:
            super().open()
        finally:
            self._opening = False

    def _reset_input_buffer(self) -> None:
        if not self._opening:
            super()._reset_input_buffer()


def open_port(path: str, baud: int, *, read_timeout_s: float = READ_TIMEOUT_S) -> serial.Serial:
    """The port at `path`, opened exclusively at `baud` 8N1; raises DeviceError saying why it cannot be."""
    if not os.path.exists(path):
        raise DeviceError(f"{path}: no such port (is the device plugged in? check the path)")
    try:
        port = _Serial(path, baud, timeout=read_timeout_s, write_timeout=1.0, exclusive=True)
    except serial.SerialException as error:
        raise DeviceError(describe_open_error(path, error)) from None
    except (OSError, ValueError) as error:
        raise DeviceError(f"{path}: cannot open: {error}") from None
    try:
        port.set_low_latency_mode(True)
    except (ValueError, OSError, AttributeError) as error:  # AttributeError: platforms without the ioctl
        log.debug("%s: low-latency mode not available (%s)", path, error)
    else:
        log.debug("%s: low-latency mode on", path)
    return port


class PortOpener:
    """`open_port(path, baud)` as a callable the reader calls to reopen; `path` lets it watch for the device."""

    def __init__(self, path: str, baud: int) -> None:
        self.path = path
        self.baud = baud

    def __call__(self) -> serial.Serial:
        return open_port(self.path, self.baud)


def describe_open_error(path: str, error: serial.SerialException) -> str:
    """pyserial's open failure as one line naming the cause and what to do."""
    code = error.errno
    text = str(error)
    if code in (errno.EWOULDBLOCK, errno.EAGAIN) or "exclusively lock" in text:
        return f"{path}: port busy (another program has it open; stop it or choose another port)"
    if code == errno.ENOTTY or "Inappropriate ioctl" in text:
        return f"{path}: not a serial port (not a terminal device; check the path, e.g. /dev/ttyUSB0)"
    if code == errno.ENOENT:
        return f"{path}: no such port (is the device plugged in? check the path)"
    if code in (errno.EACCES, errno.EPERM):
        return f"{path}: permission denied (add the user to the 'dialout' group, or check the udev rule)"
    if code == errno.EBUSY:
        return f"{path}: port busy (another program has it open; stop it or choose another port)"
    return f"{path}: cannot open: {os.strerror(code) if code else text}"
