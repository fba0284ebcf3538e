"""fogd-emu on real ptys: frames decode with the lexer, values are what the wire can carry, pacing, the link,
every fault as its ledger says (the lexer's counters agree), backpressure, unplug/replug, the command line."""

import json
import math
import os
import select
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import serial

from fogd import protocols
from fogd.cli.emu import main
from fogd.core.runio import read_run
from fogd.errors import DeviceError
from fogd.protocols.kvh import DPH_PER_RAD_S
from fogd.protocols.lexer import Lexer
from fogd.simulation import emulator as emulator_module
from fogd.simulation.emulator import TICK_S, Emulator, Faults, RunSource, SimSource, point_link
from fogd.simulation.profiles import Profile
from fogd.simulation.simulator import Simulation

COMMAND = [sys.executable, "-m", "fogd.cli.emu"]
RATE_HZ = 200.0


def write_run(path: Path, rows: int = 300, rate_hz: float = RATE_HZ) -> Path:
    t_s = np.arange(rows) / rate_hz
    rate_dph = 3.0 * np.sin(t_s * 7.0) + 0.01 * np.arange(rows)
    temp_c = 20.0 + 0.037 * np.arange(rows)  # crosses whole degrees, never lands on .5
    lines = ["t_s,rate_dph,temp_c"] + [f"{t:.6f},{r:.9f},{c:.4f}" for t, r, c in zip(t_s, rate_dph, temp_c)]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture
def run_csv(tmp_path: Path) -> Path:
    return write_run(tmp_path / "run.csv")


def read_until_gone(fd: int, timeout_s: float = 10.0, chunks: list[bytes] | None = None) -> bytes:
    """Everything the pty gives until the emulator closes it (EOF or EIO)."""
    data = bytearray()
    deadline = time.monotonic() + timeout_s
    try:
        while time.monotonic() < deadline:
            if not select.select([fd], [], [], 0.1)[0]:
                continue
            try:
                chunk = os.read(fd, 65536)
            except OSError:
                break
            if not chunk:
                break
            data += chunk
            if chunks is not None:
                chunks.append(chunk)
        else:
            pytest.fail("the emulator did not close the pty in time")
    finally:
        os.close(fd)
    return bytes(data)


def open_slave(path: str) -> int:
    return os.open(path, os.O_RDONLY | os.O_NOCTTY)


def stream(emulator: Emulator, chunks: list[bytes] | None = None) -> bytes:
    """Run `emulator` in-process and read its pty from the start to the end."""
    path = emulator.start()
    data = read_until_gone(open_slave(path), chunks=chunks)
    assert emulator.join(5.0)
    return data


def lex(protocol: str, data: bytes) -> tuple[list, Lexer]:
    lexer = Lexer(protocols.get(protocol))
    return lexer.feed(data), lexer


def ledger_lines(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def test_kvh_frames_carry_the_csv_as_format_a_can(run_csv: Path, tmp_path: Path):
    run = read_run(run_csv)
    ledger = tmp_path / "ledger.jsonl"
    emulator = Emulator(RunSource(run), "kvh-a", speed=None, ledger=str(ledger))
    frames, lexer = lex("kvh-a", stream(emulator))
    assert len(frames) == run.rows == emulator.stats.frames_sent
    assert lexer.counters.frames_ok == run.rows and lexer.counters.garbage_bytes == 0
    assert [frame.seq for frame in frames] == [i % 128 for i in range(run.rows)]
    assert all(frame.raw[28] == 0x77 and frame.rate_dph[:2] == (0.0, 0.0) for frame in frames)
    z_dph = np.array([frame.rate_dph[2] for frame in frames])
    carried_dph = np.float32(run.rate_dph / DPH_PER_RAD_S).astype(np.float64) * DPH_PER_RAD_S
    assert np.array_equal(z_dph, carried_dph)
    assert [frame.temp_c for frame in frames] == [float(round(c)) for c in run.temp_c]
    assert len(set(frame.temp_c for frame in frames)) > 5
    entries = ledger_lines(ledger)
    assert [entry["seq"] for entry in entries] == [frame.seq for frame in frames]
    assert [entry["rate_dph"] for entry in entries] == z_dph.tolist()
    assert [entry["temp_c"] for entry in entries] == [frame.temp_c for frame in frames]
    assert all(entry["sent"] and entry["valid"] and entry["rate_ok"] and not entry["faults"] for entry in entries)


def test_fogd_protocol_sends_rate_and_temperature_frames_with_their_own_counters(run_csv: Path):
    run = read_run(run_csv)
    frames, lexer = lex("fogd", stream(Emulator(RunSource(run), "fogd", speed=None, temp_rate_hz=10.0)))
    rates = [frame for frame in frames if frame.kind == "rate"]
    temps = [frame for frame in frames if frame.kind == "temp"]
    assert lexer.counters.frames_ok == len(frames) and lexer.counters.seq_gaps == 0
    assert [frame.seq for frame in rates] == list(range(run.rows))
    assert [frame.seq for frame in temps] == list(range(len(temps)))
    assert len(temps) == math.ceil(run.rows * 10.0 / RATE_HZ)
    assert np.array_equal([frame.t_s for frame in rates], np.round(run.t_s * 1e6) / 1e6)
    assert np.array_equal([frame.rate_dph[2] for frame in rates], run.rate_dph.astype(np.float32))
    assert all(frame.axis_present == (False, False, True) and frame.axis_valid[2] for frame in rates)
    by_time = dict(zip(np.round(run.t_s * 1e6).tolist(), run.temp_c.astype(np.float32).tolist()))
    assert all(frame.temp_c == by_time[round(frame.t_s * 1e6)] for frame in temps)
    assert np.diff([frame.t_s for frame in temps]) == pytest.approx(0.1)


def test_ascii_lines_carry_the_csv_exactly(run_csv: Path):
    run = read_run(run_csv)
    frames, lexer = lex("ascii", stream(Emulator(RunSource(run), "ascii", speed=None)))
    assert lexer.counters.frames_ok == run.rows and lexer.counters.bad_line == 0
    assert [frame.rate_dph[2] for frame in frames] == run.rate_dph.tolist()
    assert [frame.temp_c for frame in frames] == run.temp_c.tolist()
    assert [frame.t_s for frame in frames] == (run.t_s - run.t_s[0]).tolist()


def test_simulated_profile_ends_with_the_profile_and_loops(tmp_path: Path):
    profile = Profile("short", ((1.0, 20.0), (1.0, 25.0)))
    frames, _ = lex("ascii", stream(Emulator(SimSource(profile, 100.0, 7), "ascii", speed=None)))
    expected = Simulation(profile, 100.0, 7).columns()
    assert len(frames) == expected["t_s"].size == 201
    assert [frame.rate_dph[2] for frame in frames] == expected["rate_dph"].tolist()
    assert [frame.temp_c for frame in frames] == expected["temp_c"].tolist()
    looped, _ = lex("ascii", stream(Emulator(SimSource(profile, 100.0, 7), "ascii", speed=None, count=450, loop=True)))
    assert len(looped) == 450
    assert np.all(np.diff([frame.t_s for frame in looped]) > 0)
    assert [frame.rate_dph[2] for frame in looped[201:402]] == expected["rate_dph"].tolist()


def test_link_points_to_the_slave_and_goes_at_the_end(run_csv: Path, tmp_path: Path):
    link = tmp_path / "gyro"
    os.symlink("/nonexistent/old-pty", link)
    emulator = Emulator(RunSource(read_run(run_csv)), "kvh-a", speed=None, link=str(link))
    path = emulator.start()
    assert os.readlink(link) == path and os.path.realpath(link) == os.path.realpath(path)
    read_until_gone(open_slave(str(link)))
    assert emulator.join(5.0)
    assert not os.path.lexists(link)
    regular = tmp_path / "file"
    regular.write_text("keep me")
    with pytest.raises(DeviceError, match="not a symlink"):
        point_link(str(regular), path)
    assert regular.read_text() == "keep me"


class InjectedClock(threading.Event):
    """The emulator's clock and stop event in one: its time moves only when it waits, by what it asked for, so
    its pacing is judged apart from how busy the machine is (the pty's drain still polls in real time)."""

    def __init__(self) -> None:
        super().__init__()
        self.now_s = 0.0
        self.waits: list[float] = []

    def monotonic(self) -> float:
        return self.now_s

    def wait(self, timeout: float | None = None) -> bool:
        self.now_s += timeout or 0.0
        self.waits.append(timeout or 0.0)
        return self.is_set()


def clocked_stream(emulator: Emulator, monkeypatch) -> tuple[list, float]:
    """The frames `emulator` streams and the seconds its clock ran meanwhile (its waits)."""
    clock = InjectedClock()
    monkeypatch.setattr(emulator_module, "time", SimpleNamespace(monotonic=clock.monotonic, sleep=time.sleep))
    emulator._stop = clock
    frames, _ = lex("kvh-a", stream(emulator))
    return frames, clock.now_s


def test_real_time_pacing_and_fast_mode(monkeypatch):
    """Paced, a stream ends when its data's last frame is due at its speed, within a tick (the clock injected);
    fast, it never waits. On the real clock a paced stream never ends early (a busy machine may end it late)."""
    profile = Profile("short", ((10.0, 20.0),))
    started = time.monotonic()
    frames, _ = lex("kvh-a", stream(Emulator(SimSource(profile, 1000.0, 1), "kvh-a", count=200)))
    assert len(frames) == 200 and time.monotonic() - started > 0.199
    frames, ran_s = clocked_stream(Emulator(SimSource(profile, 1000.0, 1), "kvh-a", count=200), monkeypatch)
    assert len(frames) == 200 and 0.199 <= ran_s <= 0.199 + 2 * TICK_S
    frames, ran_s = clocked_stream(Emulator(SimSource(profile, 1000.0, 1), "kvh-a", count=1000, speed=5.0), monkeypatch)
    assert len(frames) == 1000 and 0.1998 <= ran_s <= 0.1998 + 2 * TICK_S
    fast = Emulator(SimSource(profile, 1000.0, 1), "kvh-a", speed=None)
    frames, ran_s = clocked_stream(fast, monkeypatch)
    # 10 s of data, not paced: its only waits are the retries while no reader has the pty open yet (a busy
    # machine opens it after the emulator has filled the pty's buffer), which the emulator says
    assert len(frames) == 10001 and set(fast._stop.waits) <= {emulator_module.NO_READER_RETRY_S}
    assert ran_s == 0.0 or fast._said_no_reader


def faulted(protocol: str, run_csv: Path, tmp_path: Path, chunks: list[bytes] | None = None, **faults: float):
    """Stream the run with `faults`; returns (decoded frames, lexer, ledger entries, stats)."""
    ledger = tmp_path / "ledger.jsonl"
    emulator = Emulator(RunSource(read_run(run_csv)), protocol, speed=None, ledger=str(ledger),
                        faults=Faults(seed=3, **faults), temp_rate_hz=20.0)
    frames, lexer = lex(protocol, stream(emulator, chunks))
    entries = ledger_lines(ledger)
    sent_valid = [entry for entry in entries if entry["sent"] and entry["valid"]]
    if protocol != "kvh-a":  # a copy of the frame before is dropped (counted) where a sequence number or time tells
        copies = [entry for entry in sent_valid if entry["faults"] == ["repeat"]]
        sent_valid = [entry for entry in sent_valid if entry["faults"] != ["repeat"]]
        assert lexer.counters.frames_repeated == len(copies)
    assert [(frame.kind, frame.seq) for frame in frames] == [(entry["kind"], entry["seq"]) for entry in sent_valid]
    assert lexer.counters.frames_ok == len(sent_valid)
    for name in faults:
        assert emulator.stats.faults[name] == sum(name in entry["faults"] for entry in entries) > 0
    return frames, lexer, entries, emulator.stats


@pytest.mark.parametrize("protocol", ["kvh-a", "fogd", "ascii"])
def test_garbage_is_counted_as_garbage_and_costs_no_frame(protocol, run_csv, tmp_path):
    frames, lexer, entries, stats = faulted(protocol, run_csv, tmp_path, garbage=0.2)
    assert all(entry["sent"] and entry["valid"] for entry in entries)
    assert lexer.counters.garbage_bytes == sum(entry["garbage_bytes"] for entry in entries) == stats.garbage_bytes
    if protocol == "ascii":
        assert lexer.counters.bad_line == stats.faults["garbage"]


@pytest.mark.parametrize("protocol", ["kvh-a", "fogd"])
def test_bit_flips_are_bad_crcs(protocol, run_csv, tmp_path):
    frames, lexer, entries, stats = faulted(protocol, run_csv, tmp_path, bitflip=0.1)
    flipped = [entry for entry in entries if "bitflip" in entry["faults"]]
    assert not any(entry["valid"] for entry in flipped)
    assert lexer.counters.bad_crc == len(flipped) == stats.faults["bitflip"]
    assert lexer.counters.garbage_bytes == sum(entry["bytes"] for entry in flipped)


def test_drops_are_sequence_gaps(run_csv, tmp_path):
    frames, lexer, entries, stats = faulted("kvh-a", run_csv, tmp_path, drop=0.1)
    dropped = [entry["index"] for entry in entries if not entry["sent"]]
    assert all(entries[index]["faults"] == ["drop"] for index in dropped)
    runs = sum(1 for index in dropped if index - 1 not in dropped)
    assert lexer.counters.frames_missing == len(dropped) == stats.faults["drop"]
    assert lexer.counters.seq_gaps == runs


def test_repeats_are_sequence_repeats(run_csv, tmp_path):
    frames, lexer, entries, stats = faulted("kvh-a", run_csv, tmp_path, repeat=0.1)
    assert lexer.counters.seq_repeats == stats.faults["repeat"] == len(frames) - 300


def test_nan_and_cleared_status_make_invalid_axes_with_good_crcs(run_csv, tmp_path):
    frames, lexer, entries, stats = faulted("kvh-a", run_csv, tmp_path, nan=0.1, clear_status=0.1)
    assert lexer.counters.bad_crc == 0 and len(frames) == 300
    invalid_axes = sum(frame.axis_valid.count(False) for frame in frames)
    assert lexer.counters.invalid_axes == invalid_axes == stats.faults["nan"] + stats.faults["clear_status"]
    for frame, entry in zip(frames, entries):
        assert frame.axis_valid[2] == entry["rate_ok"]
        assert math.isnan(frame.rate_dph[2]) == ("nan" in entry["faults"]) == (entry["rate_dph"] is None)
        if "clear_status" in entry["faults"]:
            assert frame.raw[28] != 0x77 and frame.raw[28] | 0x07 == 0x77


def test_split_frames_arrive_in_two_reads_and_decode(run_csv, tmp_path):
    chunks: list[bytes] = []
    frames, lexer, entries, stats = faulted("kvh-a", run_csv, tmp_path, chunks, split=0.2)
    assert len(frames) == 300 and lexer.counters.garbage_bytes == 0
    read_ends = set(np.cumsum([len(chunk) for chunk in chunks]).tolist())
    split_frames = [range(36 * entry["index"] + 1, 36 * entry["index"] + 36) for entry in entries if "split" in entry["faults"]]
    assert any(read_ends.intersection(inside) for inside in split_frames)


def test_every_fault_at_once_loses_no_valid_frame(run_csv, tmp_path):
    frames, lexer, entries, stats = faulted(
        "fogd", run_csv, tmp_path, garbage=0.05, bitflip=0.05, drop=0.05, repeat=0.05, nan=0.05,
        clear_status=0.05, split=0.05,
    )
    sent = [entry for entry in entries if entry["sent"]]
    assert lexer.counters.bad_crc == sum(not entry["valid"] for entry in sent)
    assert lexer.counters.invalid_axes == sum(entry["valid"] and entry["rate_ok"] is False for entry in sent)
    assert lexer.counters.garbage_bytes == sum(entry["garbage_bytes"] + (0 if entry["valid"] else entry["bytes"]) for entry in sent)
    valid = [entry for entry in sent if entry["valid"] and entry["kind"] == "rate" and entry["faults"] != ["repeat"]]
    assert [frame.rate_dph[2] for frame in frames if frame.kind == "rate" and frame.axis_valid[2]] == [
        entry["rate_dph"] for entry in valid if entry["rate_ok"]
    ]


def test_a_late_reader_slows_the_emulator_but_loses_nothing(tmp_path):
    profile = Profile("short", ((10.0, 20.0),))
    emulator = Emulator(SimSource(profile, 5000.0, 1), "kvh-a", count=2000)
    path = emulator.start()
    time.sleep(0.5)  # 2500 frames fall due; the pty holds about 20 kB
    frames, lexer = lex("kvh-a", read_until_gone(open_slave(path)))
    assert emulator.join(5.0)
    assert len(frames) == 2000 and lexer.counters.seq_gaps == 0
    assert emulator.stats.backpressure_s > 0.2


def test_drop_when_full_drops_and_counts(tmp_path):
    profile = Profile("short", ((10.0, 20.0),))
    ledger = tmp_path / "ledger.jsonl"
    emulator = Emulator(SimSource(profile, 5000.0, 1), "fogd", count=5000, drop_when_full=True, ledger=str(ledger))
    path = emulator.start()
    time.sleep(0.4)  # the pty fills after about 0.14 s; the stream goes on until 1 s
    frames, lexer = lex("fogd", read_until_gone(open_slave(path)))
    assert emulator.join(5.0)
    full = [entry for entry in ledger_lines(ledger) if entry["faults"] == ["full"]]
    assert emulator.stats.dropped_full == len(full) > 100
    assert len(frames) == emulator.stats.frames_sent == lexer.counters.frames_ok
    assert lexer.counters.frames_missing == len(full)


def test_unplug_repoints_the_link_to_a_new_pty_and_the_data_continues(tmp_path):
    run_csv = write_run(tmp_path / "run.csv", rows=500)
    link, ledger = tmp_path / "gyro", tmp_path / "ledger.jsonl"
    process = subprocess.Popen(
        [*COMMAND, "--csv", str(run_csv), "--link", str(link), "--ledger", str(ledger),
         "--unplug-every-s", "0.5", "--unplug-for-s", "0.2", "--drain-s", "0.5"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    paths, data, held = [], b"", []
    try:
        while line := process.stdout.readline():
            paths.append(line.strip())
            assert os.readlink(link) == paths[-1]
            fd = open_slave(str(link))
            held.append(os.dup(fd))  # a vanished pty stays open here, so a new one cannot reuse its number
            data += read_until_gone(fd)
    finally:
        for fd in held:
            os.close(fd)
        if process.poll() is None:
            process.kill()
    assert process.wait(10) == 0
    assert len(paths) >= 3 and len(set(paths)) == len(paths)
    assert "replugs" in process.stderr.read()
    frames, lexer = lex("kvh-a", data)
    entries = ledger_lines(ledger)
    lost = [entry for entry in entries if not entry["sent"]]
    assert lost and all(entry["faults"] == ["unplugged"] for entry in lost)
    assert [frame.seq for frame in frames] == [entry["seq"] for entry in entries if entry["sent"]]
    assert not os.path.lexists(link)


def test_duration_counts_seconds_of_data_and_the_path_is_the_first_line(run_csv: Path, tmp_path: Path, capsys):
    ledger = tmp_path / "ledger.jsonl"
    assert main(["--csv", str(run_csv), "--duration-s", "0.5", "--fast", "--ledger", str(ledger), "--drain-s", "0"]) == 0
    captured = capsys.readouterr()
    assert captured.out.startswith("/dev/pts/") and captured.out.count("\n") == 1
    assert "sent 100 frames for 100 samples" in captured.err
    assert [entry["sample"] for entry in ledger_lines(ledger)] == list(range(100))


def test_sigterm_stops_cleanly_with_a_summary(tmp_path):
    link = tmp_path / "gyro"
    process = subprocess.Popen(
        [*COMMAND, "--profile", "paper-test", "--protocol", "fogd", "--link", str(link), "--drain-s", "0.5"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    path = process.stdout.readline().strip()
    fd = open_slave(path)
    time.sleep(0.3)
    process.send_signal(signal.SIGTERM)
    frames, lexer = lex("fogd", read_until_gone(fd))
    assert process.wait(5) == 0
    stderr = process.stderr.read()
    assert stderr.startswith("fogd-emu: sent ") and stderr.count("\n") == 1
    assert f"sent {len(frames)} frames" in stderr and len(frames) > 20
    assert not os.path.lexists(link)


def test_pyserial_reader_with_wait_reader_gets_every_frame_from_the_first(run_csv: Path):
    process = subprocess.Popen(
        [*COMMAND, "--csv", str(run_csv), "--wait-reader", "--count", "50", "--speed", "4"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    path = process.stdout.readline().strip()
    time.sleep(0.2)  # nothing is sent while nobody listens
    with serial.Serial(path, timeout=3.0) as port:
        data = port.read(50 * 36)
    frames, lexer = lex("kvh-a", data)
    assert [frame.seq for frame in frames] == list(range(50))
    assert process.wait(5) == 0


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--protocol", "nmea", "--profile", "cycle"], "invalid choice: 'nmea'"),
        (["--csv", "/nonexistent/run.csv"], "/nonexistent/run.csv"),
        (["--profile", "no-such-profile"], "unknown profile 'no-such-profile'"),
        (["--profile", "/nonexistent/p.yaml"], "cannot read profile"),
        (["--profile", "cycle", "--garbage", "1.5"], "at least 0 and at most 1"),
        (["--profile", "cycle", "--protocol", "ascii", "--clear-status", "0.1"], "clear-status"),
        (["--profile", "cycle", "--rate-hz", "9000"], "rate_hz must be within 1..5000 Hz"),
        ([], "required"),
    ],
)
def test_bad_options_give_one_line_and_a_non_zero_exit(argv, message, capsys):
    assert main(argv) != 0
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.startswith("fogd-emu: ") and captured.err.count("\n") == 1 and message in captured.err


def test_seed_with_csv_is_refused(run_csv: Path, capsys):
    assert main(["--csv", str(run_csv), "--seed", "3"]) == 2
    assert "--seed applies to --profile" in capsys.readouterr().err


def test_help_names_units_and_defaults(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--help"])
    assert exit_info.value.code == 0
    text = capsys.readouterr().out
    for needle in ("--rate-hz HZ", "(default: 200)", "--unplug-for-s D", "--fault-seed", "ledger", "whole-degree"):
        assert needle in text
