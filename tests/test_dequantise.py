"""The dequantised temperature of a coarse sensor, at either pace: streaming = batch bit for bit, inside the
reading's band, the ramp itself on a steady ramp, the quadratic pace closer on a cycle; the resolution seen in
calibration runs; fogd-train's default uses it (quadratic) for a whole-degree sensor and not for a fine one,
and the model file keeps it, its pace, and reads files from before the pace as linear. The offline estimate
that training fits (forwards and backwards in time): symmetric in time, inside the band, closer than the
causal one where a ramp speeds up, and used for the fitted blocks only."""

import dataclasses
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fogd.calibration.features import training_set
from fogd.calibration.training import TrainConfig, for_sensor
from fogd.core import modelfile
from fogd.core.dequantise import (COARSE_RESOLUTION_C, PACES, Dequantiser, dequantise_batch, detect_resolution_c,
                                   smoothed_batch)
from fogd.core.errorstats import block_means
from fogd.core.inputs import (DEFAULT_INPUTS_TEXT, InputBank, dequantised, describe_inputs, inputs_batch,
                               parse_inputs, with_play_lag_s)
from fogd.core.runio import Run
from fogd.errors import ModelFileError, UsageError

RATE_HZ = 10.0


def _staircase(steps: list[int], hold: list[int], resolution_c: float = 1.0) -> np.ndarray:
    """Readings that change by a step or stay, each reading held for some samples (a 1 Hz sensor at 10 Hz)."""
    levels = 20.0 + resolution_c * np.cumsum(steps)
    return np.repeat(levels, [1 + h for h in hold[: len(levels)]] + [1] * max(0, len(levels) - len(hold)))


@pytest.mark.parametrize("pace", PACES)
@settings(max_examples=100, deadline=None)
@given(steps=st.lists(st.integers(-1, 1), min_size=1, max_size=400),
       hold=st.lists(st.integers(0, 30), max_size=400), sizes=st.lists(st.integers(0, 60), max_size=40))  # fmt: skip
def test_streaming_equals_batch_for_any_chunking_and_one_at_a_time(pace, steps, hold, sizes):
    temps = _staircase(steps, hold)
    batch = dequantise_batch(temps, 1.0, RATE_HZ, pace)
    streaming, parts, start = Dequantiser(1.0, RATE_HZ, pace), [], 0
    for size in [*sizes, temps.size]:
        parts.append(streaming.update(temps[start : start + size]))
        start += size
        if start >= temps.size:
            break
    assert np.array_equal(np.concatenate(parts), batch)
    one = Dequantiser(1.0, RATE_HZ, pace)
    assert [one.update_one(value) for value in temps.tolist()] == batch.tolist()
    one.reset()
    assert [one.update_one(value) for value in temps.tolist()] == batch.tolist()


@pytest.mark.parametrize("pace", PACES)
@settings(max_examples=100, deadline=None)
@given(steps=st.lists(st.integers(-2, 2), min_size=1, max_size=400), hold=st.lists(st.integers(0, 30), max_size=400),
       resolution_c=st.sampled_from([0.0625, 0.5, 1.0]))  # fmt: skip
def test_estimate_never_leaves_the_readings_band(pace, steps, hold, resolution_c):
    temps = _staircase(steps, hold, resolution_c)
    estimate = dequantise_batch(temps, resolution_c, RATE_HZ, pace)
    assert np.all(np.abs(estimate - temps) <= resolution_c / 2 + 1e-9)


@pytest.mark.parametrize("pace", PACES)
def test_a_steady_ramp_is_recovered_from_its_whole_degrees(pace):
    """From the second crossing on, a quantised steady ramp gives back the ramp (to one sample of travel; the
    parabola reads the crossings' one-second timing jitter as a little acceleration), where the readings
    themselves are off by up to half a degree."""
    t_s = np.arange(0, 3600, 1 / RATE_HZ)
    true_c = 10.3 + 0.01 * t_s
    readings = np.round(10.3 + 0.01 * np.floor(t_s))  # a 1 Hz sensor, held
    estimate = dequantise_batch(readings, 1.0, RATE_HZ, pace)
    second_crossing = int(np.flatnonzero(np.diff(readings))[1]) + 1
    after = slice(second_crossing, None)
    assert np.max(np.abs(estimate[after] - true_c[after])) < {"linear": 0.02, "quadratic": 0.05}[pace]
    assert np.max(np.abs(readings[after] - true_c[after])) > 0.45


@pytest.mark.parametrize("pace", PACES)
def test_an_overdue_crossing_relaxes_to_the_middle_of_the_band(pace):
    """A ramp that stops: the estimate does not run on to the band's edge but comes back towards its middle."""
    readings = np.concatenate([np.repeat([20.0, 21.0, 22.0], 600), np.full(36000, 23.0)])
    estimate = dequantise_batch(readings, 1.0, RATE_HZ, pace)
    assert estimate[1800 + 550] == pytest.approx(22.5 + 550 / 600, abs=1e-9)  # still on the ramp's slope
    assert 23.0 <= estimate[-1] < 23.01  # an hour later: the middle of the band


def test_the_quadratic_pace_follows_a_cycle_closer():
    """A slow sine (3 C, 1 h period) read in whole degrees at 1 Hz: the parabola through the last three
    crossings slows down into each turn, where the pace between the last two runs on past it."""
    t_s = np.arange(0, 4 * 3600, 1 / RATE_HZ)
    true_c = 20.3 + 3.0 * np.sin(2 * np.pi * t_s / 3600)
    readings = np.round(20.3 + 3.0 * np.sin(2 * np.pi * np.floor(t_s) / 3600))
    after = t_s >= 600
    rms = {pace: np.sqrt(np.mean((dequantise_batch(readings, 1.0, RATE_HZ, pace) - true_c)[after] ** 2))
           for pace in PACES}  # fmt: skip
    assert rms["quadratic"] < 0.85 * rms["linear"], rms
    assert rms["linear"] < np.sqrt(np.mean((readings - true_c)[after] ** 2)), rms


@pytest.mark.parametrize("pace", PACES)
@settings(max_examples=100, deadline=None)
@given(steps=st.lists(st.integers(-2, 2), min_size=1, max_size=300), hold=st.lists(st.integers(0, 30), max_size=300),
       resolution_c=st.sampled_from([0.5, 1.0]))  # fmt: skip
def test_the_smoothed_estimate_is_symmetric_in_time_and_inside_the_band(pace, steps, hold, resolution_c):
    temps = _staircase(steps, hold, resolution_c)
    smoothed = smoothed_batch(temps, resolution_c, RATE_HZ, pace)
    assert np.array_equal(smoothed_batch(temps[::-1], resolution_c, RATE_HZ, pace)[::-1], smoothed)
    assert np.all(np.abs(smoothed - temps) <= resolution_c / 2 + 1e-9)


@pytest.mark.parametrize("pace, share", [("linear", 0.85), ("quadratic", 0.6)])
def test_the_smoothed_estimate_is_closer_on_a_ramp_that_speeds_up(pace, share):
    """A soak, then a ramp from rest speeding up (a parabola), in whole degrees at 1 Hz: the causal estimate
    lags it (no pace before the second crossing, then the pace of crossings already past); forwards and
    backwards, the lag and the lead partly cancel (the backward estimate has its own blind start at the end)."""
    t_s = np.arange(0, 3 * 3600, 1 / RATE_HZ)
    true_c = 20.2 + 0.5 * np.clip(t_s - 1800, 0, None) ** 2 / 3600**2 * 12  # 12 C/h after the first hour
    readings = np.round(20.2 + 0.5 * np.clip(np.floor(t_s) - 1800, 0, None) ** 2 / 3600**2 * 12)
    ramp = t_s > 1800
    causal = dequantise_batch(readings, 1.0, RATE_HZ, pace)[ramp] - true_c[ramp]
    smoothed = smoothed_batch(readings, 1.0, RATE_HZ, pace)[ramp] - true_c[ramp]
    assert np.mean(causal) < -0.03
    assert np.sqrt(np.mean(smoothed**2)) < share * np.sqrt(np.mean(causal**2))


def test_training_fits_the_smoothed_estimate_and_keeps_the_served_domain():
    """With `smoothed`, the fitted blocks of a dequantised bank are block means of the inputs of the offline
    estimate; the calibrated domain (what the daemon clamps to) stays that of the causal inputs; inputs of the
    readings (a fine sensor) are the same either way."""
    t_s = np.arange(0, 2 * 3600, 1 / RATE_HZ)
    readings = np.round(20.3 + 4.0 * np.sin(2 * np.pi * np.floor(t_s) / 3600))
    run = _run(readings)
    specs = dequantised(parse_inputs("temp,lags@30..3000/3"), 1.0)
    causal, smoothed = (training_set([run], specs, 100.0, smoothed=flag) for flag in (False, True))
    fitted_rows = inputs_batch(readings, specs, RATE_HZ, smoothed=True)
    expected, _ = block_means(fitted_rows, np.ones(readings.size, dtype=bool), 1000)
    assert np.array_equal(smoothed.x, expected)
    assert not np.allclose(smoothed.x, causal.x, atol=1e-3, rtol=0)
    assert np.array_equal(smoothed.domain_min, causal.domain_min)
    assert np.array_equal(smoothed.domain_max, causal.domain_max)
    assert np.array_equal(smoothed.x_samples, causal.x_samples)
    plain = parse_inputs("temp,lags@30..3000/3")
    assert np.array_equal(training_set([run], plain, 100.0, smoothed=True).x, training_set([run], plain, 100.0).x)


def test_detect_resolution():
    fine = 20.0 + 0.0625 * np.cumsum(np.random.default_rng(1).integers(-1, 2, 5000))
    whole = np.round(fine)
    assert detect_resolution_c([fine]) == pytest.approx(0.0625)
    assert detect_resolution_c([whole, whole + 3.0]) == pytest.approx(1.0)
    assert detect_resolution_c([np.full(100, 25.0)]) == 0.0
    assert detect_resolution_c([20.0 + np.linspace(0, 10, 1000)]) < 0.02  # an unquantised sensor


def _run(temp_c: np.ndarray) -> Run:
    t_s = np.arange(temp_c.size) / RATE_HZ
    return Run("r.csv", t_s, np.zeros(temp_c.size), temp_c, RATE_HZ, "0", {})


def test_the_default_dequantises_a_whole_degree_sensor_only():
    ramp = 10.0 + 0.005 * np.arange(36000) / RATE_HZ
    # the default's inputs with the play's lag given (for_sensor would choose it: tests/test_play_lag_choice.py)
    config = TrainConfig(inputs=with_play_lag_s(parse_inputs(DEFAULT_INPUTS_TEXT), 300.0))
    coarse = for_sensor([_run(np.round(ramp))], config)
    assert all(spec.dequantise_c == 1.0 and spec.dequantise_pace == "quadratic" for spec in coarse.inputs)
    assert describe_inputs(coarse.inputs).endswith(" (dequantised 1 C)")
    assert coarse.inputs == dequantised(config.inputs, 1.0)  # the default, dequantised
    chosen = parse_inputs("temp,lag@300,play@2")  # inputs asked for are kept, dequantised
    assert for_sensor([_run(np.round(ramp))], TrainConfig(inputs=chosen)).inputs == dequantised(chosen, 1.0)
    assert for_sensor([_run(np.round(ramp * 16) / 16)], config).inputs == config.inputs
    assert for_sensor([_run(np.round(ramp))], dataclasses.replace(config, sensor_resolution_c=0.0)).inputs == config.inputs
    forced = for_sensor([_run(ramp)], TrainConfig(sensor_resolution_c=COARSE_RESOLUTION_C))
    assert all(spec.dequantise_c == COARSE_RESOLUTION_C for spec in forced.inputs)
    assert for_sensor([_run(np.round(ramp))], coarse) is coarse  # already decided: kept
    assert for_sensor([_run(np.round(ramp / 20) * 20)], config).inputs == config.inputs  # 20 C jumps: no sensor
    with pytest.raises(UsageError, match="at most 10 C"):
        for_sensor([_run(ramp)], TrainConfig(sensor_resolution_c=20.0))


@settings(max_examples=30, deadline=None)
@given(steps=st.lists(st.integers(-1, 1), min_size=1, max_size=300), hold=st.lists(st.integers(0, 30), max_size=300),
       chunk=st.integers(1, 40))  # fmt: skip
def test_dequantised_input_bank_streaming_equals_batch(steps, hold, chunk):
    """The daemon's chunks (and one sample at a time) give replay's floats with a dequantised bank, which
    mixes inputs of the readings and of the estimate."""
    specs = (dequantised(parse_inputs("temp,lags@30..3000/5,rate@50"), 1.0) + parse_inputs("lag@100")
             + dequantised(parse_inputs("lag@60"), 1.0, "linear"))  # fmt: skip
    temps = _staircase(steps, hold)
    batch = inputs_batch(temps, specs, RATE_HZ)
    bank = InputBank(specs, RATE_HZ)
    streamed = np.concatenate([bank.update(temps[i : i + chunk]) for i in range(0, temps.size, chunk)])
    assert np.array_equal(streamed, batch)
    bank.reset()
    assert np.array_equal(np.array([bank.update_one(value) for value in temps.tolist()]), batch)
    np.testing.assert_array_equal(batch[:, 0], dequantise_batch(temps, 1.0, RATE_HZ, "quadratic"))
    linear = InputBank(parse_inputs("lag@60"), RATE_HZ).update(dequantise_batch(temps, 1.0, RATE_HZ, "linear"))
    np.testing.assert_array_equal(batch[:, -1], linear[:, 0])


def _linear_doc(specs, version):
    d = len(specs)
    return {
        "format": "fogd-model", "version": version, "name": "m", "method": "linear",
        "inputs": [spec.to_dict() for spec in specs],
        "input_scaling": {"mean": [0.0] * d, "scale": [1.0] * d},
        "output_scaling": {"mean": 0.0, "scale": 1.0},
        "domain": {"min": [-100.0] * d, "max": [100.0] * d},
        "params": {"coef": [0.1] * d, "intercept": 0.0},
        "reference_dph": 0.0, "training": {}, "metrics": {}, "created_utc": "2026-01-01T00:00:00+00:00",
        "fogd_version": "0",
    }  # fmt: skip


def test_model_file_keeps_the_dequantised_inputs_as_version_4(tmp_path):
    specs = dequantised(parse_inputs("temp,lags@30..3000/5"), 1.0)
    document = modelfile.document(
        name="m", method="linear", inputs=specs, x_mean=np.zeros(6), x_scale=np.ones(6), y_mean=0.0, y_scale=1.0,
        domain_min=np.full(6, -100.0), domain_max=np.full(6, 100.0), params={"coef": [0.1] * 6, "intercept": 0.0},
        reference_dph=0.0, training={}, metrics={}, created_utc="2026-01-01T00:00:00+00:00")  # fmt: skip
    assert document["version"] == 4
    assert all(item["dequantise_pace"] == "quadratic" for item in document["inputs"])
    path = tmp_path / "m.json"
    modelfile.save(path, document)
    assert modelfile.load(path).inputs == specs
    plain_specs = parse_inputs("temp,lags@30..3000/5")
    plain = modelfile.document(**{**_document_args(document), "inputs": plain_specs})
    assert plain["version"] == 2  # files without a dequantised input still read with older fogd
    imu = tmp_path / "imu.json"  # an IMU's file (version 3) holds a dequantised channel's model as it is
    modelfile.save(imu, modelfile.channels_document(name="imu", documents={"rate_x_dph": document, "rate_z_dph": plain},
                                                    created_utc="2026-01-01T00:00:00+00:00"))  # fmt: skip
    models = modelfile.load_channels(imu)
    assert models.version == 3 and models["rate_x_dph"].inputs == specs and models["rate_z_dph"].inputs == plain_specs


def _document_args(document):
    return dict(name="m", method="linear", inputs=(), x_mean=np.zeros(6), x_scale=np.ones(6), y_mean=0.0,
                y_scale=1.0, domain_min=np.full(6, -100.0), domain_max=np.full(6, 100.0),
                params=document["params"], reference_dph=0.0, training={}, metrics={}, created_utc="x")  # fmt: skip


def test_a_version_4_file_from_before_the_pace_is_served_at_the_linear_pace(tmp_path):
    """Files written before `dequantise_pace` existed were trained on the linear pace, and are served with it."""
    doc = _linear_doc(parse_inputs("temp,lag@300"), 4)
    for item in doc["inputs"]:
        item["dequantise_c"] = 1.0
    path = tmp_path / "m.json"
    path.write_text(json.dumps(doc))
    model = modelfile.load(path)
    assert model.inputs == dequantised(parse_inputs("temp,lag@300"), 1.0, "linear")
    assert all(spec.dequantise_pace is None for spec in model.inputs)
    temps = _staircase([1, 1, 1, 1, 0, 0, -1], [300, 200, 150, 300, 400, 0, 100])
    served = InputBank(model.inputs, RATE_HZ).update(temps)
    np.testing.assert_array_equal(served[:, 0], dequantise_batch(temps, 1.0, RATE_HZ, "linear"))
    assert not np.array_equal(served[:, 0], dequantise_batch(temps, 1.0, RATE_HZ, "quadratic"))


@pytest.mark.parametrize(
    "version, value, message",
    [(2, 1.0, "unknown key"), (4, 0.0, "positive"), (4, 50.0, "above 10 C"), (4, "1", "finite number")],
)
def test_model_file_rejects_bad_or_early_dequantised_inputs(tmp_path, version, value, message):
    doc = _linear_doc(parse_inputs("temp,lag@300"), version)
    doc["inputs"][1]["dequantise_c"] = value
    path = tmp_path / "m.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(ModelFileError, match=message):
        modelfile.load(path)


@pytest.mark.parametrize("pace", ["linear", "cubic", 2])
def test_model_file_rejects_a_bad_or_unneeded_pace(tmp_path, pace):
    doc = _linear_doc(parse_inputs("temp,lag@300"), 4)
    doc["inputs"][1].update(dequantise_c=1.0, dequantise_pace=pace)  # "linear" is written as no key at all
    path = tmp_path / "m.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(ModelFileError, match="dequantise_pace"):
        modelfile.load(path)


def test_dequantising_a_whole_degree_sensor_lowers_held_out_drift():
    """A lag bank (the coarse sensor's default until 2026-11-26) on simulated whole-degree calibration runs, with and without
    the dequantised temperature, replayed on held-out runs: dequantised, the drift left is lower on every one."""
    from fogd.calibration.models import FitOptions
    from fogd.calibration.replay import replay, replay_table
    from fogd.calibration.training import train
    from fogd.simulation.profiles import builtin
    from fogd.simulation.simulator import params_for, simulate

    params = params_for("navigation", "lumped", sensor_resolution_c=1.0, sensor_rate_hz=1.0)

    def run(profile: str, seed: int) -> Run:
        sim = simulate(builtin(profile), 2.0, seed, params)
        return Run(f"{profile}.csv", sim.t_s, sim.rate_dph, sim.temp_c, 2.0, str(seed),
                   {"true_error_dph": sim.true_error_dph})  # fmt: skip

    calibration = [run(name, 11 + i) for i, name in enumerate(("paper-train", "cooling", "cycle"))]
    held_out = [run(name, 21 + i) for i, name in enumerate(("paper-test", "cool-40-to-0", "soak-after-ramp"))]
    options = FitOptions(particles=6, iterations=5, progress=False)
    drift = {}
    for resolution_c in (0.0, None):
        trained = train(calibration, TrainConfig(inputs=parse_inputs("temp,lags@30..3000/5"), fit=options,
                                                 sensor_resolution_c=resolution_c))  # fmt: skip
        assert all((spec.dequantise_c is None) == (resolution_c == 0.0) for spec in trained.model.inputs)
        drift[resolution_c] = [replay_table(r, replay(trained.model, r), 100.0).after.rmse_dph for r in held_out]
    assert all(dequantised < readings for dequantised, readings in zip(drift[None], drift[0.0])), drift
