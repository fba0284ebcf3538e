"""The offline commands as a user runs them: fogd-sim -> fogd-train -> fogd-replay, and their one-line errors."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fogd.core import modelfile
from fogd.core.runio import read_run

QUICK_PSO = ["--particles", "4", "--iterations", "2", "-q"]


def command(name: str, *args: str | Path) -> subprocess.CompletedProcess:
    module = {"fogd-sim": "sim", "fogd-train": "train", "fogd-replay": "replay"}[name]
    return subprocess.run(
        [sys.executable, "-m", f"fogd.cli.{module}", *map(str, args)], capture_output=True, text=True, timeout=300
    )


def assert_one_line_error(result: subprocess.CompletedProcess, status: int, *words: str) -> None:
    assert result.returncode == status, result.stderr
    assert "Traceback" not in result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    for word in words:
        assert word in lines[0]


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    """Two short simulated chamber runs at 10 Hz: one to train on, one held out."""
    folder = tmp_path_factory.mktemp("runs")
    profiles = {"heat": [[600, 5], [3600, 35], [600, 35]], "cool": [[600, 30], [3000, 10], [600, 10]]}
    paths = {}
    for name, segments in profiles.items():
        profile = folder / f"{name}.yaml"
        profile.write_text(json.dumps(segments))  # JSON is YAML
        paths[name] = folder / f"{name}.csv"
        result = command("fogd-sim", "--profile", profile, "-o", paths[name], "--rate-hz", "10", "--seed", "4")
        assert result.returncode == 0, result.stderr
    return paths


def test_sim_train_replay_round_trip(runs, tmp_path):
    model_path = tmp_path / "model.json"
    trained = command(
        "fogd-train", runs["heat"], "-o", model_path, "--method", "linear", "--block-s", "60", "-q",
        "--inputs", "paper", "--domain-guard",  # the paper's inputs, so the rows below can be checked by hand
    )  # fmt: skip
    assert trained.returncode == 0, trained.stderr
    assert "Table 3" in trained.stdout and "linear" in trained.stdout
    model = modelfile.load(model_path)
    document = json.loads(model_path.read_text())
    assert document["training"]["runs"][0]["name"] == "heat.csv"
    assert document["inputs"][1] == {"kind": "temp_rate_cps", "window_s": 50.0, "average_s": 0.5, "step_s": 0.0}

    out = tmp_path / "out.csv"
    replayed = command("fogd-replay", model_path, runs["cool"], "-o", out)
    assert replayed.returncode == 0, replayed.stderr
    assert "Table 4" in replayed.stdout and "Best possible" in replayed.stdout
    # cool.csv: 4200 s at 10 Hz; 600 s of settling skipped, then 36 blocks of 100 s
    assert "36 blocks of 100 s from 600 s after the first row" in replayed.stdout
    assert re.search(r"^domain guard: \d+\.\d % of samples took the linear fallback; \d+\.\d % were clamped$",
                     replayed.stdout, re.M)  # fmt: skip
    unsettled = command("fogd-replay", model_path, runs["cool"], "--settle-s", "0", "--no-allan")
    assert unsettled.returncode == 0 and "42 blocks of 100 s from 0 s after the first row" in unsettled.stdout
    recorded = read_run(runs["cool"])
    header = out.read_text().splitlines()[0]
    assert header == "t_s,rate_dph,temp_c,temp_rate_cps,comp_dph,rate_comp_dph,flags"
    table = np.loadtxt(out, delimiter=",", skiprows=1)
    assert table.shape == (recorded.rows, 7)  # one output row per input row, in order
    np.testing.assert_array_equal(table[:, 0], np.round(recorded.t_s, 6))
    np.testing.assert_allclose(table[:, 5], table[:, 1] - table[:, 4], atol=1e-6)
    warm = (table[:, 6].astype(int) & 1) == 0
    assert warm.sum() == recorded.rows - 499  # 50 s window at 10 Hz
    # the compensation is the model evaluated on the logged inputs (no clamping inside the range)
    inside = warm & ((table[:, 6].astype(int) & 2) == 0)
    expected, _ = model.predict(table[inside][:, [2, 3]])
    np.testing.assert_allclose(table[inside, 4], expected, rtol=1e-6, atol=1e-8)


def test_compare_and_holdout_print_every_method(runs, tmp_path):
    result = command(
        "fogd-train", runs["heat"], "--compare", "--inputs", "paper", "--holdout", runs["cool"], "--block-s", "60", *QUICK_PSO
    )
    assert result.returncode == 0, result.stderr
    table3, table4 = result.stdout.split("Table 4")
    for method in ("linear", "ls-poly", "rbf-nn", "pso-svr"):
        assert method in table3 and method in table4
    assert "cool.csv" in table4 and "Best possible" in table4


@pytest.mark.parametrize(
    "args, status, words",
    [
        (["--method", "magic"], 2, ["--method", "magic"]),
        (["--frobnicate"], 2, ["--frobnicate"]),
        (["--reference", "warm"], 2, ["--reference"]),
        (["--particles", "0"], 2, ["--particles"]),
        (["--window-s", "0.2", "--average-s", "0.5"], 2, ["window"]),
        ([], 2, ["-o"]),
    ],
)
def test_train_option_errors(runs, args, status, words):
    extra = [] if args == [] else ["-o", "/dev/null"]
    assert_one_line_error(command("fogd-train", runs["heat"], *extra, *args), status, *words)


def test_train_data_errors(runs, tmp_path):
    missing = tmp_path / "nope.csv"
    assert_one_line_error(command("fogd-train", missing, "-o", tmp_path / "m.json"), 66, "nope.csv")  # EX_NOINPUT
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    assert_one_line_error(command("fogd-train", empty, "-o", tmp_path / "m.json"), 65, "empty.csv", "empty")
    short = tmp_path / "short.csv"
    short.write_text("t_s,rate_dph,temp_c\n" + "".join(f"{i / 10},7.5,20\n" for i in range(300)))
    assert_one_line_error(command("fogd-train", short, "-o", tmp_path / "m.json"), 65, "short.csv", "too short")
    bad_cell = tmp_path / "cell.csv"
    bad_cell.write_text("t_s,rate_dph,temp_c\n0,1,2\n0.1,x,2\n")
    assert_one_line_error(command("fogd-train", bad_cell, "-o", tmp_path / "m.json"), 65, "cell.csv:3", "column 2")


def test_train_refuses_a_run_that_cannot_calibrate(tmp_path):
    """Long enough, but isothermal, or with a span under 5 C: one line saying what a calibration run needs."""
    rows = 20_000  # 2000 s at 10 Hz
    for name, span_c in (("flat", 0.0), ("narrow", 3.0)):
        path = tmp_path / f"{name}.csv"
        temps = 20.0 + span_c * np.arange(rows) / rows
        path.write_text("t_s,rate_dph,temp_c\n" + "".join(f"{i / 10},7.5,{t:.4f}\n" for i, t in enumerate(temps)))
        result = command("fogd-train", path, "-o", tmp_path / "m.json", "--method", "linear")
        assert_one_line_error(result, 65, f"{name}.csv", "5 C", "calibration run must")
        assert not (tmp_path / "m.json").exists()


def test_train_refuses_a_model_worse_than_no_compensation(runs, tmp_path):
    """A gyro with no thermal error at all: any model's held-out drift exceeds the uncompensated drift, so the
    model is refused in one line naming both figures; --force writes it, with a warning."""
    quiet = tmp_path / "quiet.csv"
    data = read_run(runs["heat"])
    rng = np.random.default_rng(0)
    rate = 7.5 + rng.normal(0.0, 0.05, data.rows)
    quiet.write_text("t_s,rate_dph,temp_c\n" + "".join(
        f"{t:.1f},{r:.6f},{c:.4f}\n" for t, r, c in zip(data.t_s.tolist(), rate.tolist(), data.temp_c.tolist())))  # fmt: skip
    model = tmp_path / "m.json"
    args = [quiet, "-o", model, "--method", "ls-poly", "--inputs", "paper", "--degree", "5", "--block-s", "60"]
    result = command("fogd-train", *args)
    assert result.returncode == 65 and "Traceback" not in result.stderr
    refusal = result.stderr.strip().splitlines()[-1]  # after the fit's summary lines
    assert all(word in refusal for word in ("held-out drift", "uncompensated drift", "--force")), refusal
    assert not model.exists()
    forced = command("fogd-train", *args, "--force")
    assert forced.returncode == 0, forced.stderr
    assert "written anyway" in forced.stderr and model.exists()


def test_replay_errors(runs, tmp_path):
    pickle_file = tmp_path / "model.pkl"
    pickle_file.write_bytes(b"\x80\x04\x95\x00")
    assert_one_line_error(command("fogd-replay", pickle_file, runs["cool"]), 65, "pickle")
    model = tmp_path / "model.json"
    # the paper's inputs: a 50 s estimator window the short run cannot fill
    trained = command("fogd-train", runs["heat"], "-o", model, "--method", "linear", "-q", "--inputs", "paper")
    assert trained.returncode == 0, trained.stderr
    short = tmp_path / "short.csv"
    short.write_text("t_s,rate_dph,temp_c\n" + "".join(f"{i / 10},7.5,20\n" for i in range(100)))
    assert_one_line_error(command("fogd-replay", model, short), 65, "short.csv", "estimator window")
    under_a_file = model / "out.csv"
    assert_one_line_error(command("fogd-replay", model, runs["cool"], "-o", under_a_file), 74, "out.csv")  # EX_IOERR
