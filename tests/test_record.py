"""fogd-record on the emulator's pty: the CSV it writes reads back with fogd.core.runio.read_run and holds the
values the emulator sent, also across an unplug; SIGTERM stops it cleanly."""

import subprocess
import sys
from collections.abc import Callable

import numpy as np
import pytest
import stopping
from test_daemon_e2e import RATE_HZ, Emu, run_samples, wait_for_rows, write_run

from fogd.core.runio import Run, read_run

RECORD = [sys.executable, "-m", "fogd.cli.record"]


def record(tmp_path, port: str, *args: str) -> tuple[subprocess.Popen, object]:
    stderr = open(tmp_path / "record.stderr", "wb")
    process = subprocess.Popen(
        [*RECORD, "--port", port, "-o", str(tmp_path / "rec.csv"), "--rate-hz", str(RATE_HZ), *args],
        stdout=subprocess.DEVNULL, stderr=stderr,
    )  # fmt: skip
    return process, stderr


def sent_valid(ledger: list[dict]) -> list[dict]:
    return [line for line in ledger if line["sent"] and line["valid"] and line["kind"] in ("imu", "rate")]


def stop(process: subprocess.Popen, tmp_path) -> int:
    return stopping.stop(process, (tmp_path / "record.stderr").read_text)


def record_emulated(tmp_path, samples: dict, protocol: str, rows: Callable[[list], int], *options: str) -> Run:
    """`samples` streamed by fogd-emu and recorded by fogd-record until `rows(ledger)` rows are in rec.csv."""
    run_csv = tmp_path / "run.csv"
    write_run(run_csv, samples)
    emu = Emu(tmp_path, run_csv, protocol)
    process, stderr = record(tmp_path, emu.path, "--protocol", protocol, *options)
    try:
        ledger = emu.finish()
        wait_for_rows(tmp_path / "rec.csv", rows(ledger) + 1)
        assert stop(process, tmp_path) == 0
    finally:
        emu.kill()
        if process.poll() is None:
            process.kill()
        stderr.close()
    return read_run(tmp_path / "rec.csv")


@pytest.mark.parametrize("protocol", ["kvh-a", "fogd"])
def test_record_writes_the_emulators_values(tmp_path, protocol):
    samples = run_samples(protocol)
    recorded = record_emulated(tmp_path, samples, protocol, lambda ledger: len(sent_valid(ledger)))
    assert recorded.rows == len(samples["t_s"])
    np.testing.assert_array_equal(recorded.rate_dph, samples["rate_dph"])
    np.testing.assert_array_equal(recorded.temp_c, samples["temp_c"])
    np.testing.assert_allclose(recorded.t_s, samples["t_s"], atol=1e-6)
    assert "Traceback" not in (tmp_path / "record.stderr").read_text()


def test_record_decimate_writes_the_means_of_groups(tmp_path):
    samples = run_samples("fogd")
    groups = len(samples["t_s"]) // 4
    recorded = record_emulated(tmp_path, samples, "fogd", lambda ledger: groups, "--decimate", "4")
    assert recorded.rows == groups
    whole = groups * 4
    for column in ("t_s", "rate_dph", "temp_c"):
        expected = samples[column][:whole].reshape(-1, 4).mean(axis=1)
        np.testing.assert_allclose(getattr(recorded, column), expected, rtol=1e-12, atol=1e-6, err_msg=column)
    assert recorded.rate_hz == pytest.approx(RATE_HZ / 4)


def test_record_survives_an_unplug(tmp_path):
    samples = run_samples("kvh-a")
    run_csv = tmp_path / "run.csv"
    write_run(run_csv, samples)
    emu = Emu(tmp_path, run_csv, "kvh-a", "--speed", "1", "--unplug-every-s", "1.0", "--unplug-for-s", "0.3")
    process, stderr = record(tmp_path, emu.path)
    try:
        ledger = emu.finish()
        expected = sent_valid(ledger)
        wait_for_rows(tmp_path / "rec.csv", len(expected) + 1)
        assert stop(process, tmp_path) == 0
    finally:
        emu.kill()
        if process.poll() is None:
            process.kill()
        stderr.close()
    assert any(not line["sent"] for line in ledger)  # the unplug really cost frames
    recorded = read_run(tmp_path / "rec.csv")
    np.testing.assert_array_equal(recorded.rate_dph, [line["rate_dph"] for line in expected])
    log = (tmp_path / "record.stderr").read_text()
    assert "port lost" in log and "port back" in log and "Traceback" not in log


def test_missing_port_is_one_line(tmp_path):
    result = subprocess.run([*RECORD, "--port", str(tmp_path / "ttyNONE"), "-o", str(tmp_path / "x.csv")],
                            capture_output=True, text=True, timeout=20)  # fmt: skip
    assert result.returncode == 74 and result.stderr.count("\n") == 1 and "no such port" in result.stderr
