"""Issue 35 items 2-4 with the real daemon on real ptys: the estimator runs at the rate the frames' own clock
says (one warning naming both rates), a channel the model wants and the frames never carry is reported and
counted, a repeated frame goes out once and a clock that went back is flagged."""

from __future__ import annotations

import json
import subprocess
import time

import numpy as np
from stopping import stop  # noqa: F401
from test_daemon_e2e import FOGD, Fogd, Pty, gyro, model_path, wait_for_rows  # noqa: F401  (fixtures)

from fogd.cli.top import render
from fogd.core.flags import Flag
from fogd.protocols import get
from fogd.protocols.base import ALL_AXES, Z_ONLY, Frame

FOGD_CODEC = get("fogd")
WAIT_S = 60.0


def rate_frame(seq: int, t_s: float, present=ALL_AXES) -> bytes:
    rates = tuple(1.0 if on else float("nan") for on in present)
    return FOGD_CODEC.encode(Frame("fogd", "rate", "rate", seq, t_s, rates, present, present))


def temp_frame(seq: int, t_s: float, temp_c: float) -> bytes:
    return FOGD_CODEC.encode(Frame("fogd", "temp", "temp", seq, t_s, temp_c=temp_c))


def wait_for(fogd: Fogd, text: str, feed) -> None:
    """Feed frames until `text` is in fogd's log (progress, not a deadline, is what is waited on)."""
    deadline = time.monotonic() + WAIT_S
    while text not in fogd.stderr:
        assert fogd.process.poll() is None, fogd.stderr
        assert time.monotonic() < deadline, f"fogd never said {text!r}: {fogd.stderr}"
        feed()


def test_a_200_hz_stream_runs_the_estimator_at_200_hz_whatever_rate_hz_says(tmp_path, gyro, model_path):  # noqa: F811
    """A 200 Hz stream with a 0.1 C/s ramp read as 0.5 C/s at the default 1000 Hz, flags 0, no warning."""
    out, stats = tmp_path / "out.csv", tmp_path / "stats.json"
    fogd = Fogd(tmp_path, "--port", gyro.path, "--model", str(model_path), "--protocol", "fogd", "--out", str(out),
                "--out-format", "csv", "--stats-file", str(stats), "--status-interval-s", "60")  # fmt: skip
    sent = [0]

    def feed(frames: int = 50) -> None:  # 50 frames of 200 Hz device time, about 5,000 frames/s of wall time
        data = []
        for i in range(sent[0], sent[0] + frames):
            t_s = i / 200.0
            data.append(temp_frame(i, t_s, 20.0 + 0.1 * t_s) + rate_frame(i, t_s))
        gyro.write(b"".join(data))
        sent[0] += frames
        time.sleep(0.01)

    try:
        fogd.wait_for("fogd.daemon: reading")
        fogd.wait_for("(the default)")  # the rate line follows the reading line: wait for it, never race it
        wait_for(fogd, "frames' own clock says", feed)
        for _ in range(40):  # 2,000 frames more: 10 s of device time, twenty windows of 0.5 s
            feed()
        wait_for_rows(out, sent[0] + 1)
        time.sleep(1.5)  # the stats file is written every second
        snapshot = json.loads(stats.read_text())
        status = subprocess.run([*FOGD, "--status", "--stats-file", str(stats)], capture_output=True, text=True).stdout
        assert stop(fogd.process, lambda: fogd.stderr) == 0
    finally:
        fogd.kill()
    warnings = [line for line in fogd.stderr.splitlines() if "own clock says" in line]
    assert len(warnings) == 1 and "200 Hz" in warnings[0] and "1000 Hz" in warnings[0], warnings
    assert snapshot["rate"]["in_use_hz"] == 200.0 and "rate 200 Hz (the frames' clock" in status
    rows = np.loadtxt(out, delimiter=",", skiprows=1, ndmin=2)
    temp_rate_cps, flags = rows[-500:, 3], rows[-500:, 6].astype(int)
    assert not np.any(flags & Flag.WARMUP)
    np.testing.assert_allclose(temp_rate_cps, 0.1, rtol=0.02)  # not 0.5


def test_a_channel_the_frames_never_carry_is_warned_about_counted_and_shown(tmp_path, gyro, model_path):  # noqa: F811
    """`--axis x` on a z-only fogd stream: every sample RATE_INVALID, invalid_axes 0, no warning."""
    stats = tmp_path / "stats.json"
    fogd = Fogd(tmp_path, "--port", gyro.path, "--model", str(model_path), "--protocol", "fogd", "--axis", "x",
                "--rate-hz", "1000", "--stats-file", str(stats), "--status-interval-s", "60")  # fmt: skip
    sent = [0]

    def feed() -> None:
        gyro.write(b"".join(temp_frame(i, i / 1000, 25.0) + rate_frame(i, i / 1000, Z_ONLY)
                            for i in range(sent[0], sent[0] + 20)))  # fmt: skip
        sent[0] += 20
        time.sleep(0.01)

    try:
        fogd.wait_for("fogd.daemon: reading")
        wait_for(fogd, "frames carry no", feed)
        deadline = time.monotonic() + WAIT_S
        while not stats.exists() or "MISSING" not in json.loads(stats.read_text()).get("status", ""):
            assert time.monotonic() < deadline, fogd.stderr
            feed()
        status = subprocess.run([*FOGD, "--status", "--stats-file", str(stats)], capture_output=True, text=True).stdout
        top = "\n".join(render(json.loads(stats.read_text()), str(stats)))  # what fogd-top shows
        assert stop(fogd.process, lambda: fogd.stderr) == 0
    finally:
        fogd.kill()
    warning = [line for line in fogd.stderr.splitlines() if "frames carry no" in line]
    assert len(warning) == 1 and "rate_x_dph" in warning[0], warning
    assert "MISSING rate_x_dph" in status
    assert "MISSING  rate_x_dph" in top, top
    counters = json.loads(fogd.stderr.split("fogd.status: counters ", 1)[1].splitlines()[0])
    assert counters["loop"]["samples_missing_channel"] == counters["loop"]["samples_compensated"] > 0


def test_a_repeated_frame_goes_out_once_and_a_clock_that_went_back_is_flagged(tmp_path, gyro, model_path):  # noqa: F811
    out = tmp_path / "out.csv"
    fogd = Fogd(tmp_path, "--port", gyro.path, "--model", str(model_path), "--protocol", "fogd", "--rate-hz", "1000",
                "--out", str(out), "--out-format", "csv", "--status-interval-s", "60")  # fmt: skip
    times = [i / 1000 for i in range(100)]
    times[60] = 0.0305  # back by 29 ms at frame 60
    frames = [temp_frame(0, 0.0, 25.0)] + [rate_frame(i, t_s) for i, t_s in enumerate(times)]
    frames.insert(31, frames[31])  # frame 30 sent twice (the same sequence number)
    try:
        fogd.wait_for("fogd.daemon: reading")
        gyro.write(b"".join(frames))
        wait_for_rows(out, 101)
        assert stop(fogd.process, lambda: fogd.stderr) == 0
    finally:
        fogd.kill()
    rows = np.loadtxt(out, delimiter=",", skiprows=1, ndmin=2)
    assert len(rows) == 100  # the copy dropped
    flagged = [i for i, flags in enumerate(rows[:, 6].astype(int)) if flags & Flag.TIME_BACKWARDS]
    assert flagged == [60]
    lexer = json.loads(fogd.stderr.split("fogd.status: counters ", 1)[1].splitlines()[0])["lexer"]
    assert (lexer["frames_repeated"], lexer["time_backwards"]) == (1, 1)


def test_kvh_a_says_which_rate_it_assumes_and_where_it_came_from(tmp_path, gyro, model_path):  # noqa: F811
    """Issue 36 item 5: leaving out --rate-hz with kvh-a silently assumed 1000 Hz."""
    said = {}
    for given in ([], ["--rate-hz", "500"]):
        fogd = Fogd(tmp_path, "--port", gyro.path, "--model", str(model_path), "--protocol", "kvh-a", *given)
        try:
            fogd.wait_for("fogd.daemon: reading")
            fogd.wait_for("kvh-a frames carry no time")
            assert stop(fogd.process, lambda: fogd.stderr) == 0
        finally:
            fogd.kill()
        said[bool(given)] = [line for line in fogd.stderr.splitlines() if "carry no time" in line]
    assert said[False] == ["fogd.daemon: kvh-a frames carry no time: assuming 1000 Hz, the default rate_hz; set "
                           "rate_hz to the unit's data rate (or query_settings: true to read it from the unit)"]
    assert said[True] == ["fogd.daemon: kvh-a frames carry no time: 500 Hz from the config"]
