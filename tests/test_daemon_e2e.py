"""The real `fogd` process on real ptys: what it writes equals `fogd-replay` on the same samples, frame by
frame, for every protocol; corrupted frames are counted and dropped with no valid frame lost; SIGTERM exits 0
with the output flushed; bad input gives one line and a non-zero exit, never a traceback."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import tty
from pathlib import Path

import numpy as np
import pytest
from progress import STALL_S, wait_for_exit, wait_until, watching
from stopping import stop_timed
from test_hardening import model_document

from fogd.cli import replay
from fogd.core import modelfile
from fogd.core.columns import RUN_COLUMNS
from fogd.protocols import get
from fogd.protocols.base import ALL_AXES, Z_ONLY, Frame
from fogd.protocols.kvh import DPH_PER_RAD_S
from fogd.protocols.lexer import Lexer

RATE_HZ = 1000.0
SAMPLES = 3000
FOGD = [sys.executable, "-m", "fogd.cli.daemon"]
OUT_COLUMNS = ("t_s", "rate_dph", "temp_c", "temp_rate_cps", "comp_dph", "rate_comp_dph", "flags")


@pytest.fixture(scope="module")
def model_path(tmp_path_factory) -> Path:
    """comp = 0.5 + 0.05 T + 30 dT/dt deg/h, with a 0.5 s eq. 16 window so a short run warms up."""
    path = tmp_path_factory.mktemp("model") / "model.json"
    modelfile.save(path, model_document(name="e2e-linear"))
    return path


class Pty:
    """A pty standing in for the gyro's serial port: the test writes the master, fogd opens the slave."""

    def __init__(self) -> None:
        self.master, slave = os.openpty()
        tty.setraw(slave)
        self.path = os.ttyname(slave)
        os.close(slave)

    def write(self, data: bytes, piece: int = 4096) -> None:
        for start in range(0, len(data), piece):
            os.write(self.master, data[start : start + piece])

    def close(self) -> None:
        os.close(self.master)


@pytest.fixture
def gyro():
    port = Pty()
    yield port
    port.close()


class Fogd:
    """The real daemon in a subprocess, its stderr in a file."""

    def __init__(self, tmp_path: Path, *args: str) -> None:
        if "--out" not in args:  # stdout is not a terminal here, where fogd refuses to default to it
            args = (*args, "--out", os.devnull)
        self.stderr_path = tmp_path / "fogd.stderr"
        with open(self.stderr_path, "wb") as stderr:
            self.process = subprocess.Popen([*FOGD, *args], stdout=subprocess.DEVNULL, stderr=stderr)

    @property
    def stderr(self) -> str:
        return self.stderr_path.read_text()

    def wait_for(self, text: str, timeout_s: float = STALL_S) -> None:
        """Until fogd has said `text`; fails when it exits first, or when neither its log nor its CPU time has
        moved for `timeout_s` (at least STALL_S: a wait on progress, not a deadline)."""
        wait_until(lambda: text in self.stderr, watching([self.stderr_path], [self.process]), f"fogd never said {text!r}",
                   max(timeout_s, STALL_S), alive=[self.process], said=lambda: self.stderr)  # fmt: skip

    def terminate(self, timeout_s: float = 10.0) -> tuple[int, float]:
        """SIGTERM: the exit status and the seconds fogd slept stopping (waiting on a timeout, say; time spent
        waiting for a CPU on a busy machine is not counted)."""
        return stop_timed(self.process, lambda: self.stderr, timeout_s)

    def counters(self) -> dict:
        line = next(line for line in self.stderr.splitlines() if line.startswith("fogd.status: counters "))
        return json.loads(line.split("counters ", 1)[1])

    def kill(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait()


EMU = [sys.executable, "-m", "fogd.cli.emu"]
# fogd-emu waits at most this long at its end for the reader to take what it wrote (closing the pty earlier
# throws those bytes away): it returns as soon as the reader has, and a loaded reader can take seconds
DRAIN_S = "600"


class Emu:
    """fogd-emu in a subprocess playing a run CSV (by default as fast as the reader takes it), once a reader
    is there; `options` add faults or pacing. Readers open its link, which goes when it exits, so a reader
    reconnecting afterwards can never pick up a recycled /dev/pts number."""

    def __init__(self, tmp_path: Path, run_csv: Path, protocol: str, *options: str) -> None:
        self.ledger = tmp_path / "ledger.jsonl"
        self.path = str(tmp_path / "fog0")
        pacing = [] if "--speed" in options else ["--fast"]
        command = [*EMU, "--csv", str(run_csv), "--protocol", protocol, *pacing, "--wait-reader", "--link", self.path,
                   "--temp-rate-hz", "250", "--ledger", str(self.ledger), "--drain-s", DRAIN_S, *options]  # fmt: skip
        self.process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        assert self.process.stdout.readline().strip(), self.process.stderr.read()

    def finish(self, timeout_s: float = STALL_S) -> list[dict]:
        """Wait for the end of the run (while the emulator makes progress: a slow reader slows it); the ledger's
        lines."""
        status = wait_for_exit(self.process, "fogd-emu", max(timeout_s, STALL_S), watching([self.ledger]))
        assert status == 0, self.process.stderr.read()
        return [json.loads(line) for line in self.ledger.read_text().splitlines()]

    def kill(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
        self.process.wait()
        self.process.stdout.close()
        self.process.stderr.close()


def start_fogd(tmp_path: Path, port: str, model: Path, *args: str) -> Fogd:
    fogd = Fogd(tmp_path, "--port", port, "--model", str(model), "--rate-hz", str(RATE_HZ), "--status-interval-s", "60",
                "--protocol", "kvh-a", *args)  # named: these tests write frames only after fogd says it is reading
    try:
        fogd.wait_for("fogd.daemon: reading")
    except BaseException:
        fogd.kill()  # the caller never gets it to stop: a daemon left running outlives the suite
        raise
    return fogd


def wait_for_rows(path: Path, rows: int, timeout_s: float = STALL_S) -> None:
    """Until `path` holds `rows` lines; fails when it has not grown for `timeout_s` (at least STALL_S)."""
    wait_until(lambda: path.exists() and path.read_bytes().count(b"\n") >= rows, watching([path]),
               f"{path}: fewer than {rows} rows", max(timeout_s, STALL_S))  # fmt: skip


def run_samples(protocol: str, seed: int = 3) -> dict[str, np.ndarray]:
    """A run whose values survive the `protocol`'s wire exactly: float32 rates in its units, whole-degree
    temperatures that change only on every 4th sample (where fogd frames carry one)."""
    rng = np.random.default_rng(seed)
    rate = rng.normal(0.0, 2e-5, SAMPLES).astype(np.float32).astype(np.float64)
    rate_dph = rate * DPH_PER_RAD_S if protocol == "kvh-a" else (rate * DPH_PER_RAD_S).astype(np.float32).astype(np.float64)
    temp_c = np.round(20.0 + (np.arange(SAMPLES) // 4 * 4) * 2e-3)  # a 2 C/s ramp in whole degrees
    return {"t_s": np.arange(SAMPLES) / RATE_HZ, "rate_dph": rate_dph, "temp_c": temp_c}


def wire_frames(protocol: str, samples: dict[str, np.ndarray]) -> list[bytes]:
    """The frames a gyro of `protocol` sends for these samples (fogd: a temperature frame every 4th sample)."""
    codec = get(protocol)
    frames = []
    for i, (t_s, rate, temp) in enumerate(zip(samples["t_s"].tolist(), samples["rate_dph"].tolist(), samples["temp_c"].tolist())):
        if protocol == "kvh-a":
            frames.append(codec.encode(Frame("kvh-a", "imu", "A", i % 128, None, (1.0, -1.0, rate), ALL_AXES, ALL_AXES, temp)))
        elif protocol == "fogd":
            if i % 4 == 0:
                frames.append(codec.encode(Frame("fogd", "temp", "temp", i // 4, t_s, temp_c=temp)))
            frames.append(codec.encode(Frame("fogd", "rate", "rate", i, t_s, (1.0, -1.0, rate), ALL_AXES, ALL_AXES)))
        else:
            frames.append(codec.encode(Frame("ascii", "imu", "I", None, t_s, (np.nan, np.nan, rate), Z_ONLY, Z_ONLY, temp)))
    return frames


def write_run(path: Path, samples: dict[str, np.ndarray]) -> None:
    lines = [",".join(RUN_COLUMNS)]
    lines += [f"{t:.6f},{r!r},{c!r}" for t, r, c in zip(*(samples[name].tolist() for name in RUN_COLUMNS))]
    path.write_text("\n".join(lines) + "\n")


def replayed(tmp_path: Path, model: Path, samples: dict[str, np.ndarray]) -> np.ndarray:
    """fogd-replay's compensated CSV for these samples, as an array of OUT_COLUMNS."""
    run_path, out_path = tmp_path / "run.csv", tmp_path / "replay.csv"
    write_run(run_path, samples)
    assert replay.main([str(model), str(run_path), "-o", str(out_path)]) == 0
    return np.loadtxt(out_path, delimiter=",", skiprows=1, ndmin=2)


def assert_same_as_replay(output: np.ndarray, expected: np.ndarray) -> None:
    assert output.shape == expected.shape
    np.testing.assert_allclose(output[:, :6], expected[:, :6], rtol=1e-9, atol=1e-12)
    assert output[:, 6].tolist() == expected[:, 6].tolist()  # flags


def stream_through_fogd(tmp_path: Path, model: Path, samples: dict, protocol: str) -> tuple[Path, Fogd, float]:
    """Send `samples` through the emulator of `protocol` and the real daemon (csv out), stop the daemon with
    SIGTERM once every row is out; (the output file, the stopped daemon, seconds it slept stopping)."""
    run_csv, out = tmp_path / "run.csv", tmp_path / "out.csv"
    write_run(run_csv, samples)
    emu = Emu(tmp_path, run_csv, protocol)
    try:
        fogd = start_fogd(tmp_path, emu.path, model, "--protocol", protocol, "--out-format", "csv", "--out", str(out))
        try:
            emu.finish()
            wait_for_rows(out, SAMPLES + 1)
            status, slept_s = fogd.terminate()
        finally:
            fogd.kill()
    finally:
        emu.kill()
    assert status == 0, fogd.stderr
    return out, fogd, slept_s


@pytest.mark.parametrize("protocol", ["kvh-a", "fogd", "ascii"])
def test_recorded_run_through_emulator_and_fogd_equals_replay(tmp_path, model_path, protocol):
    samples = run_samples(protocol)
    out, fogd, slept_s = stream_through_fogd(tmp_path, model_path, samples, protocol)
    assert slept_s < 4.0, fogd.stderr  # prompt, and short of the 5 s write timeout a stuck exit would wait for
    assert out.read_text().splitlines()[0] == ",".join(OUT_COLUMNS)
    assert_same_as_replay(np.loadtxt(out, delimiter=",", skiprows=1, ndmin=2), replayed(tmp_path, model_path, samples))
    counters = fogd.counters()
    assert counters["writer"]["frames_written"] == SAMPLES
    assert counters["lexer"]["bad_crc"] == counters["lexer"]["truncated"] == counters["lexer"]["bad_line"] == 0


def expected_from_ledger(ledger: list[dict], repeats_dropped: bool = False) -> dict[str, np.ndarray]:
    """The samples fogd should compensate: every valid frame that was sent, in order, with the temperature
    held from the newest valid frame that carried one (`repeats_dropped`: not the copies a fogd or ascii
    sender repeated)."""
    rates, temps, held = [], [], np.nan
    for line in ledger:
        if not (line["sent"] and line["valid"]) or (repeats_dropped and line["faults"] == ["repeat"]):
            continue
        if line["kind"] in ("imu", "temp"):
            held = np.nan if line["temp_c"] is None else line["temp_c"]
        if line["kind"] in ("imu", "rate"):
            rates.append(np.nan if line["rate_dph"] is None else line["rate_dph"])
            temps.append(held)
    n = len(rates)
    return {"t_s": np.arange(n) / RATE_HZ, "rate_dph": np.array(rates), "temp_c": np.array(temps)}


FAULTS = {
    "kvh-a": ["--garbage", "0.05", "--bitflip", "0.05", "--drop", "0.03", "--repeat", "0.03", "--nan", "0.03", "--split", "0.05"],
    "fogd": ["--garbage", "0.05", "--bitflip", "0.05", "--drop", "0.03", "--repeat", "0.03", "--nan", "0.03", "--split", "0.05"],
    # a flipped bit in a text line may still parse as another number, so ascii gets no bit flips
    "ascii": ["--garbage", "0.05", "--drop", "0.03", "--repeat", "0.03", "--nan", "0.03", "--split", "0.05"],
}


@pytest.mark.parametrize("protocol", list(FAULTS))
def test_emulator_faults_are_counted_and_no_valid_frame_is_lost(tmp_path, model_path, protocol):
    samples = run_samples(protocol, seed=7)
    run_csv, out = tmp_path / "run.csv", tmp_path / "out.csv"
    write_run(run_csv, samples)
    emu = Emu(tmp_path, run_csv, protocol, *FAULTS[protocol], "--fault-seed", "4")
    try:
        fogd = start_fogd(tmp_path, emu.path, model_path, "--protocol", protocol, "--out-format", "csv", "--out", str(out))
        try:
            ledger = emu.finish()
            expected = expected_from_ledger(ledger, repeats_dropped=protocol != "kvh-a")
            wait_for_rows(out, len(expected["rate_dph"]) + 1)
            assert fogd.terminate()[0] == 0
        finally:
            fogd.kill()
    finally:
        emu.kill()
    output = np.loadtxt(out, delimiter=",", skiprows=1, ndmin=2)
    reference = replayed(tmp_path, model_path, expected)
    assert output.shape == reference.shape  # one output row per valid rate frame, none lost, none extra
    np.testing.assert_allclose(output[:, 1:6], reference[:, 1:6], rtol=1e-9, atol=1e-12)
    assert output[:, 6].tolist() == reference[:, 6].tolist()
    sent = [line for line in ledger if line["sent"]]
    corrupted = [line for line in sent if not line["valid"]]
    lexer = fogd.counters()["lexer"]
    repeats = sum(1 for line in sent if line["faults"] == ["repeat"] and line["valid"])
    assert lexer["frames_ok"] + lexer["frames_repeated"] == len(sent) - len(corrupted)
    assert lexer["frames_repeated"] == (0 if protocol == "kvh-a" else repeats)  # copies dropped, counted
    assert lexer["bad_crc"] + lexer["truncated"] + lexer["bad_line"] == len(corrupted) + (
        sum(1 for line in sent if line["garbage_bytes"]) if protocol == "ascii" else 0
    )
    assert len(corrupted) > 0 or protocol == "ascii"
    if protocol != "ascii":  # ascii lines carry no sequence number: a repeat is just another sample
        assert lexer["seq_repeats"] == sum(1 for line in sent if line["faults"] == ["repeat"] and line["valid"]) > 0


def test_same_output_is_kvh_with_compensated_z(tmp_path, gyro, model_path):
    samples = run_samples("kvh-a")
    frames = wire_frames("kvh-a", samples)
    out = tmp_path / "out.bin"
    fogd = start_fogd(tmp_path, gyro.path, model_path, "--out", str(out))
    try:
        gyro.write(b"".join(frames))
        wait_until(lambda: out.exists() and out.stat().st_size >= 36 * SAMPLES, watching([out]), "same output")
        assert fogd.terminate()[0] == 0
    finally:
        fogd.kill()
    lexer = Lexer(get("kvh-a"))
    decoded = lexer.feed(out.read_bytes())
    assert len(decoded) == SAMPLES and lexer.counters.bad_crc == 0 and lexer.counters.seq_gaps == 0
    expected = replayed(tmp_path, model_path, samples)
    rate_z = np.array([frame.rate_dph[2] for frame in decoded])
    np.testing.assert_allclose(rate_z, expected[:, 5], rtol=2**-23, atol=1e-9)  # float32 on the wire
    assert all(out_frame.raw[4:12] == in_frame[4:12] and out_frame.raw[16:32] == in_frame[16:32]
               for out_frame, in_frame in zip(decoded, frames))  # fmt: skip


@pytest.mark.parametrize("kind", ["paper's inputs", "lag bank", "undithered lag bank"])
def test_the_daemon_maps_neither_scikit_learn_nor_scipy(tmp_path, gyro, model_path, kind):
    """The frozen evaluators are numpy only, and the daemon's lag filters run in Python floats: the running
    daemon, after compensating a burst of frames, has neither library's files mapped (memory, attack surface),
    with the paper's inputs or fogd-train's kind of model (a lag bank)."""
    if kind != "paper's inputs":
        model_path = lag_bank_model_file(tmp_path, undither=(1.0, 0.16) if kind.startswith("undithered") else None)
    out = tmp_path / "out.csv"
    fogd = start_fogd(tmp_path, gyro.path, model_path, "--out", str(out), "--out-format", "csv")
    try:
        gyro.write(b"".join(wire_frames("kvh-a", run_samples("kvh-a"))))
        wait_for_rows(out, SAMPLES + 1)
        maps = Path(f"/proc/{fogd.process.pid}/maps").read_text()
        assert fogd.terminate()[0] == 0
    finally:
        fogd.kill()
    assert "/numpy/" in maps  # the check can see a package's files
    assert "/sklearn/" not in maps and "/scipy/" not in maps


def test_corrupted_frames_are_counted_and_no_valid_frame_is_lost(tmp_path, gyro, model_path):
    samples = run_samples("kvh-a", seed=5)
    frames = wire_frames("kvh-a", samples)
    rng = np.random.default_rng(11)
    stream, valid, flipped = [], [], 0
    for i, frame in enumerate(frames):
        fault = rng.integers(0, 10)
        if fault == 0:  # garbage before the frame, including a false header
            stream.append(b"\xfe\x81\xff" + bytes(rng.integers(0, 256, 20, dtype=np.uint8)))
        if fault == 1:  # a bit flip: the CRC must catch it
            damaged = bytearray(frame)
            damaged[int(rng.integers(4, 36))] ^= 1 << int(rng.integers(0, 8))
            stream.append(bytes(damaged))
            flipped += 1
            continue
        if fault == 2:  # dropped on the way
            continue
        stream.append(frame)
        valid.append(i)
    out = tmp_path / "out.csv"
    fogd = start_fogd(tmp_path, gyro.path, model_path, "--out-format", "csv", "--out", str(out))
    try:
        data = b"".join(stream)
        cuts = np.cumsum(rng.integers(1, 200, len(data) // 50))  # split reads: frames cut across writes
        for start, stop in zip([0, *cuts.tolist()], [*cuts.tolist(), len(data)]):
            gyro.write(data[start:stop])
        wait_for_rows(out, len(valid) + 1)
        assert fogd.terminate()[0] == 0
    finally:
        fogd.kill()
    output = np.loadtxt(out, delimiter=",", skiprows=1, ndmin=2)
    kept = {name: values[valid] for name, values in samples.items()}
    kept["t_s"] = np.arange(len(valid)) / RATE_HZ  # fogd numbers the samples it receives
    assert_same_as_replay(output, replayed(tmp_path, model_path, kept))
    lexer = fogd.counters()["lexer"]
    assert lexer["frames_ok"] == len(valid)
    assert lexer["bad_crc"] + lexer["truncated"] >= flipped


def test_sigterm_while_streaming_exits_zero_with_whole_rows_flushed(tmp_path, gyro, model_path):
    out = tmp_path / "out.csv"
    fogd = start_fogd(tmp_path, gyro.path, model_path, "--out-format", "csv", "--out", str(out))
    try:
        gyro.write(b"".join(wire_frames("kvh-a", run_samples("kvh-a"))))
        wait_for_rows(out, 100)
        status, slept_s = fogd.terminate()
    finally:
        fogd.kill()
    assert status == 0 and slept_s < 4.0  # prompt (asleep, not waiting for a CPU), short of the 5 s write timeout
    text = out.read_text()
    assert text.endswith("\n")
    assert text.count("\n") - 1 == fogd.counters()["writer"]["frames_written"]


def test_sigabrt_writes_every_threads_stack_to_stderr(tmp_path, gyro, model_path):
    """What systemd's watchdog sends a hung daemon (SIGABRT) leaves, in the journal, where each thread was:
    the loop waiting in the daemon, the reader polling the port."""
    out = tmp_path / "out.csv"
    fogd = start_fogd(tmp_path, gyro.path, model_path, "--out-format", "csv", "--out", str(out))
    try:
        gyro.write(b"".join(wire_frames("kvh-a", run_samples("kvh-a"))))
        wait_for_rows(out, SAMPLES)
        # every thread waiting, as in a hang: faulthandler reads other threads' frames unlocked, and one that
        # is running meanwhile can crash the dump (its documented limit)
        time.sleep(0.5)
        fogd.process.send_signal(signal.SIGABRT)
        status = fogd.process.wait(10)
    finally:
        fogd.kill()
    assert status == -signal.SIGABRT, fogd.stderr
    stacks = fogd.stderr.split("Fatal Python error: Aborted", 1)[1]
    assert stacks.count("most recent call first") >= 3, stacks  # main, reader, writer
    for module in ("fogd/serving/daemon.py", "fogd/serving/reader.py", "fogd/serving/outputs.py"):
        assert module in stacks, stacks


def one_line_failure(tmp_path: Path, *args: str) -> tuple[int, str]:
    result = subprocess.run([*FOGD, *args], capture_output=True, text=True, timeout=20, cwd=tmp_path)
    assert "Traceback" not in result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("fogd: "), result.stderr
    return result.returncode, lines[0]


def test_bad_input_gives_one_line_and_the_right_exit_status(tmp_path, gyro, model_path):
    model = str(model_path)
    bad_model = tmp_path / "bad-model.json"
    bad_model.write_text('{"format": "fogd-model", "version": 1}')
    cases = [
        (["--port", gyro.path, "--model", model, "--protocol", "nmea"], 2, "nmea"),
        (["--port", str(tmp_path / "ttyNONE"), "--model", model], 74, "no such port"),
        (["--port", gyro.path, "--model", model, "--out", str(tmp_path / "no" / "dir" / "out")], 74, "cannot open output"),
        (["--port", gyro.path, "--model", str(bad_model)], 65, "bad-model.json"),
        (["--port", gyro.path, "--model", str(tmp_path / "missing.json")], 78, "missing.json"),
    ]
    for args, status, text in cases:
        got_status, line = one_line_failure(tmp_path, *args)
        assert (got_status, text in line) == (status, True), line


@pytest.mark.parametrize(
    "config, text",
    [
        ("out_fromat: csv\n", "unknown key 'out_fromat'"),
        ("rate_hz: fast\n", "'rate_hz' must be a number"),
        ("rate_hz: -5\n", "'rate_hz'"),
        ("out_format: xml\n", "'out_format' is 'xml'"),
        ("protocol: [kvh-a]\n", "'protocol' must be a string"),
        ("port: /dev/x\n  bad: indent\n", "not valid YAML"),
    ],
)
def test_broken_config_is_exit_78_in_one_line(tmp_path, model_path, config, text):
    path = tmp_path / "fogd.yaml"
    path.write_text(config)
    status, line = one_line_failure(tmp_path, "--config", str(path), "--model", str(model_path))
    assert status == 78 and text in line, line


def test_busy_port_is_refused_while_another_fogd_holds_it(tmp_path, gyro, model_path):
    first = start_fogd(tmp_path, gyro.path, model_path, "--out", os.devnull)
    try:
        status, line = one_line_failure(tmp_path, "--port", gyro.path, "--model", str(model_path))
        assert status == 74 and "busy" in line
    finally:
        assert first.terminate()[0] == 0


def test_command_line_wins_over_config(tmp_path, gyro, model_path):
    path = tmp_path / "fogd.yaml"
    path.write_text(f"port: {gyro.path}\nout_format: jsonl\nout: {tmp_path / 'from-config.out'}\n")
    out = tmp_path / "out.csv"
    fogd = start_fogd(tmp_path, gyro.path, model_path, "--config", str(path), "--out-format", "csv", "--out", str(out))
    try:
        gyro.write(b"".join(wire_frames("kvh-a", run_samples("kvh-a"))[:10]))
        wait_for_rows(out, 11)
    finally:
        assert fogd.terminate()[0] == 0
    assert out.read_text().startswith("t_s,rate_dph") and not (tmp_path / "from-config.out").exists()


def kvh_run_through_fogd_equals_replay(tmp_path: Path, model: Path, seed: int) -> np.ndarray:
    """Stream a simulated run as KVH Format A through the emulator and the real daemon (csv out), check the
    output equals fogd-replay of the same run, and return replay's rows."""
    samples = run_samples("kvh-a", seed=seed)
    out, _, _ = stream_through_fogd(tmp_path, model, samples, "kvh-a")
    output, expected = np.loadtxt(out, delimiter=",", skiprows=1, ndmin=2), replayed(tmp_path, model, samples)
    assert_same_as_replay(output, expected)
    return expected


def test_multi_scale_guarded_model_through_fogd_equals_replay(tmp_path):
    """A kernel model on temperature, two eq. 16 windows and a lagged temperature, with a joint-space domain
    guard (part of the run is OUT_OF_DOMAIN and uses the linear fallback): the daemon equals replay."""
    from fogd.core.inputs import parse_inputs

    inputs = parse_inputs("temp,rate@0.5,rate@1.5,lag@0.8", average_s=0.05)
    model = tmp_path / "multi.json"
    doc = modelfile.document(
        name="e2e-multi", method="pso-svr", inputs=inputs,
        x_mean=np.array([22.0, 1.0, 1.0, 21.0]), x_scale=np.array([2.0, 1.0, 1.0, 2.0]), y_mean=0.1, y_scale=0.5,
        domain_min=np.array([-40.0, -5.0, -5.0, -40.0]), domain_max=np.array([80.0, 5.0, 5.0, 80.0]),
        params={"support_vectors": [[0.0, 0.5, 0.5, 0.0], [-1.0, 1.0, 0.0, -1.0]], "dual_coef": [0.7, -0.4],
                "gamma": 0.3, "trend_coef": [0.2, 0.1, 0.05, -0.1], "intercept": 0.01},
        reference_dph=0.0, training={}, metrics={}, created_utc="2024-01-01T00:00:00Z",
        domain_guard={"points": [[t, 1.0, 1.0, t] for t in np.linspace(-1.0, 0.5, 16)], "threshold": 0.6,
                      "fallback": {"method": "linear", "params": {"coef": [0.3, 0.0, 0.0, 0.0], "intercept": 0.0}}},
    )  # fmt: skip
    modelfile.save(model, doc)
    expected = kvh_run_through_fogd_equals_replay(tmp_path, model, seed=5)
    flags = expected[:, 6].astype(int)
    assert ((flags & 32) != 0).any() and ((flags & 32) == 0).sum() > SAMPLES // 4  # both branches were used


def lag_bank_model_file(tmp_path: Path, dequantise_c: float | None = None,
                        undither: tuple[float, float] | None = None) -> Path:  # fmt: skip
    """A model like fogd-train's default (an SVR on a polynomial trend over a bank of lags, version 2; of the
    dequantised temperature with `dequantise_c`, or of the undithered one with `undither` (resolution, noise),
    version 4), its calibrated domain ending at 22 C so that a run past it is clamped."""
    from fogd.core.inputs import dequantised, parse_inputs, undithered

    inputs = dequantised(parse_inputs("lags@0.3,1,3,10"), dequantise_c)
    if undither:
        inputs = undithered(inputs, *undither)
    powers = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1], [2, 0, 0, 0], [3, 0, 0, 0], [0, 2, 0, 0]]
    model = tmp_path / "bank.json"
    doc = modelfile.document(
        name="e2e-bank", method="pso-svr", inputs=inputs,
        x_mean=np.full(4, 22.0), x_scale=np.full(4, 2.0), y_mean=0.1, y_scale=0.5,
        domain_min=np.full(4, -40.0), domain_max=np.full(4, 22.0),
        params={"support_vectors": [[0.0, 0.1, 0.2, 0.3], [-1.0, -0.5, 0.0, 0.5]], "dual_coef": [0.7, -0.4],
                "gamma": 0.3, "trend_coef": [0.2, -0.3, 0.05, 0.1, 0.02, -0.01, 0.03], "trend_powers": powers,
                "intercept": 0.01},
        reference_dph=0.0, training={}, metrics={}, created_utc="2024-01-01T00:00:00Z",
    )  # fmt: skip
    modelfile.save(model, doc)
    return model


def test_lag_bank_model_with_polynomial_trend_through_fogd_equals_replay(tmp_path):
    """fogd-train's default kind of model (an SVR on a polynomial trend over a bank of lags, model file
    version 2), with a calibrated domain the run leaves so the lags' shifted clamp is exercised: the daemon
    equals replay."""
    model = lag_bank_model_file(tmp_path)
    assert json.loads(model.read_text())["version"] == 2
    expected = kvh_run_through_fogd_equals_replay(tmp_path, model, seed=7)
    flags = expected[:, 6].astype(int)
    assert ((flags & 2) != 0).any() and ((flags & 2) == 0).any()  # clamped and unclamped samples both served


def test_lag_bank_model_with_a_play_input_through_fogd_equals_replay(tmp_path):
    """fogd-train's default for a fine sensor (a bank of lags and the play operator, model file version 5): the
    daemon, frame by frame, equals replay."""
    from fogd.core.inputs import parse_inputs

    inputs = parse_inputs("lags@0.3,1,10,play@0.2")
    powers = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1], [2, 0, 0, 0], [3, 0, 0, 0]]
    model = tmp_path / "play.json"
    doc = modelfile.document(
        name="e2e-play", method="pso-svr", inputs=inputs,
        x_mean=np.array([22.0, 22.0, 22.0, 0.0]), x_scale=np.array([2.0, 2.0, 2.0, 0.5]), y_mean=0.1, y_scale=0.5,
        domain_min=np.array([-40.0, -40.0, -40.0, -1.0]), domain_max=np.array([80.0, 80.0, 80.0, 1.0]),
        params={"support_vectors": [[0.0, 0.1, 0.2, 1.0], [-1.0, -0.5, 0.0, -1.0]], "dual_coef": [0.7, -0.4],
                "gamma": 0.3, "trend_coef": [0.2, -0.3, 0.1, 0.4, 0.02, -0.01], "trend_powers": powers,
                "intercept": 0.01},
        reference_dph=0.0, training={}, metrics={}, created_utc="2024-01-01T00:00:00Z",
    )  # fmt: skip
    modelfile.save(model, doc)
    assert json.loads(model.read_text())["version"] == 5
    kvh_run_through_fogd_equals_replay(tmp_path, model, seed=7)


def test_dequantised_lag_bank_model_through_fogd_equals_replay(tmp_path):
    """fogd-train's default for a KVH's whole degrees (the lags of the dequantised temperature, model file
    version 4): the daemon, frame by frame, equals replay."""
    model = lag_bank_model_file(tmp_path, dequantise_c=1.0)
    assert json.loads(model.read_text())["version"] == 4
    expected = kvh_run_through_fogd_equals_replay(tmp_path, model, seed=7)
    assert np.unique(expected[:, 2]).size > 3  # the run's temperature crosses levels: the dequantiser works


def test_undithered_lag_bank_model_through_fogd_equals_replay(tmp_path):
    """fogd-train's default for a fine sensor with noise of its own (the lags of the undithered temperature, model
    file version 4; here of the run's whole degrees, as one with 0.16 C of noise would be read): the daemon,
    frame by frame, equals replay."""
    model = lag_bank_model_file(tmp_path, undither=(1.0, 0.16))
    assert json.loads(model.read_text())["version"] == 4
    expected = kvh_run_through_fogd_equals_replay(tmp_path, model, seed=7)
    assert np.unique(expected[:, 2]).size > 3  # the run's temperature crosses levels: the estimate moves
