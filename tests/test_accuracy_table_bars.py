"""tools/accuracy_table.py's judgement against issue 33's bars: which floor, which bar, which runs miss."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tools"))
import accuracy_table  # noqa: E402


@pytest.mark.parametrize("text, seeds", [("1-5", [1, 2, 3, 4, 5]), ("3", [3]), ("1-3,9", [1, 2, 3, 9]), ("2,2,1", [2, 1])])
def test_seeds_are_ranges_and_lists(text: str, seeds: list[int]) -> None:
    assert accuracy_table.seed_list(text) == seeds


@pytest.mark.parametrize("text", ["x", "1-", "1-b", "", "5-1"])
def test_bad_seeds_are_a_usage_error(text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError):
        accuracy_table.seed_list(text)


def test_whole_degrees_are_judged_over_the_corrected_floor_and_fine_over_the_noise_floor() -> None:
    args = argparse.Namespace(calibration=None)
    scores = [3.0, 2.0, 5.0, 2.2, 4.0]
    rows = {accuracy_table.LADDER: [(score, 0.0) for score in scores], "_ladder_choice": ["chose lag bank"]}
    whole = accuracy_table.judge(args, rows, False, [2.0, 2.0, 2.9, 2.0, 2.3])
    assert whole.bar == 1.6 and whole.choice == "chose lag bank"
    assert whole.ratios == pytest.approx([1.5, 1.0, 5.0 / 2.9, 1.1, 4.0 / 2.3])
    assert whole.missed == ["fast-ramp", "fast-cycle"]
    fine = accuracy_table.judge(args, rows, True, None)
    assert fine.ratios == scores and fine.bar == 1.5  # three calibration runs: 1.5x the noise floor
    assert accuracy_table.judge(args, rows, False, None) is None  # whole degrees need their corrected floor


def test_the_five_run_programme_has_the_stricter_fine_bar() -> None:
    five = argparse.Namespace(calibration=[accuracy_table.as_profile(name) for name in reversed(accuracy_table.FIVE_RUN)])
    assert accuracy_table.fine_bar(five) == 1.3
    assert accuracy_table.fine_bar(argparse.Namespace(calibration=None)) == 1.5


def test_seeds_do_not_go_with_the_imu_tables(capsys, monkeypatch) -> None:
    monkeypatch.setattr(sys, "argv", ["accuracy_table.py", "--imu", "--seeds", "1-2", "--quick"])
    with pytest.raises(SystemExit) as raised:
        accuracy_table.main()
    assert raised.value.code == 2 and "--seeds judges the single-axis gyro" in capsys.readouterr().err


def test_each_run_is_also_judged_against_no_compensation() -> None:
    """Issue 33: no default worse than no compensation on any held-out run; the drift over the same run's
    uncompensated drift, run by run (the floors cancel: both are over the run's noise floor)."""
    args = argparse.Namespace(calibration=None)
    rows = {accuracy_table.LADDER: [(score, 0.0) for score in [3.0, 2.0, 5.0, 2.2, 4.0]],
            "Before compensation": [(before, 0.0) for before in [30.0, 1.0, 50.0, 22.0, 8.0]]}  # fmt: skip
    judged = accuracy_table.judge(args, rows, True, None)
    assert judged.against_none == pytest.approx([0.1, 2.0, 0.1, 0.1, 0.5])
