"""Chamber profiles: setpoint semantics, built-ins, and YAML loading with its errors."""

from pathlib import Path

import numpy as np
import pytest

from fogd.errors import InputError, UsageError
from fogd.simulation import profiles
from fogd.simulation.profiles import Profile


def test_ramp_has_the_slope_of_its_segment_and_soaks_are_constant():
    profile = Profile("t", ((100.0, 10.0), (200.0, 30.0), (50.0, 30.0)))
    t_s = np.linspace(100.0, 300.0, 41)
    assert np.allclose(np.diff(profile.setpoint_c(t_s)) / np.diff(t_s), 20.0 / 200.0)
    assert np.all(profile.setpoint_c(np.linspace(0.0, 100.0, 11)) == 10.0)
    assert np.all(profile.setpoint_c(np.linspace(300.0, 350.0, 11)) == 30.0)
    assert profile.duration_s == 350.0
    assert profile.start_c == 10.0


def test_setpoint_holds_outside_the_run_and_a_zero_duration_segment_is_a_step():
    profile = Profile("t", ((10.0, 0.0), (0.0, 20.0), (10.0, 20.0)))
    assert profile.setpoint_c(np.array([-5.0, 9.99, 10.0, 15.0, 99.0])).tolist() == [0.0, 0.0, 20.0, 20.0, 20.0]


def test_builtins_are_listed_and_paper_train_spans_the_papers_range():
    assert {"paper-train", "paper-test", "cooling", "cycle"} <= set(profiles.names())
    train = profiles.builtin("paper-train")
    setpoint_c = train.setpoint_c(np.linspace(0.0, train.duration_s, 1000))
    assert setpoint_c.min() == -15.0 and setpoint_c.max() == 50.0
    assert np.all(np.diff(setpoint_c) >= 0)
    assert 2 * 3600 <= train.duration_s <= 6 * 3600
    cooling = profiles.builtin("cooling")
    assert np.all(np.diff(cooling.setpoint_c(np.linspace(0.0, cooling.duration_s, 100))) <= 0)


def test_unknown_builtin_is_a_usage_error_listing_the_names():
    with pytest.raises(UsageError) as caught:
        profiles.builtin("paper-trian")
    assert "paper-train" in str(caught.value) and "cycle" in str(caught.value)


def test_yaml_profile_loads(tmp_path: Path):
    path = tmp_path / "chamber.yaml"
    path.write_text("# soak, ramp, soak\n- [600, -5]\n- [1200, 25.5]\n- [300, 25.5]\n")
    profile = profiles.load(path)
    assert profile.segments == ((600.0, -5.0), (1200.0, 25.5), (300.0, 25.5))
    assert profile.setpoint_c(1200.0) == pytest.approx(-5.0 + 30.5 * 600.0 / 1200.0)
    assert profiles.resolve(str(path)).segments == profile.segments


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("duration: 5\n", "expected a YAML list"),
        ("[]\n", "no segments"),
        ("- [600, 20]\n- [300]\n", "entry 2"),
        ("- [600, 20]\n- [abc, 20]\n", "entry 2"),
        ("- [600, 20]\n- [true, 20]\n", "entry 2"),
        ("- [600, 20]\n- [-60, 30]\n", "negative"),
        ("- [600, 20]\n- [60, 300]\n", "outside -60..125"),
        ("- [600, 20]\n- [60, -80]\n", "outside -60..125"),
        ("- [0, 20]\n", "total duration"),
        ("- [600, 20\n- [60, 30]\n", "chamber.yaml:"),
    ],
)
def test_bad_yaml_profiles_name_the_file_and_the_problem(tmp_path: Path, text: str, expected: str):
    path = tmp_path / "chamber.yaml"
    path.write_text(text)
    with pytest.raises(InputError) as caught:
        profiles.load(path)
    assert str(path) in str(caught.value)
    assert expected in str(caught.value)


def test_missing_profile_file_is_an_input_error(tmp_path: Path):
    with pytest.raises(InputError, match="nothere.yaml"):
        profiles.resolve(str(tmp_path / "nothere.yaml"))


def test_profile_built_in_code_rejects_bad_segments():
    with pytest.raises(ValueError, match="entry 1"):
        Profile("t", ((float("nan"), 20.0),))


@pytest.mark.parametrize(
    ("name", "times_s", "expected_c"),
    [
        ("cool-40-to-0", [0.0, 3600.0, 7200.0, 10_800.0, 14_400.0], [40.0, 40.0, 20.0, 0.0, 0.0]),
        ("fast-cycle", [0.0, 1800.0, 2700.0, 3600.0, 5400.0, 9000.0], [10.0, 10.0, 25.0, 40.0, 10.0, 10.0]),
    ],
)
def test_held_out_builtins_have_their_soaks_and_ramps(name, times_s, expected_c):
    profile = profiles.builtin(name)
    assert profile.duration_s == times_s[-1]
    assert profile.setpoint_c(np.array(times_s)).tolist() == expected_c
    assert name in profiles.names() and profiles.summary(name)


def _fastest_pace_cph(profile: Profile) -> float:
    """The profile's fastest setpoint ramp, C/h."""
    previous_c, fastest = profile.start_c, 0.0
    for duration_s, target_c in profile.segments:
        if duration_s > 0:
            fastest = max(fastest, abs(target_c - previous_c) / duration_s * 3600.0)
        previous_c = target_c
    return fastest


@pytest.mark.parametrize("name, pace_cph, soaks_s", [("cal-soaks", 20.0, 1800.0 + 3 * 5400.0), ("cal-fast-cycle", 60.0, 3 * 1800.0)])
def test_the_guides_extra_calibration_runs_keep_the_held_out_fast_ramp_the_fastest(name, pace_cph, soaks_s):
    """The KVH guide's programme (docs/guides/kvh-chamber.md) adds these two; the accuracy table's fast-ramp must
    stay faster than any."""
    profile = profiles.builtin(name)
    assert _fastest_pace_cph(profile) == pytest.approx(pace_cph)
    assert _fastest_pace_cph(profile) < _fastest_pace_cph(profiles.builtin("fast-ramp")) == pytest.approx(80.0)
    previous_c, soaked_s = profile.start_c, 0.0
    for duration_s, target_c in profile.segments:
        soaked_s += duration_s if target_c == previous_c else 0.0
        previous_c = target_c
    assert soaked_s == pytest.approx(soaks_s)
    assert profiles.summary(name).startswith(("0 C", "-10 C"))
