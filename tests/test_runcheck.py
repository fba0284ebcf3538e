"""A run that cannot calibrate is refused in one line: too short, too little temperature span, isothermal."""

from __future__ import annotations

import numpy as np
import pytest

from fogd.calibration.runcheck import MIN_SPAN_C, check_calibration_run
from fogd.core.runio import Run
from fogd.errors import InputError

RATE_HZ = 10.0
WARMUP_S, BLOCK_S = 50.0, 100.0
NEEDS = "a calibration run must move the gyro's temperature over the range it will see in use"


def make_run(temp_c: np.ndarray) -> Run:
    t_s = np.arange(temp_c.size) / RATE_HZ
    rate = np.random.default_rng(0).normal(0.0, 0.01, temp_c.size)
    return Run("runs/chamber.csv", t_s, rate, np.asarray(temp_c, dtype=np.float64), RATE_HZ, "0" * 64)


def ramp(start_c: float, end_c: float, seconds: float = 3600.0) -> np.ndarray:
    return np.linspace(start_c, end_c, int(seconds * RATE_HZ))


def refusal(run: Run) -> str:
    with pytest.raises(InputError) as caught:
        check_calibration_run(run, WARMUP_S, BLOCK_S)
    message = str(caught.value)
    assert "\n" not in message and message.startswith("runs/chamber.csv: ")
    assert caught.value.exit_status == 65
    return message


def test_a_heating_and_cooling_run_passes():
    assert MIN_SPAN_C == 5.0
    assert check_calibration_run(make_run(np.r_[ramp(-10.0, 40.0), ramp(40.0, 0.0)]), WARMUP_S, BLOCK_S) is None
    assert check_calibration_run(make_run(ramp(20.0, 25.0)), WARMUP_S, BLOCK_S) is None  # exactly 5 C


def test_a_small_span_is_refused_with_what_a_calibration_run_needs():
    message = refusal(make_run(ramp(20.0, 22.3)))
    assert message == (
        "runs/chamber.csv: temperature span 2.3 C is under 5 C: a calibration run must move the gyro's "
        "temperature over the range it will see in use (heat, cool, soak at a few temperatures)"
    )
    assert "span 4.99 C is under 5 C" in refusal(make_run(ramp(20.0, 24.99)))
    assert "span 4.99999 C is under 5 C" in refusal(make_run(ramp(20.0, 24.99999)))  # not '5 C is under 5 C'


def test_an_isothermal_run_is_refused():
    message = refusal(make_run(np.full(36_000, 25.0)))
    assert "isothermal" in message and "span 0 C" in message and NEEDS in message


def test_invalid_temperatures_do_not_count_towards_the_span():
    temp = ramp(20.0, 23.0)
    temp[100:200] = np.nan
    temp[5000] = 300.0  # out of the valid range: a corrupt reading, not a hot chamber
    temp[6000] = -150.0
    assert "temperature span 3 C is under 5 C" in refusal(make_run(temp))
    assert "no valid temperature" in refusal(make_run(np.full(36_000, np.nan)))


def test_a_run_shorter_than_warmup_and_one_block_is_refused():
    needed = int((WARMUP_S + BLOCK_S) * RATE_HZ)
    assert check_calibration_run(make_run(np.linspace(0.0, 30.0, needed)), WARMUP_S, BLOCK_S) is None
    message = refusal(make_run(np.linspace(0.0, 30.0, needed - 1)))
    assert "149.9 s of data (1499 rows at 10 Hz) is too short" in message
    assert "the estimator warm-up (50 s) and one 100 s block need 150 s" in message
    assert NEEDS in message
