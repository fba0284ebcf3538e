"""fogd.core.undither and fogd-train's choice of it: the inverse of the dithered staircase against its definition,
streaming equal to batch bit for bit (the estimate alone and through an input bank), a slow ramp recovered
closer than the readings' own average, the model file keeping and checking it, a restart priming it, and
fogd-train taking the sensor's noise where the staircase costs the fit, the readings where it does not."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fogd.calibration.models import FitOptions
from fogd.calibration.training import UNDITHER_NOISE_STEPS, TrainConfig, for_sensor, with_undither
from fogd.core import modelfile
from fogd.core.history import TempHistory
from fogd.core.inputs import InputBank, describe_inputs, inputs_batch, parse_inputs, undithered, undithers
from fogd.core.lag import lag_batch
from fogd.core.runio import Run
from fogd.core.undither import (
    MAX_NOISE_STEPS,
    MIN_NOISE_STEPS,
    TABLE_SIZE,
    Undither,
    expected_reading_steps,
    inverse_table,
    undither_batch,
)
from fogd.errors import ModelFileError, UsageError

RATE_HZ = 10.0
STEP_C = 0.0625  # a DS18B20's


def readings(true_c: np.ndarray, noise_c: float, seed: int, sensor_hz: float = 4.0) -> np.ndarray:
    """A fine sensor's readings of `true_c` (sampled at RATE_HZ): Gaussian noise at each of its own samples,
    then its steps, each reading held until the next."""
    index = np.floor(np.arange(true_c.size) / RATE_HZ * sensor_hz + 1e-9).astype(np.int64)
    noise = np.random.default_rng(seed).normal(0.0, noise_c, index[-1] + 1)[index]
    return np.round((true_c + noise) / STEP_C) * STEP_C


def monte_carlo_expected_steps(x_steps: float, noise_steps: float, draws: int = 400_000) -> float:
    noise = np.random.default_rng(7).normal(0.0, noise_steps, draws)
    return float(np.mean(np.round(x_steps + noise)))


@pytest.mark.parametrize("noise_steps", [0.05, 0.16, 0.5, 1.5])
def test_the_expected_reading_is_the_mean_of_the_noisy_staircase(noise_steps):
    """E(x) against a Monte Carlo mean of round(x + noise), at points across one step."""
    for x in (0.0, 0.2, 0.45, 0.5, 0.55, 0.9):
        expected = expected_reading_steps(np.array([x]), noise_steps)[0]
        assert expected == pytest.approx(monte_carlo_expected_steps(x, noise_steps), abs=4e-3)


@settings(max_examples=60, deadline=None)
@given(noise_steps=st.floats(MIN_NOISE_STEPS, MAX_NOISE_STEPS), x_steps=st.floats(-400.0, 1600.0))
def test_the_inverse_undoes_the_expected_reading(noise_steps, x_steps):
    """invert(E(T)) = T to a small share of a step, anywhere (the table is periodic in the step)."""
    undither = Undither(STEP_C, noise_steps * STEP_C, 2.5, RATE_HZ)
    base = math.floor(x_steps)
    mean_c = (base + expected_reading_steps(np.array([x_steps - base]), noise_steps)[0]) * STEP_C
    # the table's resolution in temperature: its steps in E times the steepest slope of the inverse
    table = np.array(inverse_table(noise_steps))
    tolerance_steps = 2.0 * np.max(np.diff(table)) + 1e-9
    assert abs(undither.invert_one(mean_c) / STEP_C - x_steps) <= tolerance_steps


@settings(max_examples=60, deadline=None)
@given(steps=st.lists(st.integers(-2, 2), min_size=1, max_size=600),
       sizes=st.lists(st.integers(0, 70), max_size=30),
       noise_steps=st.sampled_from([MIN_NOISE_STEPS, 0.16, 0.4, MAX_NOISE_STEPS]))  # fmt: skip
def test_streaming_equals_batch_for_any_chunking_and_one_at_a_time(steps, sizes, noise_steps):
    temps = 20.0 + STEP_C * np.cumsum(steps)
    temps[::7] -= 41.0  # far below zero too: the table's periodicity
    batch = undither_batch(temps, STEP_C, noise_steps * STEP_C, 2.5, RATE_HZ)
    streaming = Undither(STEP_C, noise_steps * STEP_C, 2.5, RATE_HZ)
    parts, start = [], 0
    for size in sizes:
        parts.append(streaming.update(temps[start : start + size]))
        start += size
    parts.append(streaming.update(temps[start:]))
    assert np.array_equal(np.concatenate(parts), batch)
    one = Undither(STEP_C, noise_steps * STEP_C, 2.5, RATE_HZ)
    assert np.array_equal(np.array([one.update_one(value) for value in temps.tolist()]), batch)


@settings(max_examples=30, deadline=None)
@given(steps=st.lists(st.integers(-1, 1), min_size=1, max_size=800), chunk=st.integers(1, 50))
def test_an_undithered_input_bank_streaming_equals_batch(steps, chunk):
    specs = undithered(parse_inputs("temp,lags@10..3000/7,play@2:300,rate@30"), STEP_C, 0.01)
    temps = 15.0 + STEP_C * np.cumsum(steps)
    batch = inputs_batch(temps, specs, RATE_HZ)
    bank = InputBank(specs, RATE_HZ)
    chunks = [bank.update(temps[start : start + chunk]) for start in range(0, temps.size, chunk)]
    assert np.array_equal(np.vstack(chunks), batch)
    bank.reset()
    assert np.array_equal(np.array([bank.update_one(value) for value in temps.tolist()]), batch)
    np.testing.assert_array_equal(batch[:, 0], undither_batch(temps, STEP_C, 0.01, 2.5, RATE_HZ))


def test_a_slow_ramp_is_recovered_closer_than_by_the_readings_average():
    """A 1/16 C sensor with 0.01 C of noise on a 0.5 C/h ramp: the readings' 2.5 s lag keeps the staircase's
    plateaus (errors of a third of a step), the undithered estimate follows the lagged ramp to a fraction of that."""
    t_s = np.arange(0.0, 4 * 3600.0, 1 / RATE_HZ)
    true_c = 20.0 + 0.5 / 3600.0 * t_s
    read_c = readings(true_c, 0.01, seed=3)
    truth = lag_batch(true_c, 2.5, RATE_HZ)
    averaged = np.abs(lag_batch(read_c, 2.5, RATE_HZ) - truth)[100:]
    estimate = np.abs(undither_batch(read_c, STEP_C, 0.01, 2.5, RATE_HZ) - truth)[100:]
    print(f"RMS error: readings' lag {np.sqrt(np.mean(averaged**2)):.4f} C, undithered {np.sqrt(np.mean(estimate**2)):.4f} C")
    assert np.sqrt(np.mean(estimate**2)) < 0.6 * np.sqrt(np.mean(averaged**2))


def test_the_estimate_checks_its_settings():
    for args in [(0.0, 0.01, 2.5, RATE_HZ), (STEP_C, 0.0, 2.5, RATE_HZ), (STEP_C, 0.01, 0.0, RATE_HZ),
                 (STEP_C, 0.01, 2.5, 0.0), (1e-9, 1e-10, 2.5, RATE_HZ), (STEP_C, 10 * STEP_C, 2.5, RATE_HZ)]:  # fmt: skip
        with pytest.raises(ValueError):
            Undither(*args)
    with pytest.raises(ValueError):
        inverse_table(MIN_NOISE_STEPS / 2)
    assert len(inverse_table(0.16)) == TABLE_SIZE + 1


def _document(specs) -> dict:
    d = len(specs)
    return modelfile.document(
        name="m", method="linear", inputs=specs, x_mean=np.zeros(d), x_scale=np.ones(d), y_mean=0.0, y_scale=1.0,
        domain_min=np.full(d, -100.0), domain_max=np.full(d, 100.0), params={"coef": [0.1] * d, "intercept": 0.0},
        reference_dph=0.0, training={}, metrics={}, created_utc="2026-01-01T00:00:00+00:00")  # fmt: skip


def test_the_model_file_keeps_undithered_inputs(tmp_path):
    specs = undithered(parse_inputs("temp,lags@30..3000/5"), STEP_C, 0.01)
    document = _document(specs)
    assert document["version"] == 4  # an older fogd refuses it by the keys it does not know
    assert document["inputs"][1] | {} == {"kind": "temp_lag_c", "tau_s": 30.0, "undither_c": STEP_C,
                                          "undither_noise_c": 0.01, "undither_tau_s": 2.5}  # fmt: skip
    path = tmp_path / "m.json"
    modelfile.save(path, document)
    model = modelfile.load(path)
    assert model.inputs == specs and undithers(model.inputs)
    assert "(undithered 0.0625 C, noise 0.01 C)" in describe_inputs(model.inputs)
    with_play = undithered(parse_inputs("temp,lags@30..3000/5,play@2:300"), STEP_C, 0.01)
    assert _document(with_play)["version"] == 5


@pytest.mark.parametrize(
    "change, message",
    [
        ({"undither_noise_c": 0.01, "undither_tau_s": 2.5}, "needs all of"),
        ({"undither_c": STEP_C, "undither_noise_c": 0.5, "undither_tau_s": 2.5}, "noise must be"),
        ({"undither_c": STEP_C, "undither_noise_c": 0.01, "undither_tau_s": 1e9}, "lag must be"),
        ({"undither_c": 1e-300, "undither_noise_c": 1e-301, "undither_tau_s": 2.5}, "resolution must be"),
        ({"undither_c": STEP_C, "undither_noise_c": -0.01, "undither_tau_s": 2.5}, "positive"),
        ({"undither_c": "0.0625", "undither_noise_c": 0.01, "undither_tau_s": 2.5}, "finite number"),
        ({"undither_c": STEP_C, "undither_noise_c": 0.01, "undither_tau_s": 2.5, "dequantise_c": 1.0}, "no dequantise_c"),
    ],
)
def test_the_model_file_refuses_a_bad_undither(tmp_path, change, message):
    document = _document(parse_inputs("temp,lag@300"))
    document["version"] = 4
    document["inputs"][1].update(change)
    path = tmp_path / "m.json"
    path.write_text(json.dumps(document))
    with pytest.raises(ModelFileError, match=message):
        modelfile.load(path)


def test_a_version_2_file_with_undither_keys_is_refused(tmp_path):
    document = _document(parse_inputs("temp,lag@300"))
    document["inputs"][1].update(undither_c=STEP_C, undither_noise_c=0.01, undither_tau_s=2.5)
    document["version"] = 2
    path = tmp_path / "m.json"
    path.write_text(json.dumps(document))
    with pytest.raises(ModelFileError, match="unknown key"):
        modelfile.load(path)


def test_a_restart_primes_the_undithered_inputs_as_the_whole_run_left_them():
    """A soak, a ramp and ten minutes of soak read by a fine sensor; the history's 1 s block means alone (the
    state file) and the next reading: the primed bank's row is the batch row of the whole run to a hundredth of a
    step, where a cold start is off by most of the ramp."""
    t_s = np.arange(0.0, 6000.0, 1 / RATE_HZ)
    true_c = 20.0 + np.clip(t_s - 1800.0, 0.0, 3600.0) * 2.0 / 3600.0
    read_c = readings(true_c, 0.01, seed=5)
    specs = undithered(parse_inputs("temp,lags@10..3000/7,play@2:300"), STEP_C, 0.01)
    expected = inputs_batch(read_c, specs, RATE_HZ)[-1]
    full = TempHistory(RATE_HZ)
    full.extend(t_s[:-1].tolist(), read_c[:-1].tolist())
    restored = TempHistory(RATE_HZ)
    restored.restore(full.points(), full.samples)
    restored.bridge(t_s[-1], read_c[-1])
    bank = InputBank(specs, RATE_HZ)
    restored.prime(bank)
    row = np.array(bank.update_one(read_c[-1]))
    np.testing.assert_allclose(row, expected, rtol=0, atol=0.01 * STEP_C)
    cold = np.array(InputBank(specs, RATE_HZ).update_one(read_c[-1]))
    assert np.abs(cold[1:8] - expected[1:8]).max() > 0.5


PROGRAMMES = (  # (time s, setpoint C) knots of three chamber runs
    ((0, 10), (3600, 10), (18000, 40), (24000, 40)),
    ((0, 40), (3600, 40), (14400, 5), (21600, 5)),
    ((0, 15), (2400, 15), (8000, 35), (10000, 35), (16000, 15), (21600, 15)),
)


def chamber_runs(noise_c: float, seed: int, rate_hz: float = 2.0) -> list[Run]:
    """Three runs whose error follows the true temperature's 300 s lag and its gradient, read by a fine sensor
    with `noise_c` of noise (0: a bare staircase)."""
    rng = np.random.default_rng(seed)
    out = []
    for index, knots in enumerate(PROGRAMMES):
        t_s = np.arange(0.0, knots[-1][0], 1 / rate_hz)
        true_c = lag_batch(np.interp(t_s, *zip(*knots)), 600.0, rate_hz)  # a housing's temperature: smooth
        coil_c = lag_batch(true_c, 300.0, rate_hz)
        error_dph = 0.003 * coil_c + 0.4 * (true_c - coil_c) + rng.normal(0.0, 0.002, t_s.size)
        index_s = np.floor(t_s * 4.0 + 1e-9).astype(np.int64)  # a 4 Hz sensor, held
        noise = rng.normal(0.0, noise_c, index_s[-1] + 1)[index_s] if noise_c else 0.0
        read_c = np.round((true_c + noise) / STEP_C) * STEP_C
        out.append(Run(f"run{index}.csv", t_s, error_dph, read_c, rate_hz, f"{seed}-{index}"))
    return out


def config(**changes) -> TrainConfig:
    return TrainConfig(inputs=parse_inputs("temp,lags@10..3000/7,play@2"), fit=FitOptions(progress=False), **changes)


def test_fogd_train_takes_the_sensors_noise_where_the_staircase_costs_the_fit():
    """0.16 steps of noise: the candidate chosen is within one of the truth (the candidates are a factor 1.6
    apart), the config names it, and a second call keeps it."""
    runs = chamber_runs(0.16 * STEP_C, seed=1)
    chosen = with_undither(runs, config(), STEP_C)
    assert undithers(chosen.inputs) and chosen.inputs == undithered(config().inputs, STEP_C, chosen.sensor_noise_c)
    assert 0.1 * STEP_C <= chosen.sensor_noise_c <= 0.28 * STEP_C
    assert with_undither(runs, chosen, STEP_C) is chosen
    assert for_sensor(runs, chosen).inputs == chosen.inputs


def test_fogd_train_keeps_the_readings_where_undithering_cannot_help():
    """A bare staircase (no noise to read) and a sensor whose noise spans many of its steps keep the readings,
    and the config says so (0), so a second call chooses nothing; the paper's inputs are never undithered."""
    bare = with_undither(chamber_runs(0.0, seed=2), config(), STEP_C)
    assert not undithers(bare.inputs) and bare.sensor_noise_c == 0.0
    noisy = with_undither(chamber_runs(5 * STEP_C, seed=2), config(), STEP_C)
    assert not undithers(noisy.inputs) and noisy.sensor_noise_c == 0.0
    paper = TrainConfig(inputs=parse_inputs("temp,rate@50"), fit=FitOptions(progress=False))
    assert not undithers(with_undither(chamber_runs(0.16 * STEP_C, seed=2), paper, STEP_C).inputs)


def test_a_given_noise_is_taken_and_checked():
    runs = chamber_runs(0.16 * STEP_C, seed=3)
    given = with_undither(runs, config(sensor_noise_c=0.012), STEP_C)
    assert given.inputs == undithered(config().inputs, STEP_C, 0.012)
    assert with_undither(runs, config(sensor_noise_c=0.0), STEP_C).inputs == config().inputs
    with pytest.raises(UsageError, match="--sensor-noise-c"):
        with_undither(runs, config(sensor_noise_c=1.0), STEP_C)
    assert UNDITHER_NOISE_STEPS[0] == max(UNDITHER_NOISE_STEPS)  # the gentlest first: the tie goes to it
