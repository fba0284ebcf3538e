"""Model inputs: multi-scale input sets streaming = batch bit for bit, the --inputs syntax, the model file."""

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fogd import modelfile
from fogd.errors import ModelFileError
from fogd.estimator import EstimatorSettings
from fogd.inputs import TEMP, TEMP_LAG, TEMP_RATE, InputBank, InputSpec, describe_inputs, inputs_batch, parse_inputs

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


@pytest.mark.parametrize(
    "text, message",
    [
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
