"""fogd-train --inputs / --method auto and fogd-replay's Allan summary, end to end on short simulated runs."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from fogd.core import modelfile
from fogd.core.inputs import describe_inputs


def command(module: str, *args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", f"fogd.cli.{module}", *map(str, args)], capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("runs")
    paths = {}
    for profile, seed in (("paper-train", 1), ("cooling", 2), ("paper-test", 3)):
        paths[profile] = out / f"{profile}.csv"
        result = command("sim", "--profile", profile, "-o", paths[profile], "--rate-hz", "2", "--seed", seed)
        assert result.returncode == 0, result.stderr
    return paths


def test_inputs_option_is_carried_by_model_and_replay(runs, tmp_path):
    model = tmp_path / "m.json"
    result = command("train", runs["paper-train"], runs["cooling"], "-o", model, "--method", "rbf-nn",
                     "--inputs", "temp,rate@50,rate@300,lag@600", "--domain-guard", "-q")  # fmt: skip
    assert result.returncode == 0, result.stderr
    loaded = modelfile.load(model)
    assert describe_inputs(loaded.inputs) == "temp,rate@50,rate@300,lag@600"
    assert "domain_guard" in json.loads(model.read_text())  # asked for; off by default
    plot = tmp_path / "allan.png"
    result = command("replay", model, runs["paper-test"], "-o", tmp_path / "out.csv", "--allan-plot", plot)
    assert result.returncode == 0, result.stderr
    assert "ARW (deg/sqrt h)" in result.stdout and "after compensation" in result.stdout
    assert plot.stat().st_size > 1000


def test_method_auto_prints_and_stores_the_selection(runs, tmp_path):
    model = tmp_path / "auto.json"
    result = command("train", runs["paper-train"], runs["cooling"], "-o", model, "--method", "auto",
                     "--auto-inputs", "temp,rate@50", "--auto-inputs", "temp,rate@50,lag@600",
                     "--particles", "4", "--iterations", "2", "-q", "--report", tmp_path / "report")  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert "Model selection (--method auto)" in result.stdout and "<- chosen" in result.stdout
    selection = json.loads(model.read_text())["training"]["selection"]
    assert len(selection["candidates"]) == 5  # linear, ls-poly, pso-svr; no plain linear on the set with a lag
    assert selection["folds"] == "5 blocked time folds of every run"  # two runs: not one left out
    chosen = selection["chosen"]
    assert f"(nested held-out RMSE {chosen['held_out_rmse_dph']:.3e} deg/h)" in result.stdout
    assert "Model selection" in (tmp_path / "report" / "report.md").read_text()


@pytest.mark.parametrize(
    "args, words",
    [
        (["--inputs", "temp,speed@3"], "speed@3"),
        (["--auto-inputs", "temp,rate@50"], "--auto-inputs goes with --method auto"),
        (["--method", "auto", "--compare"], "--compare"),
    ],
)
def test_bad_options_give_one_line(runs, tmp_path, args, words):
    result = command("train", runs["paper-train"], "-o", tmp_path / "m.json", *args)
    assert result.returncode != 0 and words in result.stderr and "Traceback" not in result.stderr


def test_a_whole_degree_run_is_fitted_from_the_offline_estimate_unless_asked(tmp_path):
    """A KVH-like sensor (whole degrees at 1 Hz): fogd-train says how the dequantised inputs were fitted, and the
    model file records it; --fit-temperature causal fits them as the daemon computes them."""
    run = tmp_path / "whole.csv"
    result = command("sim", "--profile", "cycle", "-o", run, "--rate-hz", "2", "--seed", 4,
                     "--sensor-resolution-c", 1, "--sensor-rate-hz", 1)  # fmt: skip
    assert result.returncode == 0, result.stderr
    for option, said, stored in (((), "fitted from its offline estimate", "smoothed"),
                                 (("--fit-temperature", "causal"), "fitted as the daemon computes it", "as served")):
        model = tmp_path / f"m-{stored}.json"
        result = command("train", run, "-o", model, "--method", "linear", "--force", *option)
        assert result.returncode == 0, result.stderr
        assert said in result.stdout + result.stderr
        document = json.loads(model.read_text())
        assert document["training"]["fit_temperature"] == stored
        assert all(spec.dequantise_c == 1.0 for spec in modelfile.load(model).inputs)
