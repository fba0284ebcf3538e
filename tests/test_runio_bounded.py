"""Issue 35.12 and 35.14: run CSVs are read a chunk at a time and checked as they are read. A 2 GB line (here
from a FIFO fed by a thread, not a file on disk) and /dev/zero are refused after a bounded read, never a
MemoryError; UTF-16, CR-only line endings and a Latin-1 byte in a comment each get a message that says so."""

from __future__ import annotations

import os
import threading
from pathlib import Path

import pytest

from fogd.cli import train as train_cli
from fogd.core.runio import read_run
from fogd.errors import InputError

TWO_GB = 2 << 30
ROWS = "".join(f"{n / 10:.1f},{0.01 * (n % 7)!r},{20 + n / 1000:.4f}\n" for n in range(400))


class Feeder(threading.Thread):
    """Writes a header then one endless line of digits into a FIFO until the reader goes away or 2 GB are
    written; `written` is how much the reader let through."""

    def __init__(self, fifo: Path) -> None:
        super().__init__(daemon=True)
        self.fifo, self.written = fifo, 0
        self.start()

    def run(self) -> None:
        block = b"1" * (1 << 20)
        try:
            with open(self.fifo, "wb", buffering=0) as stream:
                stream.write(b"t_s,rate_dph,temp_c\n0.0,")
                while self.written < TWO_GB:
                    self.written += stream.write(block)
        except BrokenPipeError:
            pass


def test_a_2_gb_line_from_a_fifo_is_refused_as_it_is_read(tmp_path):
    fifo = tmp_path / "run.csv"
    os.mkfifo(fifo)
    feeder = Feeder(fifo)
    with pytest.raises(InputError, match=r"run.csv:2: a line longer than 2048 bytes"):
        read_run(fifo)
    feeder.join(timeout=60)
    assert not feeder.is_alive()
    assert feeder.written < 16 << 20  # stopped within the first chunks, not after 2 GB


def test_train_on_dev_zero_is_one_line_not_a_memory_error(tmp_path, capsys):
    status = train_cli.main(["/dev/zero", "-o", str(tmp_path / "m.json"), "-q"])
    assert status == 65
    assert capsys.readouterr().err.strip().splitlines() == [
        "fogd-train: /dev/zero:1: a NUL byte; not a text file (a device, or a binary file?)"
    ]


def test_a_utf16_run_says_save_as_utf8(tmp_path):
    path = tmp_path / "u16.csv"
    path.write_bytes(("t_s,rate_dph,temp_c\n" + ROWS).encode("utf-16"))
    with pytest.raises(InputError, match=r"^[^\x00]*UTF-16 text; save it as UTF-8[^\x00]*$"):
        read_run(path)


def test_cr_only_line_endings_are_named(tmp_path):
    path = tmp_path / "mac.csv"
    path.write_bytes(("t_s,rate_dph,temp_c\n" + ROWS).replace("\n", "\r").encode())
    with pytest.raises(InputError, match="mac.csv:1: CR line endings"):
        read_run(path)


def test_a_latin1_byte_in_a_comment_is_read_past(tmp_path):
    """A chamber log's '25 °C' saved as Latin-1 in a comment gave 'unreadable data after line 2'."""
    path = tmp_path / "latin.csv"
    path.write_bytes(b"# chamber at 25\xb0C\nt_s,rate_dph,temp_c\n" + ROWS.encode())
    run = read_run(path)
    assert run.rows == 400 and run.temp_c[-1] == pytest.approx(20.399)


def test_a_non_utf8_byte_in_a_data_row_is_still_named(tmp_path):
    path = tmp_path / "bad.csv"
    path.write_bytes(b"t_s,rate_dph,temp_c\n0.0,1.0,20.0\n0.1,1\xb0,20.0\n" + ROWS.encode())
    with pytest.raises(InputError, match="bad.csv:3: column 2 is not a number"):
        read_run(path)
