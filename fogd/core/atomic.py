"""Files are read safely and written whole or not at all: every output file goes to a temporary file in its own
directory (a random name, created with O_EXCL|O_NOFOLLOW), is fsynced and renamed over the old one (then the
directory is fsynced), so a full disk, a crash or a kill leaves the old file as it was. A FIFO, a character
device or stdout named as an output is written as a stream, never replaced; a directory, block device or socket
is refused, and no missing directory is created. An output that is one of the command's inputs (the same inode,
through any symlink or hard link) is refused before anything is written. Models and configs are read only from
regular files.
"""

from __future__ import annotations

import errno
import os
import stat
import sys
import tempfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from typing import IO

from fogd.errors import OutputError, UsageError


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


STREAM, REPLACE = "stream", "replace"


def output_kind(path: str) -> str:
    """How `path` is written: REPLACE (a regular file, or a new name in an existing directory: a temporary file
    renamed over it) or STREAM ('-', stdout by any name, a FIFO or a character device: written in place, never
    replaced). Raises OSError naming `path` for a missing directory, a directory, a block device or a socket."""
    if path == "-":
        return STREAM
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        directory = os.path.dirname(os.path.realpath(path)) or "."
        if not os.path.isdir(directory):
            raise OSError(errno.ENOENT, f"no directory {directory} (fogd creates no directories)", path) from None
        return REPLACE
    if _is_stdout(path) or stat.S_ISFIFO(mode) or stat.S_ISCHR(mode):
        return STREAM
    if stat.S_ISREG(mode):
        return REPLACE
    kind = "a directory" if stat.S_ISDIR(mode) else "a block device" if stat.S_ISBLK(mode) else "a socket"
    raise OSError(errno.EINVAL, f"{kind}; an output is a regular file, a FIFO, a character device or '-'", path)


def _is_stdout(path: str) -> bool:
    """Whether `path` is this process's stdout (/dev/stdout, /proc/self/fd/1: their real path is a pipe's name)."""
    try:
        named, out = os.stat(path), os.fstat(sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):  # stdout closed or replaced by an object without a descriptor
        return False
    return (named.st_dev, named.st_ino) == (out.st_dev, out.st_ino)


def check_output(path: str, inputs: Iterable[str | os.PathLike[str]] = ()) -> None:
    """Refuse, before any long work, an output that could not be written: an input (UsageError), a missing
    directory, a directory or other special file, a directory fogd cannot create a file in (OutputError)."""
    refuse_inputs(path, inputs)
    try:
        kind = output_kind(path)
        if kind == STREAM:
            if path != "-" and not os.access(path, os.W_OK):
                raise OSError(errno.EACCES, os.strerror(errno.EACCES), path)
            return
        fd, temporary = _temporary(os.path.dirname(os.path.realpath(path)) or ".", path)
        os.close(fd)
        os.unlink(temporary)
    except OSError as error:
        raise _output_error(path, error) from None


def check_output_directory(path: str) -> None:
    """Refuse, before any long work, an output directory (a report's) that could not be written: a file or
    other non-directory there, a missing parent (only the directory itself is created), no permission."""
    try:
        if os.path.isdir(path):
            fd, temporary = _temporary(path, "probe")
            os.close(fd)
            os.unlink(temporary)
            return
        if os.path.lexists(path):
            raise OSError(errno.ENOTDIR, "exists and is not a directory", path)
        parent = os.path.dirname(os.path.abspath(path))
        if not os.path.isdir(parent):
            raise OSError(errno.ENOENT, f"no directory {parent} (fogd creates no parent directories)", path)
        if not os.access(parent, os.W_OK | os.X_OK):
            raise OSError(errno.EACCES, f"cannot create it in {parent}: permission denied", path)
    except OSError as error:
        raise _output_error(path, error) from None


def _temporary(directory: str, path: str) -> tuple[int, str]:
    """A new file beside `path` (O_EXCL|O_NOFOLLOW and a random name: a link or FIFO planted there is never
    followed or opened)."""
    return tempfile.mkstemp(dir=directory, prefix=f".{os.path.basename(path)}.", suffix=".tmp")


def _output_error(path: str, error: OSError) -> OutputError:
    reason = error.strerror or os.strerror(error.errno or 0) or str(error)
    return OutputError(f"cannot write {path}: {reason}")


@contextmanager
def replaced(path: str, *, inputs: Iterable[str | os.PathLike[str]] = (), binary: bool = False) -> Iterator[IO]:
    """A stream for the output `path` (see output_kind): a regular file's contents are replaced when the block
    ends without an exception (a symlink's target is replaced; on failure the old file is untouched and no
    temporary file left); a FIFO, character device or stdout is written as a stream. Any failure, the body's
    writes included, is an OutputError naming `path` (exit 74); an output that is an input a UsageError."""
    refuse_inputs(path, inputs)
    try:
        kind = output_kind(path)
    except OSError as error:
        raise _output_error(path, error) from None
    try:
        if kind == STREAM:
            with _stream(path, binary) as stream:
                yield stream
        else:
            with _replacing(path, binary) as stream:
                yield stream
    except OSError as error:
        if isinstance(error, BrokenPipeError):
            raise  # a reader that went away (| head): the command ends quietly
        raise _output_error(path, error) from None


@contextmanager
def _stream(path: str, binary: bool) -> Iterator[IO]:
    if path == "-" or _is_stdout(path):
        stream = sys.stdout.buffer if binary else sys.stdout
        yield stream
        stream.flush()
        return
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_NOCTTY | os.O_CLOEXEC)
    with os.fdopen(fd, "wb") if binary else os.fdopen(fd, "w", encoding="utf-8", newline="\n") as stream:
        yield stream


@contextmanager
def _replacing(path: str, binary: bool) -> Iterator[IO]:
    target = os.path.realpath(path)
    directory = os.path.dirname(target) or "."
    fd, temporary = _temporary(directory, target)
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
