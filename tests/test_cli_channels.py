"""fogd-train and fogd-replay on IMU runs: a model per channel in one file, each channel trained and replayed
exactly as its own single-axis run would be; a manifest of units, in parallel (joblib, and Dask's backend)."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from imu_runs import write_channel_run

from fogd.cli import replay as replay_cli
from fogd.cli import train as train_cli
from fogd.core import modelfile

CHOSEN = ("rate_y_dph", "accel_z_g")
FITTED_KEYS = ("method", "inputs", "input_scaling", "output_scaling", "domain", "params", "reference_dph", "metrics")


@pytest.fixture(scope="module")
def runs(imu_runs, tmp_path_factory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("imu")
    paths = dict(imu_runs)  # tests/conftest.py's, written once per session
    for channel in CHOSEN:
        for name in ("heat", "cool", "check"):
            paths[f"{name}-{channel}"] = write_channel_run(out / f"{name}-{channel}.csv", paths[name], channel)
    return paths


def main(command, args, capsys) -> tuple[int, str, str]:
    status = command.main([str(arg) for arg in args])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


@pytest.fixture(scope="module")
def imu_model(runs, tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("model") / "imu.json"
    args = [runs["heat"], runs["cool"], "-o", path, "--method", "linear", "--channels", ",".join(CHOSEN), "--jobs", "2", "-q"]
    assert train_cli.main([str(arg) for arg in args]) == 0
    return path


def test_each_channel_is_trained_as_its_own_single_axis_run(runs, imu_model, tmp_path, capsys):
    document = json.loads(imu_model.read_text())
    assert document["version"] == 3 and list(document["channels"]) == list(CHOSEN)
    for channel in CHOSEN:
        single = tmp_path / f"{channel}.json"
        status, _, err = main(train_cli, [runs[f"heat-{channel}"], runs[f"cool-{channel}"], "-o", single,
                                          "--method", "linear", "-q"], capsys)  # fmt: skip
        assert status == 0, err
        alone = json.loads(single.read_text())
        assert alone["version"] == 5  # the default inputs hold play@2: a version-5 file
        for key in FITTED_KEYS:
            assert document["channels"][channel][key] == alone[key], (channel, key)


def test_replay_compensates_the_model_channels_and_passes_the_others_through(runs, imu_model, tmp_path, capsys):
    out = tmp_path / "out.csv"
    status, stdout, err = main(replay_cli, [imu_model, runs["check"], "-o", out, "--no-allan"], capsys)
    assert status == 0, err
    assert stdout.count("Table 4: check.csv") == len(CHOSEN)
    assert "passed through unchanged" in stdout and "rate_x_dph, rate_z_dph, accel_x_g, accel_y_g" in stdout
    assert "RMSE (g)" in stdout and "RMSE (deg/h)" in stdout
    written = np.genfromtxt(out, delimiter=",", names=True)
    recorded = np.genfromtxt(runs["check"], delimiter=",", names=True)
    for channel in ("rate_x_dph", "rate_z_dph", "accel_x_g", "accel_y_g"):  # untouched, and no columns added
        np.testing.assert_array_equal(written[channel], recorded[channel])
        assert f"flags_{channel}" not in written.dtype.names
    models = modelfile.load_channels(imu_model)
    for channel in CHOSEN:  # each channel as the single-axis replay of that channel's own run gives it
        single_model = tmp_path / f"{channel}.json"
        modelfile.save(single_model, json.loads(imu_model.read_text())["channels"][channel])
        single_out = tmp_path / f"{channel}.csv"
        status, _, err = main(replay_cli, [single_model, runs[f"check-{channel}"], "-o", single_out, "--no-allan"], capsys)
        assert status == 0, err
        alone = np.genfromtxt(single_out, delimiter=",", names=True)
        stem, _, unit = channel.rpartition("_")
        # the stacked evaluator sums a channel's terms in another order than the model alone (StackedModels:
        # within 1e-12 of their size), which can move the last of the CSV's nine significant digits
        for column, single in ((f"{stem}_comp_{unit}", "rate_comp_dph"), (f"comp_{channel}", "comp_dph")):
            size = np.max(np.abs(alone[single]))
            np.testing.assert_allclose(written[column], alone[single], rtol=2e-9, atol=2e-9 * size)
        np.testing.assert_array_equal(written[f"flags_{channel}"], alone["flags"])
        assert models[channel].method == "linear"


def test_swarm_per_channel_in_parallel_with_a_report(runs, tmp_path, capsys):
    model, report = tmp_path / "svr.json", tmp_path / "report"
    status, stdout, err = main(train_cli, [runs["heat"], runs["cool"], "-o", model, "--channels", "rate_x_dph,accel_z_g",
                                           "--method", "pso-svr", "--particles", "6", "--iterations", "4", "--jobs", "2", "-q",
                                           "--report", report], capsys)  # fmt: skip
    assert status == 0, err
    assert stdout.index("=== rate_x_dph ===") < stdout.index("=== accel_z_g ===")
    models = modelfile.load_channels(model)
    assert models.channels == ("rate_x_dph", "accel_z_g")
    assert all(m.method == "pso-svr" for m in models.values())
    assert (report / "rate_x_dph" / "report.md").is_file() and (report / "accel_z_g" / "report.md").is_file()


@pytest.mark.parametrize(
    "args, words",
    [
        (["{heat}", "--channels", "rate_w_dph"], "--channels 'rate_w_dph'"),
        (["{heat-rate_y_dph}", "--channels", "rate_y_dph"], "single-axis run"),
        (["{heat}", "{cool-rate_y_dph}"], "single-axis run"),
        (["{heat}", "--manifest", "units.yaml"], "--manifest"),
    ],
)
def test_bad_channel_options_give_one_line(runs, tmp_path, capsys, args, words):
    args = [arg.format(**{k: str(v) for k, v in runs.items()}) for arg in args]
    status, _, err = main(train_cli, [*args, "-o", tmp_path / "m.json", "--method", "linear"], capsys)
    assert status != 0 and words in err and len(err.strip().splitlines()) == 1, err


def test_a_worse_channel_is_refused_by_name_and_forced_with_a_warning(runs, tmp_path, capsys):
    """rate_y_dph with its thermal error taken out is noise: a linear fit makes its held-out drift worse."""
    noisy = []
    for name in ("heat", "cool"):
        table = np.genfromtxt(runs[name], delimiter=",", names=True)
        names = list(table.dtype.names)
        flat = np.column_stack([table[n] - (table["true_error_rate_y_dph"] if n == "rate_y_dph" else 0) for n in names])
        noisy.append(tmp_path / f"{name}.csv")
        np.savetxt(noisy[-1], flat, delimiter=",", header=",".join(names), comments="", fmt="%.9g")
    model = tmp_path / "m.json"
    args = [*noisy, "-o", model, "--method", "linear", "--channels", "rate_x_dph,rate_y_dph", "-q"]
    status, _, err = main(train_cli, args, capsys)
    assert status != 0 and not model.exists()
    last = err.strip().splitlines()[-1]  # after each channel's summary lines
    assert last.startswith("fogd-train: rate_y_dph: the model's held-out drift") and "(--channels)" in last
    status, _, err = main(train_cli, [*args, "--force"], capsys)
    assert status == 0 and "warning: rate_y_dph: the model's held-out drift" in err and "rate_x_dph: the" not in err
    assert modelfile.load_channels(model).channels == ("rate_x_dph", "rate_y_dph")


def manifest(tmp_path: Path, runs: dict[str, Path], units: str) -> Path:
    for name in ("heat", "cool", "heat-rate_y_dph", "cool-rate_y_dph"):
        (tmp_path / f"{name}.csv").symlink_to(runs[name])
    (tmp_path / "models").mkdir(exist_ok=True)  # fogd-train creates no directories (issue 35.1)
    path = tmp_path / "units.yaml"
    path.write_text(units)
    return path


UNITS = """\
units:
  - name: imu-1
    runs: [heat.csv, cool.csv]
    channels: [rate_x_dph, accel_z_g]
  - name: gyro-2
    runs: [heat-rate_y_dph.csv, cool-rate_y_dph.csv]
    out: models/gyro-2.json
"""


def test_manifest_trains_every_unit_in_parallel(runs, tmp_path, capsys):
    path = manifest(tmp_path, runs, UNITS)
    status, stdout, err = main(train_cli, ["--manifest", path, "--method", "linear", "--jobs", "2", "-q"], capsys)
    assert status == 0, err
    imu = modelfile.load_channels(tmp_path / "imu-1.json")
    assert imu.version == 3 and imu.channels == ("rate_x_dph", "accel_z_g") and imu.name == "imu-1"
    gyro = modelfile.load(tmp_path / "models" / "gyro-2.json")  # single-axis runs: a version-2 file
    alone = tmp_path / "alone.json"
    assert train_cli.main([str(runs["heat-rate_y_dph"]), str(runs["cool-rate_y_dph"]), "-o", str(alone), "--method", "linear", "-q"]) == 0
    assert json.loads((tmp_path / "models" / "gyro-2.json").read_text())["params"] == json.loads(alone.read_text())["params"]
    assert gyro.method == "linear" and "=== imu-1: rate_x_dph ===" in stdout and "=== gyro-2 ===" in stdout


@pytest.mark.parametrize(
    "units, words",
    [
        ("units:\n  - name: a\n    runs: [heat.csv]\n    rusn: [cool.csv]\n", "unknown key(s) 'rusn'"),
        ("units:\n  - name: a\n    runs: [heat.csv, gone.csv]\n", "no run file"),
        ("units:\n  - name: a\n    runs: [heat.csv]\n  - name: a\n    runs: [cool.csv]\n", "same name 'a'"),
        ("units:\n  - name: a\n    runs: [heat.csv]\n  - name: b\n    runs: [cool.csv]\n    out: a.json\n", "same out"),
        ("units:\n  - name: a\n    name: b\n    runs: [heat.csv]\n", "appears twice"),
        ("units:\n  - name: a\n    runs: [heat.csv]\n    channels: [rate_w_dph]\n", "unknown channel 'rate_w_dph'"),
        ("units:\n  - name: ../a\n    runs: [heat.csv]\n", "name '../a'"),
        ("units:\n  - runs: [heat.csv]\n", "lacks name"),
        ("unit:\n  - name: a\n", "the one key 'units'"),
        ("units: [a, b", "not valid YAML"),
    ],
)
def test_bad_manifest_gives_one_line(runs, tmp_path, capsys, units, words):
    path = manifest(tmp_path, runs, units)
    status, _, err = main(train_cli, ["--manifest", path, "--method", "linear", "-q"], capsys)
    assert status != 0 and words in err and len(err.strip().splitlines()) == 1, err


def test_manifest_through_joblibs_dask_backend_on_a_local_cluster(runs, tmp_path, capsys):
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError as error:
        message = f"dask.distributed is not installed ({error}); pip install -e '.[test]' runs this test"
        print(message)
        pytest.skip(message)
    from joblib import parallel_config

    path = manifest(tmp_path, runs, UNITS)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            Client(cluster) as client, parallel_config(backend="dask"):  # fmt: skip
        status, _, err = main(train_cli, ["--manifest", path, "--method", "pso-svr", "--particles", "6", "--iterations", "4",
                                          "--jobs", "2", "-q"], capsys)  # fmt: skip
        assert client.run(lambda: 1)  # the workers were there all along
    assert status == 0, err
    imu = modelfile.load_channels(tmp_path / "imu-1.json")
    assert imu.channels == ("rate_x_dph", "accel_z_g") and all(m.method == "pso-svr" for m in imu.values())
    assert modelfile.load(tmp_path / "models" / "gyro-2.json").method == "pso-svr"


def test_the_imu_guides_three_axis_block_runs_as_written(tmp_path):
    """docs/guides/imu.md's calibration commands, with shorter runs (2 Hz) and a tiny swarm."""
    text = (Path(__file__).resolve().parents[1] / "docs" / "guides" / "imu.md").read_text()
    block = re.search(r"^```shell\n(.*?)^```", text, flags=re.S | re.M).group(1)
    extra = {".venv/bin/fogd-sim": " --rate-hz 2", ".venv/bin/fogd-train": " --particles 4 --iterations 2 -q"}
    lines = []
    for line in block.splitlines():
        command, _, _ = line.partition("  #")
        lines.append(command.rstrip() + next((more for name, more in extra.items() if command.startswith(name)), ""))
    (tmp_path / ".venv").symlink_to(Path(sys.executable).parent.parent)
    done = subprocess.run(["bash", "-c", "set -e\n" + "\n".join(lines)], cwd=tmp_path, capture_output=True, text=True,
                          timeout=600, env={**os.environ, "MPLBACKEND": "Agg"})  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    models = modelfile.load_channels(tmp_path / "imu.json")
    assert models.version == 3 and len(models) == 6
    header = (tmp_path / "imu-compensated.csv").read_text().split("\n", 1)[0].split(",")
    assert sum(name.startswith("flags_") for name in header) == 6 and "rate_x_comp_dph" in header
    assert done.stdout.count("Table 4: imu-test.csv") == 12  # fogd-train's holdout and fogd-replay, each channel


def test_an_alias_bomb_manifest_is_one_line_not_gigabytes(runs, tmp_path, capsys):
    bomb = "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
        f"{chr(98 + i)}: &{chr(98 + i)} [*{chr(97 + i)}, *{chr(97 + i)}, *{chr(97 + i)}, *{chr(97 + i)}]\n" for i in range(20)
    )
    path = manifest(tmp_path, runs, bomb)
    status, _, err = main(train_cli, ["--manifest", path, "--method", "linear", "-q"], capsys)
    assert status != 0 and "aliases (*name) are not allowed in a manifest" in err and len(err.strip().splitlines()) == 1, err
