"""Issue 35.10: temporary files are made with a random name, O_EXCL|O_NOFOLLOW, in the target's directory: a
symlink or a FIFO planted at the old predictable name (`<stats>.<pid>.tmp`) is never followed, written or
waited on, and the target ends a regular file."""

from __future__ import annotations

import json
import os
import stat
import threading
from pathlib import Path

import pytest

from fogd.errors import DeviceError
from fogd.serving.statsfile import write_stats
from fogd.simulation.emulator import point_link


def test_the_stats_file_never_follows_a_link_planted_at_its_temporary_name(tmp_path):
    victim = tmp_path / "victim"
    victim.write_text("precious\n")
    stats = tmp_path / "stats.json"
    (tmp_path / f"stats.json.{os.getpid()}.tmp").symlink_to(victim)
    assert write_stats(str(stats), {"pid": os.getpid(), "running": True})
    assert victim.read_text() == "precious\n"
    assert stat.S_ISREG(os.lstat(stats).st_mode) and json.loads(stats.read_text())["running"] is True


def test_the_stats_file_never_opens_a_fifo_planted_at_its_temporary_name(tmp_path):
    """A reader holds the FIFO open, so the old code did not block here: it wrote the JSON into the FIFO and
    renamed the FIFO over the stats file. Without that reader it blocked the daemon's loop for good."""
    stats = tmp_path / "stats.json"
    fifo = tmp_path / f"stats.json.{os.getpid()}.tmp"
    os.mkfifo(fifo)
    reader = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)
    try:
        assert write_stats(str(stats), {"pid": os.getpid(), "running": True})
        try:
            leaked = os.read(reader, 65536)
        except BlockingIOError:
            leaked = b""
        assert leaked == b""
    finally:
        os.close(reader)
    assert stat.S_ISREG(os.lstat(stats).st_mode) and json.loads(stats.read_text())["pid"] == os.getpid()
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)


def test_the_emulators_link_is_made_beside_a_fifo_planted_at_its_old_temporary_name(tmp_path):
    """point_link made `<link>.<pid>.<thread>.tmp`; a FIFO (or anything) there made it fail."""
    link = tmp_path / "fog0"
    (tmp_path / f"fog0.{os.getpid()}.{threading.get_ident()}.tmp").mkdir()
    point_link(str(link), "/dev/null")
    assert os.readlink(link) == "/dev/null"


def test_a_link_that_cannot_be_made_names_the_link_not_the_pty(tmp_path):
    """Issue 35.14: a pty link on a read-only filesystem blamed /dev/pts/N (the symlink's target)."""
    link = tmp_path / "missing" / "fog0"
    with pytest.raises(DeviceError) as raised:
        point_link(str(link), "/dev/pts/7")
    assert str(link) in str(raised.value) and "/dev/pts" not in str(raised.value)
