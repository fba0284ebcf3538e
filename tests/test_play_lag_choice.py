"""fogd.calibration.training.with_play_lag: fogd-train's default play@2:auto takes the lag whose play the runs'
error follows, the reading's own when it follows that; inputs that do not ask are left alone."""

from __future__ import annotations

import numpy as np
import pytest

from fogd.calibration.models import FitOptions
from fogd.calibration.training import (PLAY_LAG_TOLERANCE, PLAY_LAGS_S, TrainConfig, shortest_within_tolerance, turns,
                                      with_play_lag)
from fogd.core.inputs import parse_inputs
from fogd.core.lag import lag_batch
from fogd.core.play import play_batch
from fogd.core.runio import Run

PROGRAMMES = (  # (time s, setpoint C) knots of three chamber runs at 1 Hz
    ((0, 10), (3600, 10), (18000, 40), (24000, 40)),
    ((0, 40), (3600, 40), (14400, 5), (21600, 5)),
    ((0, 15), (2400, 15), (8000, 35), (10000, 35), (16000, 15), (21600, 15)),
)


def runs_whose_hysteresis_follows(lag_s: float, seed: int) -> list[Run]:
    rng = np.random.default_rng(seed)
    out = []
    for index, knots in enumerate(PROGRAMMES):
        t_s = np.arange(0.0, knots[-1][0] + 1.0)
        temp_c = np.interp(t_s, *zip(*knots))
        coil_c = lag_batch(temp_c, lag_s, 1.0) if lag_s else temp_c
        error_dph = 0.002 * temp_c + 0.01 * play_batch(coil_c, 2.0) + rng.normal(0.0, 0.002, t_s.size)
        out.append(Run(f"run{index}.csv", t_s, error_dph, temp_c, 1.0, f"{seed}-{index}"))
    return out


@pytest.mark.parametrize("lag_s", [0.0, 1000.0, 2500.0])
def test_the_play_takes_the_lag_the_error_follows(lag_s):
    config = TrainConfig(inputs=parse_inputs("temp,lags@10..3000/7,play@2:auto"), fit=FitOptions(progress=False))
    chosen = with_play_lag(runs_whose_hysteresis_follows(lag_s, 1), config)
    (play,) = [spec for spec in chosen.inputs if spec.width_c is not None]
    assert lag_s in PLAY_LAGS_S and not play.play_lag_auto
    assert play.play_lag_s == (lag_s or None)
    assert chosen.inputs[:-1] == config.inputs[:-1]  # the rest as asked


def test_inputs_that_do_not_ask_are_left_alone():
    config = TrainConfig(inputs=parse_inputs("temp,lags@10..3000/7,play@2"), fit=FitOptions(progress=False))
    assert with_play_lag(runs_whose_hysteresis_follows(1000.0, 2), config) is config


def test_the_shortest_lag_within_the_tolerance_of_the_least_residual_is_taken():
    """A lag the blocks can hardly tell from a shorter one is noise: the shorter wins unless the longer leaves
    more than PLAY_LAG_TOLERANCE less residual."""
    assert PLAY_LAG_TOLERANCE == pytest.approx(0.01)
    assert shortest_within_tolerance([(0.865, "0"), (0.864, "100 s"), (0.864, "300 s")]) == "0"
    assert shortest_within_tolerance([(0.887, "0"), (0.876, "1000 s"), (0.865, "2500 s")]) == "2500 s"
    assert shortest_within_tolerance([(0.900, "0"), (0.880, "100 s"), (0.875, "300 s")]) == "100 s"


def test_runs_that_never_turn_keep_the_readings_play():
    """A heating run and a cooling run: each holds its play's level in its own offset, so no lag can be told
    from them (a lagged play would only fit one more slow transient); the reading's play is kept."""
    runs = runs_whose_hysteresis_follows(2500.0, 3)[:2]
    assert not turns(runs, 2.0) and turns(runs_whose_hysteresis_follows(2500.0, 3), 2.0)
    config = TrainConfig(inputs=parse_inputs("temp,lags@10..3000/7,play@2:auto"), fit=FitOptions(progress=False))
    (play,) = [spec for spec in with_play_lag(runs, config).inputs if spec.width_c is not None]
    assert play.play_lag_s is None and not play.play_lag_auto
