"""tools/accuracy_table.py --calibration: another calibration programme, built-in or YAML, checked before any work."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pytest

from fogd.simulation.simulator import params_for

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tools"))
import accuracy_table  # noqa: E402


def test_without_the_option_the_three_built_in_runs_calibrate() -> None:
    profiles = accuracy_table.calibration_profiles(argparse.Namespace(calibration=None))
    assert [profile.name for profile in profiles] == list(accuracy_table.CALIBRATION)


def test_built_in_names_and_yaml_files_are_taken_in_order(tmp_path: Path) -> None:
    path = tmp_path / "steps.yaml"
    path.write_text("- [600, 10]\n- [1800, 30]\n- [600, 30]\n", encoding="utf-8")
    profiles = accuracy_table.calibration_profiles(argparse.Namespace(calibration=["fast-cycle", str(path)]))
    assert [profile.name for profile in profiles] == ["fast-cycle", "steps"]
    run = accuracy_table.simulated_run(profiles[1], 1, 1.0, params_for("navigation", "lumped"))
    assert run.name == "steps.csv"
    assert run.t_s[-1] == pytest.approx(3000.0)
    # the file's programme is the one simulated: it starts at 10 C and heats (the housing lags the 30 C setpoint)
    assert np.mean(run.temp_c[:300]) == pytest.approx(10.0, abs=0.5)
    assert np.mean(run.temp_c[-300:]) > 18.0


@pytest.mark.parametrize("spec, message", [("nosuch", "unknown profile 'nosuch'"), ("bad.yaml", "is not a finite number")])
def test_a_bad_programme_is_a_usage_error_before_any_work(spec: str, message: str, tmp_path: Path, capsys,
                                                          monkeypatch) -> None:  # fmt: skip
    (tmp_path / "bad.yaml").write_text("- [600, 0]\n- [x, 1]\n", encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "argv", ["accuracy_table.py", "--calibration", spec, "--quick"])
    with pytest.raises(SystemExit) as raised:
        accuracy_table.main()
    assert raised.value.code == 2 and message in capsys.readouterr().err
