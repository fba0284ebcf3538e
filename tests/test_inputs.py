"""Model inputs: multi-scale input sets streaming = batch bit for bit, the --inputs syntax, the model file."""

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fogd.core import modelfile
from fogd.core.estimator import EstimatorSettings
from fogd.core.inputs import (
    TEMP,
    TEMP_LAG,
    TEMP_RATE,
    InputBank,
    InputSpec,
    describe_inputs,
    inputs_batch,
    parse_inputs,
)
from fogd.errors import ModelFileError

RATE_HZ = 10.0
MULTI = (
    InputSpec(TEMP),
    InputSpec(TEMP_RATE, EstimatorSettings(5.0, 0.5)),
    InputSpec(TEMP_RATE, EstimatorSettings(30.0, 0.5)),
    InputSpec(TEMP_LAG, tau_s=60.0),
    InputSpec(TEMP_LAG, tau_s=7.5),
)


@settings(max_examples=100, deadline=None)
@given(
    steps=st.lists(st.integers(-3, 3), min_size=1, max_size=800),
    sizes=st.lists(st.integers(0, 50), max_size=40),
)
def test_multi_scale_inputs_streaming_equal_batch_bit_for_bit(steps, sizes):
    temps = 20.0 + 0.0625 * np.cumsum(steps)  # a quantised sensor
    bank, parts, start = InputBank(MULTI, RATE_HZ), [], 0
    for size in [*sizes, temps.size]:
        parts.append(bank.update(temps[start : start + size]))
        start += size
        if start >= temps.size:
            break
    assert np.array_equal(np.concatenate(parts), inputs_batch(temps, MULTI, RATE_HZ))
    assert bank.warmup == 299  # the longest window; lags have no warm-up


def test_parse_inputs_syntax():
    specs = parse_inputs("temp, rate@50,rate@300,lag@600", average_s=0.5, step_s=0.0)
    assert specs == (
        InputSpec(TEMP),
        InputSpec(TEMP_RATE, EstimatorSettings(50.0, 0.5, 0.0)),
        InputSpec(TEMP_RATE, EstimatorSettings(300.0, 0.5, 0.0)),
        InputSpec(TEMP_LAG, tau_s=600.0),
    )
    assert describe_inputs(specs) == "temp,rate@50,rate@300,lag@600"
    assert [spec.label for spec in specs] == ["temp_c", "temp_rate_cps@50s", "temp_rate_cps@300s", "temp_lag_c@600s"]


def test_lag_bank_is_its_lags_one_by_one():
    listed = parse_inputs("lags@300,1000,3000,rate@50")
    assert listed == (*(InputSpec(TEMP_LAG, tau_s=tau) for tau in (300.0, 1000.0, 3000.0)),
                      InputSpec(TEMP_RATE, EstimatorSettings(50.0, 0.5, 0.0)))  # fmt: skip
    assert listed[:3] == parse_inputs("lag@300,lag@1000,lag@3000")
    assert describe_inputs(listed) == "lags@300,1000,3000,rate@50"


def test_lag_bank_range_is_log_spaced_and_round_trips():
    specs = parse_inputs("temp,lags@30..10000/6")
    taus = [spec.tau_s for spec in specs[1:]]
    assert taus[0] == 30.0 and taus[-1] == 10000.0 and len(taus) == 6
    ratios = np.diff(np.log(taus))
    np.testing.assert_allclose(ratios, ratios.mean(), rtol=1e-2)  # equal steps in log (to 3 digits)
    assert parse_inputs(describe_inputs(specs)) == specs


@settings(max_examples=30, deadline=None)
@given(steps=st.lists(st.integers(-1, 1), min_size=1, max_size=3000), chunk=st.integers(1, 40))
def test_whole_degree_lag_bank_streaming_equals_batch(steps, chunk):
    """A KVH's whole-degree temperature through the default bank: the daemon's chunks give replay's floats."""
    specs = parse_inputs("lags@30..10000/6")
    temps = 20.0 + np.cumsum(steps).astype(float)
    bank = InputBank(specs, RATE_HZ)
    streamed = np.concatenate([bank.update(temps[i : i + chunk]) for i in range(0, temps.size, chunk)])
    assert np.array_equal(streamed, inputs_batch(temps, specs, RATE_HZ))


@pytest.mark.parametrize(
    "text, message",
    [
        ("lags@10..5/3", "FIRST..LAST/COUNT"),
        ("lags@1..50", "FIRST..LAST/COUNT"),
        ("lags@300,300", "twice"),
        ("temp,300", "expected temp"),
        ("lags@1..10000/20", "1 to 16 inputs"),
        ("lags@1..100000/4", "86400"),
        ("temp,rate", "rate@SECONDS"),
        ("temp,speed@3", "expected temp"),
        ("temp,lag@-5", "time constant"),
        ("temp,lag@abc", "could not convert"),
        ("temp,rate@0.6", "window"),
        ("temp,temp", "twice"),
        ("", "expected temp"),
    ],
)
def test_parse_inputs_rejects_with_the_item(text, message):
    with pytest.raises(ValueError, match=message):
        parse_inputs(text)


def test_inputspec_checks_its_fields():
    with pytest.raises(ValueError):
        InputSpec(TEMP_LAG)
    with pytest.raises(ValueError):
        InputSpec(TEMP, tau_s=5.0)
    with pytest.raises(ValueError):
        InputSpec(TEMP_LAG, tau_s=0.0)


def _linear_doc(specs):
    d = len(specs)
    return {
        "format": "fogd-model", "version": 1, "name": "m", "method": "linear",
        "inputs": [spec.to_dict() for spec in specs],
        "input_scaling": {"mean": [0.0] * d, "scale": [1.0] * d},
        "output_scaling": {"mean": 0.0, "scale": 1.0},
        "domain": {"min": [-100.0] * d, "max": [100.0] * d},
        "params": {"coef": [0.1] * d, "intercept": 0.0},
        "reference_dph": 0.0, "training": {}, "metrics": {}, "created_utc": "2026-01-01T00:00:00+00:00",
        "fogd_version": "0",
    }  # fmt: skip


def test_model_file_round_trips_multi_scale_inputs(tmp_path):
    path = tmp_path / "m.json"
    modelfile.save(path, _linear_doc(MULTI))
    assert modelfile.load(path).inputs == MULTI


@pytest.mark.parametrize(
    "bad, message",
    [
        ({"kind": "temp_lag_c"}, "lacks tau_s"),
        ({"kind": "temp_lag_c", "tau_s": 0}, "tau_s"),
        ({"kind": "temp_lag_c", "tau_s": 1e9}, "tau_s"),
        ({"kind": "temp_lag_c", "tau_s": "5"}, "finite number"),
        ({"kind": "temp_lag_c", "tau_s": 5, "window_s": 3}, "unknown key"),
        ({"kind": "temp_gradient"}, "kind is one of"),
    ],
)
def test_model_file_rejects_bad_lag_inputs(tmp_path, bad, message):
    doc = _linear_doc(MULTI[:2])
    doc["inputs"][1] = bad
    path = tmp_path / "m.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(ModelFileError, match=message):
        modelfile.load(path)


def test_model_file_rejects_duplicate_inputs(tmp_path):
    doc = _linear_doc((MULTI[3], MULTI[3]))
    path = tmp_path / "m.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(ModelFileError, match="twice"):
        modelfile.load(path)


@settings(max_examples=60, deadline=None)
@given(steps=st.lists(st.integers(-3, 3), min_size=1, max_size=400),
       text=st.sampled_from(["temp,lags@10..3000/7,play@2", "lags@5..50/3", "rate@5,lag@60,lag@7.5,temp",
                             "lag@20,temp,lag@60"]))  # fmt: skip
def test_a_row_at_a_time_equals_the_batch_bit_for_bit_whatever_the_order_of_lags(steps, text):
    """update_one (the daemon's row path: a run of lags in one call, the rest one by one) gives the rows
    inputs_batch gives, in the specs' order."""
    specs = parse_inputs(text)
    temps = 20.0 + 0.0625 * np.cumsum(steps)
    bank = InputBank(specs, RATE_HZ)
    rows = np.array([bank.update_one(temp) for temp in temps.tolist()])
    assert np.array_equal(rows, inputs_batch(temps, specs, RATE_HZ))
    assert bank.count == temps.size
