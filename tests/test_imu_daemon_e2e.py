"""A three-axis IMU through the real daemon over a real pty: fogd-emu streams a simulated KVH Format A IMU (rate
and delta output), fogd compensates all six channels with a version-3 model fogd-train wrote from simulated
IMU runs, and every channel of its output equals fogd-replay of the same recording (the samples the wire
carried, as the emulator's ledger decodes them, which is what fogd-record writes); x, y and the
accelerometers are compensated, not passed through. A model with only some channels compensates those and
passes the others through untouched, saying so at start and in its status; fogd-top and fogd --status show
each compensated channel in its own unit. `same` output re-encodes every compensated channel, in the unit's
own rate or delta units; `fogd` output is the six-channel compensated-IMU frame; the unit's settings are
queried at start when asked, and a contradiction stops fogd in one line."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from progress import STALL_S, wait_for_exit, wait_until, watching
from stopping import stop

from fogd.cli import replay, top
from fogd.core import modelfile
from fogd.core.channels import output_columns
from fogd.core.columns import ACCEL_CHANNELS, CHANNELS, GYRO_CHANNELS
from fogd.core.flags import describe
from fogd.protocols import get
from fogd.protocols.fogdbin import decode_comp_imu
from fogd.protocols.lexer import Lexer
from fogd.serving import statsfile

EMU = [sys.executable, "-m", "fogd.cli.emu"]
FOGD = [sys.executable, "-m", "fogd.cli.daemon"]
SIM = [sys.executable, "-m", "fogd.cli.sim"]
TRAIN = [sys.executable, "-m", "fogd.cli.train"]
RATE_HZ = 200.0
COUNT = 1500
UNITS = {"rate": [], "delta": ["--rotfmt", "delta", "--linfmt", "delta"]}
FLOAT32 = 2.0**-23
# --fast: fogd-emu writes as fast as fogd reads (the pty's back-pressure), whatever the machine's speed; at its end
# it waits at most DRAIN_S for fogd to take the last bytes (closing the pty earlier would throw them away), and
# returns as soon as fogd has
DRAIN_S = "600"


def run(command: list[str], cwd: Path) -> None:
    done = subprocess.run(command, cwd=cwd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]


@pytest.fixture(scope="module")
def models(tmp_path_factory) -> dict[str, Path]:
    """fogd-train's version-3 models from a simulated IMU chamber run (2 Hz, the linear fit: the point here is
    equality, not accuracy): every channel, and two of them."""
    where = tmp_path_factory.mktemp("imu-models")
    run([*SIM, "--profile", "fast-ramp", "--imu", "--rate-hz", "2", "--seed", "1", "-o", "cal.csv"], where)
    run([*TRAIN, "cal.csv", "-o", "imu.json", "--method", "linear", "--force", "-q"], where)
    run([*TRAIN, "cal.csv", "-o", "part.json", "--method", "linear", "--force", "-q",
         "--channels", "rate_x_dph,accel_z_g"], where)  # fmt: skip
    assert modelfile.load_channels(where / "imu.json").channels == CHANNELS
    return {"all": where / "imu.json", "part": where / "part.json"}


def wait_for(path: Path, predicate, what: str, process: subprocess.Popen, said) -> None:
    """Until `path` holds `what`, while it grows or `process` works (a wait on progress: a loaded machine is
    slower, not wrong); fails when `process` exits first."""
    wait_until(lambda: path.exists() and predicate(path.read_bytes()), watching([path], [process]), f"{path}: no {what}",
               STALL_S, alive=[process], said=said)  # fmt: skip


def through_fogd(tmp_path: Path, model: Path, emu_options: list[str], fogd_options: list[str],
                 done: callable) -> tuple[list[dict], Path, str]:  # fmt: skip
    """fogd-emu streams COUNT simulated IMU samples once fogd has the pty; fogd writes to out until `done`
    says the output is whole, then stops on SIGTERM. Returns the emulator's ledger, the output and fogd's
    stderr."""
    link, ledger, out = tmp_path / "imu0", tmp_path / "ledger.jsonl", tmp_path / "out"
    emu = subprocess.Popen([*EMU, "--profile", "fast-ramp", "--imu", "--rate-hz", str(RATE_HZ), "--seed", "4",
                            "--count", str(COUNT), "--fast", "--wait-reader", "--link", str(link), "--ledger",
                            str(ledger), "--drain-s", DRAIN_S, *emu_options], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    stderr_path = tmp_path / "fogd.stderr"
    fogd = None
    try:
        assert emu.stdout.readline().strip(), emu.stderr.read()
        with open(stderr_path, "wb") as stderr:
            fogd = subprocess.Popen([*FOGD, "--port", str(link), "--model", str(model), "--rate-hz", str(RATE_HZ),
                                     "--status-interval-s", "60", "--out", str(out), *fogd_options],
                                    stdout=subprocess.DEVNULL, stderr=stderr)  # fmt: skip
        assert wait_for_exit(emu, "fogd-emu", watch=watching([ledger, out], [fogd])) == 0, emu.stderr.read()
        wait_for(out, done, "whole output", fogd, stderr_path.read_text)
        assert stop(fogd, stderr_path.read_text) == 0, stderr_path.read_text()
    finally:
        for process in (emu, fogd):
            if process is not None and process.poll() is None:
                process.kill()
                process.wait()
        emu.stdout.close()
        emu.stderr.close()
    return [json.loads(line) for line in ledger.read_text().splitlines()], out, stderr_path.read_text()


def rows(count: int):
    return lambda data: data.count(b"\n") >= count


def recording(tmp_path: Path, ledger: list[dict]) -> Path:
    """The run fogd-record writes from this stream (t_s, the six channels as decoded, temp_c)."""
    path = tmp_path / "recorded.csv"
    lines = [",".join(["t_s", *CHANNELS, "temp_c"])]
    for i, line in enumerate(entry for entry in ledger if entry["sent"]):
        values = [*line["rates_dph"], *line["accel_g"], line["temp_c"]]
        lines.append(f"{i / RATE_HZ:.6f}," + ",".join(map(repr, values)))
    path.write_text("\n".join(lines) + "\n")
    return path


def replayed(tmp_path: Path, model: Path, run_csv: Path) -> tuple[list[str], np.ndarray]:
    out = tmp_path / "replay.csv"
    assert replay.main([str(model), str(run_csv), "-o", str(out), "--no-allan"]) == 0
    return out.read_text().split("\n", 1)[0].split(","), np.loadtxt(out, delimiter=",", skiprows=1, ndmin=2)


def assert_equal_tables(header: list[str], output: np.ndarray, expected_header: list[str], expected: np.ndarray) -> None:
    """Equal column for column (as the single-axis e2e test checks: values to 1e-9, flags exactly)."""
    assert header == expected_header
    assert output.shape == expected.shape
    for index, name in enumerate(header):
        if name.startswith("flags_"):
            assert output[:, index].tolist() == expected[:, index].tolist(), name
        else:
            np.testing.assert_allclose(output[:, index], expected[:, index], rtol=1e-9, atol=1e-12, err_msg=name)


@pytest.mark.parametrize("units", list(UNITS))
def test_a_kvh_imu_through_fogd_equals_replay_on_all_six_channels(tmp_path, models, units):
    ledger, out, stderr = through_fogd(tmp_path, models["all"], UNITS[units], [*UNITS[units], "--out-format", "csv"],
                                       rows(COUNT + 1))  # fmt: skip
    assert "6 channels" in stderr and "passes through" not in stderr, stderr
    header = out.read_text().split("\n", 1)[0].split(",")
    output = np.loadtxt(out, delimiter=",", skiprows=1, ndmin=2)
    expected_header, expected = replayed(tmp_path, models["all"], recording(tmp_path, ledger))
    assert_equal_tables(header, output, expected_header, expected)
    for channel in CHANNELS:  # every channel compensated: reading - comp, and comp is not nothing
        comp_name, compensated_name, _ = output_columns(channel)
        reading, comp, compensated = (output[:, header.index(name)] for name in (channel, comp_name, compensated_name))
        assert np.all(np.abs(comp) > 0), channel
        # each printed to nine significant digits: the difference holds to the sum of their roundings
        rounding = 1e-8 * (np.abs(reading) + np.abs(comp) + np.abs(compensated))
        assert np.all(np.abs(compensated - (reading - comp)) <= rounding), channel
        assert not np.any(compensated == reading), channel


def test_a_model_with_some_channels_compensates_those_and_passes_the_others_through(tmp_path, models):
    ledger, out, stderr = through_fogd(tmp_path, models["part"], [], ["--out-format", "csv"], rows(COUNT + 1))
    start = next(line for line in stderr.splitlines() if "compensates" in line)
    assert "rate_x_dph, accel_z_g" in start and "passes through rate_y_dph, rate_z_dph, accel_x_g, accel_y_g" in start
    header = out.read_text().split("\n", 1)[0].split(",")
    expected_header, expected = replayed(tmp_path, models["part"], recording(tmp_path, ledger))
    assert_equal_tables(header, np.loadtxt(out, delimiter=",", skiprows=1, ndmin=2), expected_header, expected)
    assert [name for name in header if name.startswith("flags_")] == ["flags_rate_x_dph", "flags_accel_z_g"]
    assert "comp_rate_y_dph" not in header and "rate_y_dph" in header  # passed through: the reading alone


def test_a_partial_model_is_flagged_in_the_status_and_fogd_top_shows_every_channel(tmp_path, models, capsys):
    """The channels passed through are named in the stats file and its status line, and carry the wire's readings
    untouched; fogd-top shows a row per compensated channel with the daemon's last compensation (the output's
    last row) in the channel's own unit and its flags, and names the channels passed through."""
    stats = tmp_path / "stats.json"
    ledger, out, _ = through_fogd(tmp_path, models["part"], [], ["--out-format", "csv", "--stats-file", str(stats)],
                                  rows(COUNT + 1))  # fmt: skip
    snapshot = json.loads(stats.read_text())
    passed = ["rate_y_dph", "rate_z_dph", "accel_x_g", "accel_y_g"]
    assert snapshot["channels"] == {"compensated": ["rate_x_dph", "accel_z_g"], "passed": passed}
    assert f"passed through: {', '.join(passed)}" in snapshot["status"]
    header = out.read_text().split("\n", 1)[0].split(",")
    output = np.loadtxt(out, delimiter=",", skiprows=1, ndmin=2)
    sent = [entry for entry in ledger if entry["sent"]]
    for channel in passed:
        accel = channel in ACCEL_CHANNELS
        axis = (ACCEL_CHANNELS if accel else GYRO_CHANNELS).index(channel)
        wire = [entry["accel_g" if accel else "rates_dph"][axis] for entry in sent]
        # the wire's float32 reading, printed to nine significant digits
        np.testing.assert_allclose(output[:, header.index(channel)], wire, rtol=1e-8, atol=0, err_msg=channel)
    capsys.readouterr()
    assert top.main(["--stats-file", str(stats), "--count", "1"]) == top.EXIT_NOT_RUNNING  # stopped: its last screen
    screen = capsys.readouterr().out.splitlines()
    for channel, spec, unit in (("rate_x_dph", "+.4f", "deg/h"), ("accel_z_g", "+.4g", "g")):
        comp_name, _, flags_name = output_columns(channel)
        last_comp, last_flags = output[-1, header.index(comp_name)], int(output[-1, header.index(flags_name)])
        row = next(line for line in screen if line.startswith(channel))
        assert row.split() == [channel, format(last_comp, spec), unit, *describe(last_flags).split()], row
    assert f"passed through untouched (no model for them): {', '.join(passed)}" in screen
    assert not any(line.startswith(channel) for line in screen for channel in passed)
    described = statsfile.describe(snapshot)  # fogd --status: each channel's compensation in its own unit
    for channel, unit in (("rate_x_dph", "deg/h"), ("accel_z_g", "g")):
        assert f"{channel} {output[-1, header.index(output_columns(channel)[0])]:+.6g} {unit}" in described, described


@pytest.mark.parametrize("units", list(UNITS))
def test_same_output_re_encodes_every_compensated_channel_in_the_units_own_units(tmp_path, models, units):
    """Format A frames out, in rate or delta output: each channel decodes (with the unit's settings) to
    replay's compensated value, to float32 precision; a channel the model does not cover keeps its bytes."""
    ledger, out, stderr = through_fogd(tmp_path, models["part"], UNITS[units], UNITS[units],
                                       lambda data: len(data) >= 36 * COUNT)  # fmt: skip
    protocol = get("kvh-a", rate_hz=RATE_HZ, **({"rotfmt": "delta", "linfmt": "delta"} if units == "delta" else {}))
    lexer = Lexer(protocol)
    decoded = lexer.feed(out.read_bytes())
    assert len(decoded) == COUNT and lexer.counters.bad_crc == 0, stderr
    header, expected = replayed(tmp_path, models["part"], recording(tmp_path, ledger))
    sent = [entry for entry in ledger if entry["sent"]]
    for channel in CHANNELS:
        accel, axis = channel in ACCEL_CHANNELS, (ACCEL_CHANNELS if channel in ACCEL_CHANNELS else GYRO_CHANNELS).index(channel)
        got = np.array([(frame.accel_g if accel else frame.rate_dph)[axis] for frame in decoded])
        if channel in ("rate_x_dph", "accel_z_g"):
            want = expected[:, header.index(output_columns(channel)[1])]
            np.testing.assert_allclose(got, want, rtol=4 * FLOAT32, atol=1e-12, err_msg=channel)
            assert not np.allclose(got, [entry["accel_g" if accel else "rates_dph"][axis] for entry in sent], rtol=0, atol=0)
        else:
            np.testing.assert_array_equal(got, [entry["accel_g" if accel else "rates_dph"][axis] for entry in sent], channel)


def test_fogd_output_is_one_compensated_imu_frame_per_sample(tmp_path, models):
    ledger, out, _ = through_fogd(tmp_path, models["part"], [], ["--out-format", "fogd"], lambda data: len(data) >= 111 * COUNT)
    lexer = Lexer(get("fogd"))
    frames = lexer.feed(out.read_bytes())
    assert len(frames) == COUNT and lexer.counters.bad_crc == 0
    header, expected = replayed(tmp_path, models["part"], recording(tmp_path, ledger))
    records = [decode_comp_imu(frame.raw) for frame in frames]
    assert all(record.covered == (True, False, False, False, False, True) for record in records)
    for i, channel in ((0, "rate_x_dph"), (5, "accel_z_g")):
        comp_name, compensated_name, flags_name = output_columns(channel)
        np.testing.assert_allclose([r.comp[i] for r in records], expected[:, header.index(comp_name)], rtol=FLOAT32, atol=1e-12)
        np.testing.assert_allclose([r.compensated[i] for r in records], expected[:, header.index(compensated_name)], rtol=FLOAT32)
        assert [r.flags[i] for r in records] == expected[:, header.index(flags_name)].astype(int).tolist()
    assert all(r.comp[1] == 0.0 and r.compensated[1] == r.rate_dph[1] and r.flags[1] == 0 for r in records)


def test_jsonl_output_names_every_channel_as_the_csv_does(tmp_path, models):
    _, out, _ = through_fogd(tmp_path, models["part"], [], ["--out-format", "jsonl"], rows(COUNT))
    first = json.loads(out.read_text().splitlines()[0])
    assert list(first) == ["t_s", "temp_c", "temp_rate_cps", "rate_x_dph", *output_columns("rate_x_dph"), "rate_y_dph",
                           "rate_z_dph", "accel_x_g", "accel_y_g", "accel_z_g", *output_columns("accel_z_g")]  # fmt: skip


@pytest.mark.parametrize("units", list(UNITS))
def test_the_units_settings_are_queried_at_start_and_agree(tmp_path, models, units):
    _, _, stderr = through_fogd(tmp_path, models["all"], UNITS[units],
                                [*UNITS[units], "--query-settings", "--out-format", "csv"], rows(100))  # fmt: skip
    rotfmt = "delta" if units == "delta" else "rate"
    assert f"unit settings on {tmp_path / 'imu0'} agree with the config: rotfmt {rotfmt}, angle_unit rad" in stderr
    assert "rate_hz 200" in stderr


def test_settings_that_contradict_the_unit_stop_fogd_in_one_line(tmp_path, models):
    link = tmp_path / "imu0"
    emu = subprocess.Popen([*EMU, "--profile", "fast-ramp", "--imu", "--rate-hz", str(RATE_HZ), "--fast", "--wait-reader",
                            "--link", str(link), "--rotfmt", "delta", "--drain-s", "0"],
                           stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)  # fmt: skip
    try:
        assert emu.stdout.readline().strip()
        result = subprocess.run([*FOGD, "--port", str(link), "--model", str(models["all"]), "--rate-hz", str(RATE_HZ),
                                 "--query-settings", "--out", os.devnull], capture_output=True, text=True, timeout=30)  # fmt: skip
    finally:
        emu.kill()
        emu.wait()
        emu.stdout.close()
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 78 and len(lines) == 1 and "Traceback" not in result.stderr, result.stderr
    assert "key 'rotfmt'" in lines[0] and "reports rotfmt delta" in lines[0]


@pytest.mark.parametrize(
    ("args", "text"),
    [
        (["--protocol", "ascii"], "does not carry"),
        (["--protocol", "fogd", "--rotfmt", "delta"], "applies to protocol kvh-a only"),
    ],
)
def test_a_model_channel_the_protocol_lacks_is_one_line_at_start(tmp_path, models, args, text):
    result = subprocess.run([*FOGD, "--port", "/dev/null", "--model", str(models["all"]), "--out", os.devnull, *args],
                            capture_output=True, text=True, timeout=30)  # fmt: skip
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 78 and len(lines) == 1 and text in lines[0], result.stderr
