"""A three-axis IMU end to end over a real pty: fogd-emu streams six channels (simulated or a recorded
multi-channel run; rate or delta output) and fogd-record, a separate process, records them; the recorded
channels are the emulated ones to float32 wire precision. Bad combinations of options are one line."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from progress import wait_for_exit, wait_until, watching
from stopping import stop

from fogd.core.columns import ACCEL_CHANNELS, CHANNELS, GYRO_CHANNELS
from fogd.core.runio import read_run
from fogd.protocols.kvh import DPH_PER_RAD_S, KvhProtocol
from fogd.protocols.lexer import Lexer
from fogd.simulation import profiles
from fogd.simulation.emulator import Emulator, SimSource
from fogd.simulation.simulator import Simulation

EMU = [sys.executable, "-m", "fogd.cli.emu"]
RECORD = [sys.executable, "-m", "fogd.cli.record"]
RATE_HZ = 200.0
COUNT = 600
FLOAT32 = 2.0**-23  # relative spacing of float32: the wire's precision
DRAIN_S = "600"  # fogd-emu's wait at its end for the reader to take the last bytes: over as soon as it has
UNIT_OPTIONS = {
    "rate": [],
    "delta": ["--rotfmt", "delta", "--linfmt", "delta"],
    "delta-deg-ft": ["--rotfmt", "delta", "--angle-unit", "deg", "--linfmt", "delta", "--lin-unit", "ft"],
}


def wait_for_rows(path: Path, rows: int, process: subprocess.Popen) -> None:
    """Until `path` holds `rows` lines, while it grows or `process` (its writer) works."""
    wait_until(lambda: path.exists() and path.read_bytes().count(b"\n") >= rows, watching([path], [process]),
               f"{path}: fewer than {rows} lines", alive=[process])  # fmt: skip


def emulate_and_record(tmp_path: Path, source: list[str], emu_options: list[str], record_options: list[str],
                       rows: int) -> tuple[list[dict], Path, str]:  # fmt: skip
    """fogd-emu (on a link, once a reader is there) and fogd-record on it until `rows` rows are written;
    returns the emulator's ledger, the recorded CSV and fogd-record's stderr."""
    link, ledger, output = tmp_path / "imu0", tmp_path / "ledger.jsonl", tmp_path / "rec.csv"
    emu = subprocess.Popen([*EMU, *source, "--fast", "--wait-reader", "--link", str(link), "--ledger", str(ledger),
                            "--drain-s", DRAIN_S, *emu_options], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    record_err = open(tmp_path / "record.stderr", "w+b")
    record = None
    try:
        assert emu.stdout.readline().strip(), emu.stderr.read()
        record = subprocess.Popen([*RECORD, "--port", str(link), "-o", str(output), "--rate-hz", str(RATE_HZ),
                                   *record_options], stdout=subprocess.DEVNULL, stderr=record_err)  # fmt: skip
        assert wait_for_exit(emu, "fogd-emu", watch=watching([ledger, output], [record])) == 0, emu.stderr.read()
        wait_for_rows(output, rows + 1, record)
        assert stop(record, (tmp_path / "record.stderr").read_text) == 0
    finally:
        for process in (emu, record):
            if process is not None and process.poll() is None:
                process.kill()
                process.wait()
        emu.stdout.close()
        emu.stderr.close()
        record_err.close()
    lines = [json.loads(line) for line in ledger.read_text().splitlines()]
    return lines, output, (tmp_path / "record.stderr").read_text()


@pytest.mark.parametrize("units", list(UNIT_OPTIONS))
def test_a_simulated_imu_through_emu_and_record_keeps_all_six_channels(tmp_path, units):
    options = UNIT_OPTIONS[units]
    source = ["--profile", "fast-ramp", "--imu", "--rate-hz", str(RATE_HZ), "--seed", "4", "--count", str(COUNT)]
    ledger, output, stderr = emulate_and_record(tmp_path, source, options, ["--channels", "all", *options], COUNT)
    recorded = read_run(output)
    assert "Traceback" not in stderr
    assert list(recorded.channels) == list(CHANNELS) and recorded.rows == COUNT
    # exactly what the wire carried, as the emulator's own decoder read each frame
    for axis, channel in enumerate(GYRO_CHANNELS):
        np.testing.assert_array_equal(recorded.channels[channel], [line["rates_dph"][axis] for line in ledger], channel)
    for axis, channel in enumerate(ACCEL_CHANNELS):
        np.testing.assert_array_equal(recorded.channels[channel], [line["accel_g"][axis] for line in ledger], channel)
    # and the simulated IMU itself, to float32 precision in the unit's own units (whole degrees for temperature)
    simulated = Simulation(profiles.builtin("fast-ramp"), RATE_HZ, 4).imu_columns(0, COUNT)
    for channel in CHANNELS:
        np.testing.assert_allclose(recorded.channels[channel], simulated[channel], rtol=2 * FLOAT32, atol=0, err_msg=channel)
    np.testing.assert_array_equal(recorded.temp_c, np.round(simulated["temp_c"]))
    np.testing.assert_allclose(recorded.t_s, simulated["t_s"], atol=1e-6)
    assert np.mean(recorded.channels["accel_z_g"]) == pytest.approx(1.0, abs=5e-3)  # gravity, in g whatever the wire


def test_delta_output_is_per_sample_on_the_wire():
    """Read as if the unit sent rates, the delta bytes on the pty are the simulated channels divided by the data
    rate (and by g, in m/s): the emulator really sends increments, not rates in disguise."""
    from test_emulator import stream

    sim = Simulation(profiles.builtin("fast-ramp"), RATE_HZ, 2)
    emulator = Emulator(SimSource(profiles.builtin("fast-ramp"), RATE_HZ, 2, imu=True), "kvh-a", speed=None, count=100,
                        protocol_options={"rotfmt": "delta", "linfmt": "delta"})  # fmt: skip
    lexer = Lexer(KvhProtocol())  # a reader that takes the fields as rad/s and g
    frames = lexer.feed(stream(emulator)) + lexer.flush()
    as_rates = np.array([frame.rate_dph for frame in frames])
    as_accels = np.array([frame.accel_g for frame in frames])
    simulated = sim.imu_columns(0, 100)
    assert len(frames) == 100
    for axis, channel in enumerate(GYRO_CHANNELS):
        np.testing.assert_allclose(as_rates[:, axis] * RATE_HZ, simulated[channel], rtol=2 * FLOAT32, err_msg=channel)
    for axis, channel in enumerate(ACCEL_CHANNELS):
        np.testing.assert_allclose(as_accels[:, axis] * RATE_HZ / 9.80665, simulated[channel], rtol=2 * FLOAT32, err_msg=channel)


@pytest.mark.parametrize("protocol", ["kvh-a", "fogd"])
def test_a_recorded_multi_channel_run_plays_and_records_back_exactly(tmp_path, protocol):
    rng = np.random.default_rng(11)
    rows = 400
    # values a float32 wire carries exactly: float32 in the wire's units (rad/s, g; fogd: deg/h)
    gyro_rad_s = rng.normal(0.0, 3e-5, (rows, 3)).astype(np.float32).astype(np.float64)
    gyro_dph = gyro_rad_s * DPH_PER_RAD_S if protocol == "kvh-a" else (gyro_rad_s * DPH_PER_RAD_S).astype(np.float32).astype(np.float64)
    accel_g = (rng.normal(0.0, 1e-3, (rows, 3)) + [0.0, 0.0, 1.0]).astype(np.float32).astype(np.float64)
    t_s = np.arange(rows) / RATE_HZ
    temp_c = np.round(25.0 + np.arange(rows) // 40)
    run_csv = tmp_path / "imu_run.csv"
    table = np.column_stack([t_s, gyro_dph, accel_g, temp_c])
    header = ",".join(["t_s", *CHANNELS, "temp_c"])
    np.savetxt(run_csv, table, delimiter=",", header=header, comments="", fmt="%.17g")
    _, output, stderr = emulate_and_record(
        tmp_path, ["--csv", str(run_csv)], ["--protocol", protocol],
        ["--protocol", protocol, "--channels", "all"], rows,
    )  # fmt: skip
    recorded = read_run(output)
    assert list(recorded.channels) == list(CHANNELS) and recorded.rows == rows, stderr
    for axis, channel in enumerate(GYRO_CHANNELS):
        np.testing.assert_array_equal(recorded.channels[channel], gyro_dph[:, axis], channel)
    for axis, channel in enumerate(ACCEL_CHANNELS):
        np.testing.assert_array_equal(recorded.channels[channel], accel_g[:, axis], channel)
    np.testing.assert_array_equal(recorded.temp_c, temp_c)


def one_line(command: list[str]) -> tuple[int, str]:
    result = subprocess.run(command, capture_output=True, text=True, timeout=60)
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr, result.stderr
    return result.returncode, result.stderr


@pytest.mark.parametrize(
    ("command", "text"),
    [
        ([*EMU, "--profile", "fast-ramp", "--protocol", "fogd", "--rotfmt", "delta"], "kvh-a only"),
        ([*EMU, "--profile", "fast-ramp", "--protocol", "ascii", "--imu"], "one gyro axis"),
        ([*RECORD, "--port", "/dev/null", "-o", "/dev/null", "--protocol", "ascii", "--channels", "accel_x_g"], "do not carry"),
        ([*RECORD, "--port", "/dev/null", "-o", "/dev/null", "--channels", "rate_w_dph"], "unknown channel"),
        ([*RECORD, "--port", "/dev/null", "-o", "/dev/null", "--channels", "all", "--axis", "x"], "give one of them"),
        ([*RECORD, "--port", "/dev/null", "-o", "/dev/null", "--protocol", "ascii", "--linfmt", "delta"], "kvh-a only"),
    ],
)  # fmt: skip
def test_option_mistakes_are_one_line(command, text):
    status, stderr = one_line(command)
    assert status != 0 and text in stderr
