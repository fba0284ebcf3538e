"""Reading a KVH unit's output settings at start (`query_settings: true`), as public KVH drivers do before
streaming: `=CONFIG,1` (the unit stops streaming and answers), one query per setting (`?ROTFMT`, `?DR`, ...),
then `=CONFIG,0` (streaming again). The replies are found among whatever frames were already on the way and
parsed by fogd.protocols.kvh (those frames are not lost: every byte read is handed to the reader, which frames
it before anything else, the reply lines counted as garbage bytes); a setting the unit reports differently
from the config stops fogd in one line (ConfigError, exit 78), since every value decoded under the wrong
setting would be wrong.
"""

from __future__ import annotations

import logging
import re
import time
from typing import Any, Protocol

from fogd.errors import ConfigError, DeviceError
from fogd.protocols import kvh

log = logging.getLogger("fogd.daemon")

ENTER_CONFIG = b"=CONFIG,1\r\n"
LEAVE_CONFIG = b"=CONFIG,0\r\n"
REPLY_TIMEOUT_S = 3.0
MAX_BYTES = 1 << 20  # of frames and replies read while waiting: a unit that never answers is not read forever
_REPLY = re.compile(rb"(?:%s),[A-Za-z0-9.+-]+(?=\r?\n)" % b"|".join(name.encode() for name in kvh.SETTING_QUERIES))
SETTINGS = ("rotfmt", "angle_unit", "linfmt", "lin_unit", "temp_unit", "rate_hz")  # the config keys they check


class Port(Protocol):
    def write(self, data: bytes) -> Any: ...

    def read(self, size: int) -> bytes: ...


def query_settings(port: Port, path: str, timeout_s: float = REPLY_TIMEOUT_S,
                   received: bytearray | None = None) -> dict[str, object]:  # fmt: skip
    """The unit's settings as kvh-a protocol options (rotfmt, angle_unit, linfmt, lin_unit, temp_unit,
    rate_hz); DeviceError (one line) when it does not answer every query within `timeout_s`. Every byte read
    meanwhile (the frames already on the way, and the replies) is appended to `received`, for the reader to
    frame first: those frames are the unit's too, sent under the settings just checked."""
    try:
        port.write(ENTER_CONFIG + b"".join(kvh.query(name) for name in kvh.SETTING_QUERIES))
        replies = _replies(port, timeout_s, received)
        port.write(LEAVE_CONFIG)
    except OSError as error:
        raise DeviceError(f"{path}: cannot query the unit's settings: {error}") from None
    missing = [name for name in kvh.SETTING_QUERIES if name not in replies]
    if missing:
        raise DeviceError(f"{path}: the unit did not answer ?{', ?'.join(missing)} within {timeout_s:g} s (is it a "
                          "KVH unit that answers queries? set query_settings: false to skip them)")  # fmt: skip
    return kvh.settings_from_replies(list(replies.values()))


def _replies(port: Port, timeout_s: float, received: bytearray | None = None) -> dict[str, bytes]:
    """The first reply line to each query, found in the bytes the port delivers (frames sent before the
    unit entered configuration mode come first)."""
    replies: dict[str, bytes] = {}
    data = b""
    deadline = time.monotonic() + timeout_s
    try:
        while len(replies) < len(kvh.SETTING_QUERIES) and time.monotonic() < deadline and len(data) < MAX_BYTES:
            data += port.read(4096)
            for match in _REPLY.finditer(data):
                line = match.group(0)
                replies.setdefault(line.split(b",", 1)[0].decode("ascii"), line)
    finally:  # every byte read, the replies and the frames around them, goes on to the reader
        if received is not None:
            received += data
    return replies


def check_settings(unit: dict[str, object], settings: dict[str, Any], path: str) -> None:
    """ConfigError naming the first setting the unit reports differently from the config."""
    for key in SETTINGS:
        if key in unit and unit[key] != settings[key]:
            shown = f"{unit[key]:g}" if isinstance(unit[key], float) else unit[key]
            raise ConfigError(f"key '{key}': the unit on {path} reports {key} {shown}, the config says "
                              f"{settings[key]}; set {key}: {shown} (or change the unit's setting)")  # fmt: skip
    log.info("unit settings on %s agree with the config: %s", path,
             ", ".join(f"{key} {unit[key]}" for key in SETTINGS if key in unit))  # fmt: skip
