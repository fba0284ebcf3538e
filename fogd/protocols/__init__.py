"""The table of wire protocols fogd speaks, like gpsd's driver table: `get(name, **options)` builds one,
`names()` lists them. Every protocol has the same shape (`Protocol` in base.py) and decodes to `Frame`.

- `kvh-a`: KVH DSP-1750/1760/1775 binary Format A (also B, C and BIT replies), kvh.py
- `fogd`: fogd's own binary rate / temperature / compensated-output frames, fogdbin.py
- `ascii`: KVH DSP-3000 lines and fogd's R/T/I/C lines, ascii.py

The byte-driven lexer that finds frames of any of them in a stream is lexer.py. Protocols know bytes and
frames only: they never import the model, the core, the daemon or the command line.
"""

from ..errors import UsageError
from .ascii import AsciiProtocol
from .base import Frame, FrameError, Protocol
from .fogdbin import FogdProtocol
from .kvh import KvhProtocol

_PROTOCOLS: dict[str, type[Protocol]] = {
    KvhProtocol.name: KvhProtocol,
    FogdProtocol.name: FogdProtocol,
    AsciiProtocol.name: AsciiProtocol,
}


def names() -> list[str]:
    """The protocol names `get` accepts."""
    return list(_PROTOCOLS)


def get(name: str, **options: object) -> Protocol:
    """A protocol instance by name; `options` go to its constructor (ConfigError when they are bad)."""
    try:
        protocol_class = _PROTOCOLS[name]
    except KeyError:
        raise UsageError(f"unknown protocol {name!r}; valid protocols: {', '.join(_PROTOCOLS)}") from None
    try:
        return protocol_class(**options)
    except TypeError as error:
        raise UsageError(f"{name}: {error}") from None


__all__ = ["Frame", "FrameError", "Protocol", "get", "names"]
