"""Small YAML files an operator writes (the daemon's config, a production line's manifest), read so that a
mistake or a hostile file is one line and never a hang: bounded in bytes, values and value length, YAML's
safe loader without aliases (an alias bomb expands a few lines into gigabytes), no key appears twice (YAML
would keep the last silently).
"""

from __future__ import annotations

from typing import Any

import yaml

from fogd.core.atomic import read_regular

MAX_YAML_NODES = 10_000
MAX_SCALAR_CHARS = 1024
NEWLINE = b"\n"


class YamlFileError(ValueError):
    """A file that cannot be read as the YAML expected: one line, naming the file (and line)."""


def read_yaml(path: str, what: str, max_bytes: int = 1 << 20) -> Any:
    """The parsed document of `path` (`what` names it in messages: 'a fogd config', 'a manifest'), or
    YamlFileError; an OSError of the read itself is raised as it is, for the caller's own wording."""
    text = read_regular(path, max_bytes)
    if len(text) > max_bytes:
        raise YamlFileError(f"{path}: larger than {max_bytes // 1024} KiB; not {what}")
    _refuse_bytes(path, text, what)
    loader = type("Loader", (_StrictLoader,), {"what": what})
    try:
        return yaml.load(text, Loader=loader)  # noqa: S506 (a SafeLoader, bounded)
    except ValueError as error:  # Python's own limits (a huge integer) surfacing through the constructor
        raise YamlFileError(f"{path}: not {what} ({str(error)[:80]})") from None
    except yaml.YAMLError as error:
        where = getattr(error, "problem_mark", None)
        line = f":{where.line + 1}" if where is not None else ""
        problem = " ".join(str(getattr(error, "problem", None) or error).split())  # one line, whatever YAML says
        raise YamlFileError(f"{path}{line}: not valid YAML ({problem})") from None
    except RecursionError:
        raise YamlFileError(f"{path}: nested too deeply; not {what}") from None


def _refuse_bytes(path: str, text: bytes, what: str) -> None:
    """YamlFileError naming the line of a NUL or a byte that is not UTF-8 (PyYAML's own message takes two lines
    and counts characters, not lines)."""
    nul = text.find(b"\0")
    try:
        text.decode("utf-8")
        bad = None
    except UnicodeDecodeError as error:
        bad = error.start
    if nul >= 0 and (bad is None or nul <= bad):
        raise YamlFileError(f"{path}:{text.count(NEWLINE, 0, nul) + 1}: a NUL byte; not {what}")
    if bad is not None:
        raise YamlFileError(f"{path}:{text.count(NEWLINE, 0, bad) + 1}: byte 0x{text[bad]:02x} is not UTF-8; save the "
                            "file as UTF-8")  # fmt: skip


class _StrictLoader(yaml.SafeLoader):
    what = "this file"

    def compose_node(self, parent: Any, index: Any) -> Any:
        if self.check_event(yaml.AliasEvent):
            raise yaml.composer.ComposerError(None, None, f"aliases (*name) are not allowed in {self.what}",
                                              self.peek_event().start_mark)  # fmt: skip
        self._nodes = getattr(self, "_nodes", 0) + 1
        if self._nodes > MAX_YAML_NODES:
            raise yaml.composer.ComposerError(None, None, f"more than {MAX_YAML_NODES} values; not {self.what}",
                                              self.peek_event().start_mark)  # fmt: skip
        node = super().compose_node(parent, index)
        if isinstance(node, yaml.ScalarNode) and len(node.value) > MAX_SCALAR_CHARS:
            raise yaml.composer.ComposerError(None, None, f"a value longer than {MAX_SCALAR_CHARS} characters",
                                              node.start_mark)  # fmt: skip
        return node

    def construct_mapping(self, node: Any, deep: bool = False) -> Any:
        seen: set[str] = set()
        for key_node, _ in node.value:
            if isinstance(key_node, yaml.ScalarNode):
                if key_node.value in seen:
                    raise yaml.constructor.ConstructorError(
                        None, None, f"key {key_node.value[:40]!r} appears twice", key_node.start_mark
                    )
                seen.add(key_node.value)
        return super().construct_mapping(node, deep=deep)
