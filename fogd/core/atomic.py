"""Files are read safely and written whole or not at all: every output goes to a temporary file in its own directory, is
fsynced and renamed over the old one (then the directory is fsynced), so a full disk, a crash or a kill leaves
the old file as it was. An output that is one of the command's inputs (the same inode, through any symlink or
hard link) is refused before anything is written. Models and configs are read only from regular files.
"""

from __future__ import annotations

import errno
import os
import stat
import tempfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from typing import IO

from fogd.errors import UsageError


def refuse_inputs(output: str, inputs: Iterable[str | os.PathLike[str]]) -> None:
    """UsageError when `output` is the same file as one of `inputs` (writing it would destroy the input)."""
    try:
        out_stat = os.stat(output)
    except OSError:
        return  # not there yet (or unreadable): it cannot be an input we read
    for name in inputs:
        try:
            in_stat = os.stat(name)
        except OSError:
            continue
        if (in_stat.st_dev, in_stat.st_ino) == (out_stat.st_dev, out_stat.st_ino):
            raise UsageError(f"output {output} is the input {os.fspath(name)}; refusing to overwrite an input")


@contextmanager
def replaced(path: str, *, inputs: Iterable[str | os.PathLike[str]] = (), binary: bool = False) -> Iterator[IO]:
    """A stream whose contents replace `path` when the block ends without an exception; raises OSError (the
    old file untouched, no temporary file left) when the file cannot be written. A symlink's target is replaced."""
    refuse_inputs(path, inputs)
    target = os.path.realpath(path)
    directory = os.path.dirname(target) or "."
    os.makedirs(directory, exist_ok=True)
    fd, temporary = tempfile.mkstemp(dir=directory, prefix=f".{os.path.basename(target)}.", suffix=".tmp")
    try:
        try:
            mode = os.stat(target).st_mode & 0o7777  # keep the old file's permissions
        except FileNotFoundError:
            umask = os.umask(0)
            os.umask(umask)
            mode = 0o666 & ~umask
        os.fchmod(fd, mode)
        stream = os.fdopen(fd, "wb") if binary else os.fdopen(fd, "w", encoding="utf-8", newline="\n")
        with stream:
            yield stream
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(temporary, target)
    except BaseException:
        try:
            os.unlink(temporary)
        except OSError:
            pass
        raise
    _fsync_directory(directory)


def _fsync_directory(directory: str) -> None:
    try:
        fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass  # some filesystems refuse a directory fsync; the rename itself is done
    finally:
        os.close(fd)


def read_regular(path: str | os.PathLike[str], max_bytes: int) -> bytes:
    """At most `max_bytes` + 1 bytes of a regular file. The open never blocks (O_NONBLOCK: a FIFO or a device
    named as a model or config would wait forever for a writer) and anything but a regular file is refused
    with an OSError naming the path."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC)
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise OSError(errno.EINVAL, "not a regular file (a FIFO, device or directory?)", os.fspath(path))
        os.set_blocking(fd, True)
        chunks, size = [], 0
        while size <= max_bytes:
            chunk = os.read(fd, min(1 << 20, max_bytes + 1 - size))
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
        return b"".join(chunks)
    finally:
        os.close(fd)
