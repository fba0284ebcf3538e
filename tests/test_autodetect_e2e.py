"""--protocol auto, the default, with the real daemon on real ptys: fogd-emu's kvh-a, fogd and ascii each
recognised from at most a second of the stream, said in one line with the measured rate, and every frame of
the run (those read while detecting too) compensated as fogd-replay does; another protocol's text or random
bytes get one warning saying what the bytes look like and what was tried, and SIGTERM still exits 0."""

from __future__ import annotations

import re
import signal

import numpy as np
import pytest
from test_daemon_e2e import (  # noqa: F401, F811 (model_path, gyro: fixtures)
    RATE_HZ,
    SAMPLES,
    Emu,
    Fogd,
    assert_same_as_replay,
    gyro,
    model_path,
    replayed,
    run_samples,
    wait_for_rows,
    write_run,
)

FOUND = re.compile(r"fogd\.daemon: protocol auto: (\S+) on \S+ \((\d+) valid frames in a row, ([\d.]+) s of the stream; (.*)\)$")
NMEA = b"$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47\r\n$GPVTG,054.7,T,034.4,M,005.5,N,010.2,K*48\r\n"


@pytest.mark.parametrize("protocol", ["kvh-a", "fogd", "ascii"])
def test_each_protocol_from_the_emulator_is_recognised_and_no_frame_is_lost(tmp_path, model_path, protocol):
    samples = run_samples(protocol)
    run_csv, out = tmp_path / "run.csv", tmp_path / "out.csv"
    write_run(run_csv, samples)
    emu = Emu(tmp_path, run_csv, protocol, "--speed", "1")  # paced at RATE_HZ, as a unit sends
    try:
        fogd = Fogd(tmp_path, "--port", emu.path, "--model", str(model_path), "--rate-hz", str(RATE_HZ),
                    "--out-format", "csv", "--out", str(out), "--stats-file", "none")  # fmt: skip
        try:
            emu.finish()
            wait_for_rows(out, SAMPLES + 1)
            status, _ = fogd.terminate()
        finally:
            fogd.kill()
    finally:
        emu.kill()
    assert status == 0, fogd.stderr
    found = [FOUND.match(line) for line in fogd.stderr.splitlines() if "protocol auto" in line]
    assert len(found) == 1 and found[0] is not None, fogd.stderr
    name, frames, span_s, rate = found[0].groups()
    assert name == protocol and int(frames) >= 5
    assert float(span_s) <= 1.0  # what it took to decide, in the stream's own time (not this machine's)
    if protocol != "kvh-a":  # fogd frames and ascii I lines carry the device's time
        assert rate == f"{RATE_HZ:.4g} samples/s by the device's clock"
    # every sample, those read while detecting included, compensated exactly as the replay does
    assert_same_as_replay(np.loadtxt(out, delimiter=",", skiprows=1, ndmin=2), replayed(tmp_path, model_path, samples))
    assert "nothing recognised" not in fogd.stderr


@pytest.mark.parametrize(
    "data, looks_like",
    [(NMEA * 30, "printable text, e.g. '$GP"), (np.random.default_rng(5).bytes(3000), "binary with no known header")],
    ids=["nmea", "random"],
)
def test_a_stream_no_protocol_matches_gets_one_warning_and_sigterm_exits_0(tmp_path, model_path, gyro, data, looks_like):
    fogd = Fogd(tmp_path, "--port", gyro.path, "--model", str(model_path), "--stats-file", "none")
    try:
        gyro.write(data)
        fogd.wait_for("nothing recognised", timeout_s=30.0)
        gyro.write(data)
        status, _ = fogd.terminate()
    finally:
        fogd.kill()
    assert status == 0, fogd.stderr
    warnings = [line for line in fogd.stderr.splitlines() if "nothing recognised" in line]
    assert len(warnings) == 1, fogd.stderr
    assert warnings[0].startswith(f"fogd.daemon: protocol auto: nothing recognised on {gyro.path} in 3 s: {looks_like}")
    assert "tried kvh-a, fogd, ascii" in warnings[0] and "Traceback" not in fogd.stderr


def test_a_silent_port_gets_one_warning_that_nothing_was_read(tmp_path, model_path, gyro):
    fogd = Fogd(tmp_path, "--port", gyro.path, "--model", str(model_path), "--stats-file", "none")
    try:
        fogd.wait_for("nothing read from", timeout_s=30.0)
        status, _ = fogd.terminate()
    finally:
        fogd.kill()
    assert status == 0, fogd.stderr
    warnings = [line for line in fogd.stderr.splitlines() if "protocol auto" in line]
    assert warnings == [f"fogd.daemon: protocol auto: nothing read from {gyro.path} in 3 s; still listening for kvh-a, "
                        "fogd, ascii. Is the unit on, streaming, and on this port?"], fogd.stderr  # fmt: skip


def test_sighup_and_sigusr1_while_detecting_do_not_end_fogd(tmp_path, model_path, gyro):
    fogd = Fogd(tmp_path, "--port", gyro.path, "--model", str(model_path), "--stats-file", "none")
    try:
        fogd.wait_for("nothing read from", timeout_s=30.0)  # still detecting
        fogd.process.send_signal(signal.SIGHUP)
        fogd.process.send_signal(signal.SIGUSR1)
        gyro.write(NMEA)  # fogd reads on after both (what it reads is not recognised: it goes on detecting)
        status, _ = fogd.terminate()
    finally:
        fogd.kill()
    assert status == 0, fogd.stderr
