"""`fogd --demo` as a person sees it: the real command on a pty that is its terminal, its output drawn by a
terminal emulator (pyte), and the screen checked, not the bytes: one live line rewritten in place with the raw
and compensated drift side by side (compensated well under raw once the gyro has warmed for an hour of its
time), a log record written meanwhile on a line of its own, and Ctrl-C ending with exit 0 and a short summary,
no JSON."""

from __future__ import annotations

import fcntl
import os
import pty
import re
import select
import signal
import struct
import sys
import termios
import time

import pyte

COLUMNS, ROWS = 120, 200
LIVE = re.compile(r"^drift raw ([+-]\d+\.\d+)  compensated ([+-]\d+\.\d+) deg/h \| T +(-?[\d.]+) C \| chamber (\d+):(\d\d) \|")
SUMMARY = re.compile(r"^  compensated  [+-][\d.]+ \.\. [+-][\d.]+ deg/h \(spread [\d.]+\): (-?\d+) % less$")
TIMEOUT_S = 300.0  # progress is waited for; this only ends a test that would never finish


class Terminal:
    """A child process on a pty of COLUMNS x ROWS, its output drawn on a pyte screen."""

    def __init__(self, argv: list[str], cwd) -> None:
        self.screen = pyte.Screen(COLUMNS, ROWS)
        self.stream = pyte.ByteStream(self.screen)
        self.raw = bytearray()
        self.pid, self.fd = pty.fork()
        if self.pid == 0:  # the child: the pty is its terminal (stdin, stdout, stderr) and controlling tty
            try:
                os.chdir(cwd)
                os.execve(argv[0], argv, {**os.environ, "TERM": "xterm", "COLUMNS": str(COLUMNS)})
            finally:
                os._exit(127)
        fcntl.ioctl(self.fd, termios.TIOCSWINSZ, struct.pack("HHHH", ROWS, COLUMNS, 0, 0))
        self.status: int | None = None

    def rows(self) -> list[str]:
        return [row.rstrip() for row in self.screen.display]

    def pump(self, timeout_s: float = 0.5) -> bool:
        """Draw what the child wrote within `timeout_s`; False once it has closed the terminal."""
        if not select.select([self.fd], [], [], timeout_s)[0]:
            return True
        try:
            data = os.read(self.fd, 65536)
        except OSError:  # EIO: the child is gone
            return False
        self.raw += data
        self.stream.feed(data)
        return bool(data)

    def wait_for(self, condition, what: str) -> None:
        deadline = time.monotonic() + TIMEOUT_S
        while not condition(self.rows()):
            assert self.pump(), f"the demo ended before {what}:\n" + "\n".join(self.rows())
            assert time.monotonic() < deadline, f"no {what} in {TIMEOUT_S:g} s:\n" + "\n".join(self.rows())

    def finish(self) -> int:
        deadline = time.monotonic() + 60.0
        while self.pump():
            assert time.monotonic() < deadline, "the demo did not end after Ctrl-C:\n" + "\n".join(self.rows())
        _, status = os.waitpid(self.pid, 0)
        os.close(self.fd)
        return os.waitstatus_to_exitcode(status)

    def kill(self) -> None:
        try:
            os.kill(self.pid, signal.SIGKILL)
            os.waitpid(self.pid, 0)
        except (ProcessLookupError, ChildProcessError):
            pass


def live_rows(rows: list[str]) -> list[str]:
    return [row for row in rows if "drift raw" in row or "drift: measuring" in row]


def chamber_min(rows: list[str]) -> int:
    lines = live_rows(rows)
    match = LIVE.match(lines[-1]) if lines else None
    return int(match.group(4)) * 60 + int(match.group(5)) if match else -1


def test_the_demo_on_a_terminal_shows_the_drift_removed_keeps_log_records_apart_and_sums_up(tmp_path):
    terminal = Terminal([sys.executable, "-m", "fogd.cli.daemon", "--demo", "--stats-file", "none"], tmp_path)
    try:
        # an hour of the gyro's time: half a minute of the demo's at 120x real time
        terminal.wait_for(lambda rows: chamber_min(rows) >= 60, "live line at chamber 1:00")
        os.kill(terminal.pid, signal.SIGHUP)  # the demo has nothing to reload: fogd logs a warning meanwhile
        terminal.wait_for(lambda rows: b"nothing to reload" in terminal.raw, "SIGHUP's log record")
        shown_min = chamber_min(terminal.rows())
        terminal.wait_for(lambda rows: chamber_min(rows) > shown_min, "the live line drawn again after the record")
        rows = terminal.rows()
        os.write(terminal.fd, b"\x03")  # Ctrl-C, as a person stops it: the terminal sends SIGINT
        status = terminal.finish()
    finally:
        terminal.kill()
    screen = "\n".join(rows)
    # one live line, rewritten in place: never scrolled, never sharing its row with a log record
    lines = live_rows(rows)
    assert len(lines) == 1 and LIVE.match(lines[0]) and "fogd." not in lines[0], screen
    raw_dph, comp_dph = (float(value) for value in LIVE.match(lines[0]).group(1, 2))
    assert abs(raw_dph) >= 0.02 and abs(comp_dph) <= abs(raw_dph) / 4, screen  # the drift, and the drift removed
    records = [row for row in rows if "fogd." in row and not row.startswith(("fogd demo:", "  "))]
    assert all(row.startswith(("fogd.daemon: ", "fogd.placement: ")) for row in records), screen  # each on its own row
    sighup = [row for row in rows if "SIGHUP" in row]
    assert len(sighup) == 1 and sighup[0].startswith("fogd.daemon: SIGHUP: nothing to reload"), screen
    assert rows.index(sighup[0]) < rows.index(lines[0])  # the live line went on below the record
    assert any(row.startswith("fogd.daemon: protocol auto: fogd on ") for row in rows), screen
    # Ctrl-C: exit 0 and a short summary below the last live line, no JSON
    final = [row for row in terminal.rows() if row]
    assert status == 0, "\n".join(final)
    summary = final[final.index(next(row for row in final if row.startswith("fogd demo: ") and "gyro's time in" in row)) :]
    assert len(summary) == 4 and summary[1].startswith("  raw  ") and summary[3].startswith("  frames "), final
    assert int(SUMMARY.match(summary[2]).group(1)) >= 80, final
    assert live_rows(final) and final.index(live_rows(final)[-1]) < final.index(summary[0])
    assert b"{" not in terminal.raw and "Traceback" not in "\n".join(final)
