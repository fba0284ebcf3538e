"""`fogd-sim`: the CSV it writes, its options, and one-line errors for an operator's mistakes."""

import io
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fogd.cli.sim import main
from fogd.core.runio import read_run
from fogd.simulation import profiles
from fogd.simulation.simulator import NOISE_PRESETS, params_for, simulate

SHORT_YAML = "- [120, 20]\n- [600, 26]\n- [120, 26]\n"
COMMAND = [sys.executable, "-c", "import sys; from fogd.cli.sim import main; sys.exit(main())"]


@pytest.fixture
def short_profile(tmp_path: Path) -> Path:
    path = tmp_path / "short.yaml"
    path.write_text(SHORT_YAML)
    return path


def test_writes_a_run_that_read_run_reads_back(tmp_path: Path, short_profile: Path, capsys):
    out = tmp_path / "run.csv"
    assert main(["--profile", str(short_profile), "-o", str(out), "--rate-hz", "20", "--seed", "3"]) == 0
    run = read_run(out)
    assert run.rate_hz == pytest.approx(20.0)
    assert list(run.extra) == ["true_error_dph"]
    expected = simulate(profiles.load(short_profile), 20.0, 3)
    assert run.rows == expected.t_s.size
    assert np.allclose(run.rate_dph, expected.rate_dph, atol=1e-6)
    assert np.array_equal(run.temp_c, expected.temp_c)
    assert np.allclose(run.extra["true_error_dph"], expected.true_error_dph, atol=1e-7)
    comments = [line for line in out.read_text().splitlines() if line.startswith("#")]
    assert any("short" in line for line in comments) and any("seed 3" in line for line in comments)
    assert "Traceback" not in capsys.readouterr().err


def test_same_seed_same_file_other_seed_other_file(tmp_path: Path, short_profile: Path):
    files = []
    for index, seed in enumerate(("5", "5", "6")):
        files.append(tmp_path / f"run{index}.csv")
        assert main(["--profile", str(short_profile), "-o", str(files[-1]), "--rate-hz", "10", "--seed", seed]) == 0
    assert files[0].read_bytes() == files[1].read_bytes()
    assert files[0].read_bytes() != files[2].read_bytes()


def test_dash_writes_csv_to_stdout(short_profile: Path, capsys):
    assert main(["--profile", str(short_profile), "-o", "-", "--rate-hz", "5", "--no-noise"]) == 0
    text = capsys.readouterr().out
    lines = [line for line in text.splitlines() if not line.startswith("#")]
    assert lines[0] == "t_s,rate_dph,temp_c,true_error_dph"
    table = np.loadtxt(io.StringIO("\n".join(lines[1:])), delimiter=",")
    assert table.shape == (840 * 5 + 1, 4)
    earth_dph = 15.041 * math.sin(math.radians(30.5))
    assert np.allclose(table[:, 1] - table[:, 3], earth_dph, atol=2e-6)


def test_sensor_options_reach_the_temperature_column(tmp_path: Path, short_profile: Path):
    out = tmp_path / "run.csv"
    args = ["--profile", str(short_profile), "-o", str(out), "--rate-hz", "10"]
    assert main(args + ["--sensor-resolution-c", "1", "--sensor-rate-hz", "1"]) == 0
    run = read_run(out)
    assert np.array_equal(run.temp_c, np.round(run.temp_c))
    held = run.temp_c[:-1].reshape(-1, 10)  # 10 rows = one 1 Hz sensor period
    assert np.all(held == held[:, :1])
    data_line = out.read_text().splitlines()[-1]
    assert "." not in data_line.split(",")[2]


def test_noise_options_change_the_white_noise(tmp_path: Path, short_profile: Path):
    stds = []
    for arw in ("0.002", "0.02"):
        out = tmp_path / f"arw{arw}.csv"
        assert main(["--profile", str(short_profile), "-o", str(out), "--rate-hz", "100", "--arw-dpsh", arw]) == 0
        run = read_run(out)
        stds.append(np.std(np.diff(run.rate_dph - run.extra["true_error_dph"])) / math.sqrt(2))
    assert stds[1] / stds[0] == pytest.approx(10.0, rel=0.1)


def test_builtin_profile_by_name(tmp_path: Path):
    out = tmp_path / "run.csv"
    assert main(["--profile", "fast-ramp", "-o", str(out), "--rate-hz", "1"]) == 0
    run = read_run(out)
    assert run.t_s[-1] == profiles.builtin("fast-ramp").duration_s


def test_list_profiles(capsys):
    assert main(["--list-profiles"]) == 0
    assert capsys.readouterr().out.split() == profiles.names()


@pytest.mark.parametrize(
    ("args", "status", "expected"),
    [
        (["--profile", "paper-trian", "-o", "x.csv"], 2, "paper-train"),
        (["--profile", "cycle", "-o", "x.csv", "--rate-hz", "0"], 2, "--rate-hz"),
        (["--profile", "cycle", "-o", "x.csv", "--rate-hz", "6000"], 2, "at least 1 and at most 5000"),
        (["--profile", "cycle", "-o", "x.csv", "--rate-hz", "fast"], 2, "not a number"),
        (["--profile", "cycle", "-o", "x.csv", "--seed", "-1"], 2, "--seed"),
        (["--profile", "cycle", "-o", "x.csv", "--sensor-resolution-c", "0"], 2, "--sensor-resolution-c"),
        (["--profile", "cycle"], 2, "-o"),
        (["--profile", "cycle", "-o", "x.csv", "--speed"], 2, "--speed"),
        (["--profile", "missing.yaml", "-o", "x.csv"], 66, "missing.yaml"),
        (["--profile", "BAD", "-o", "x.csv"], 65, "entry 2"),
        (["--profile", "cycle", "-o", "x.csv", "--noise", "strategic"], 2, "--noise"),
        (["--profile", "cycle", "-o", "x.csv", "--thermal", "layered"], 2, "--thermal"),
        (["--profile", "cycle", "-o", "x.csv", "--thermal", "diffusive", "--coil-nodes", "1"], 2, "2..50"),
        (["--profile", "cycle", "-o", "x.csv", "--thermal", "diffusive", "--coil-nodes", "51"], 2, "2..50"),
        (["--profile", "cycle", "-o", "x.csv", "--thermal", "diffusive", "--coil-nodes", "3.5"], 2, "whole number"),
        (["--profile", "cycle", "-o", "x.csv", "--coil-nodes", "4"], 2, "--thermal diffusive only"),
        (["--profile", "cycle", "-o", "x.csv", "--housing-tau-s", "0"], 2, "--housing-tau-s"),
        (["--profile", "cycle", "-o", "x.csv", "--sensor-tau-s", "-5"], 2, "--sensor-tau-s"),
        (["--profile", "cycle", "-o", "x.csv", "--sensor-tau-s", "nan"], 2, "--sensor-tau-s"),
        (["--profile", "cycle", "-o", "x.csv", "--turn-on-bias-dph", "-0.1"], 2, "--turn-on-bias-dph"),
        (["--profile", "cycle", "-o", "x.csv", "--sensor-on", "roof"], 2, "--sensor-on"),
        (["--profile", "cycle", "-o", "x.csv", "--baseplate-tau-s", "100"], 2, "--sensor-on baseplate only"),
    ],
)
def test_bad_options_give_one_line_and_a_status(tmp_path: Path, capsys, args, status, expected):
    bad = tmp_path / "bad.yaml"
    bad.write_text("- [60, 20]\n- [-5, 30]\n")
    args = [str(bad) if arg == "BAD" else str(tmp_path / arg) if arg.endswith((".csv", ".yaml")) else arg
            for arg in args]
    assert main(args) == status
    captured = capsys.readouterr()
    err_lines = captured.err.splitlines()
    assert len(err_lines) == 1 and err_lines[0].startswith("fogd-sim: ")
    assert expected in err_lines[0]
    assert captured.out == ""
    assert not (tmp_path / "x.csv").exists()


def test_command_process_has_no_traceback_and_a_helpful_help():
    bad = subprocess.run(COMMAND + ["--profile", "nope", "-o", "-"], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2
    assert bad.stderr.count("\n") == 1 and "Traceback" not in bad.stderr
    helped = subprocess.run(COMMAND + ["--help"], capture_output=True, text=True, timeout=60)
    assert helped.returncode == 0
    for text in ("--rate-hz", "(default: 200)", "deg/sqrt(h)", "paper-train", "[duration_s, target_c]",
                 "--noise", "navigation", "--thermal", "diffusive", "--coil-nodes", "(default: 6)",
                 "--housing-tau-s", "(default: 1500)", "--sensor-tau-s", "(default: 20)", "--turn-on-bias-dph",
                 "(default: 0.02)", "cool-40-to-0", "fast-cycle"):
        assert text in " ".join(helped.stdout.split()), text


def _sim(tmp_path: Path, profile: Path, *options: str) -> Path:
    out = tmp_path / f"run{len(list(tmp_path.glob('run*.csv')))}.csv"
    assert main(["--profile", str(profile), "-o", str(out), "--rate-hz", "10", "--seed", "4", *options]) == 0
    return out


def test_no_noise_grade_is_the_tactical_grade_and_the_old_default(tmp_path: Path, short_profile: Path):
    plain, tactical = _sim(tmp_path, short_profile), _sim(tmp_path, short_profile, "--noise", "tactical")
    assert plain.read_bytes() == tactical.read_bytes()
    expected = simulate(profiles.load(short_profile), 10.0, 4)
    assert np.allclose(read_run(plain).rate_dph, expected.rate_dph, atol=1e-6)


@pytest.mark.parametrize(
    ("options", "arw_dpsh"),
    [
        (["--noise", "navigation"], NOISE_PRESETS["navigation"]["arw_dpsh"]),
        (["--noise", "navigation", "--arw-dpsh", "0.01"], 0.01),  # an explicit value overrides the grade
        (["--arw-dpsh", "0.01", "--noise", "navigation"], 0.01),
    ],
)
def test_noise_grade_sets_the_white_noise_unless_overridden(tmp_path: Path, short_profile: Path, options, arw_dpsh):
    out = tmp_path / "run.csv"
    assert main(["--profile", str(short_profile), "-o", str(out), "--rate-hz", "100", *options]) == 0
    run = read_run(out)
    white_dph = np.std(np.diff(run.rate_dph - run.extra["true_error_dph"])) / math.sqrt(2)
    assert white_dph == pytest.approx(60.0 * arw_dpsh * math.sqrt(100.0), rel=0.1)
    assert f"ARW {arw_dpsh:g} deg/sqrt(h)" in out.read_text()


def test_structure_and_sensor_options_reach_the_simulation(tmp_path: Path, short_profile: Path):
    options = ["--noise", "navigation", "--bias-instability-dph", "0.002", "--thermal", "diffusive",
               "--coil-nodes", "4", "--housing-tau-s", "900", "--sensor-on", "baseplate", "--baseplate-tau-s", "200",
               "--sensor-tau-s", "60", "--turn-on-bias-dph", "0.5"]
    out = _sim(tmp_path, short_profile, *options)
    params = params_for("navigation", "diffusive", bias_instability_dph=0.002, coil_nodes=4, housing_tau_s=900.0,
                        sensor_on="baseplate", baseplate_tau_s=200.0, sensor_tau_s=60.0, turn_on_bias_dph=0.5)
    expected = simulate(profiles.load(short_profile), 10.0, 4, params)
    run = read_run(out)
    assert np.array_equal(run.temp_c, expected.temp_c)
    assert np.allclose(run.extra["true_error_dph"], expected.true_error_dph, atol=1e-7)
    assert np.allclose(run.rate_dph, expected.rate_dph, atol=1e-6)
    assert abs(expected.turn_on_bias_dph) > 0.02  # drawn with the given std, not the default 0.02
    text = out.read_text()
    assert "diffusive coil, 4 layers" in text and "sensor: baseplate temperature, lag 60 s" in text
    assert "housing lag 900 s" in text and "baseplate lag 200 s" in text


def test_a_zero_turn_on_bias_leaves_only_the_earth_rate(tmp_path: Path, short_profile: Path):
    out = _sim(tmp_path, short_profile, "--turn-on-bias-dph", "0", "--arw-dpsh", "0", "--bias-instability-dph", "0")
    run = read_run(out)
    earth_dph = 15.041 * math.sin(math.radians(30.5))
    assert np.allclose(run.rate_dph - run.extra["true_error_dph"], earth_dph, atol=2e-6)
