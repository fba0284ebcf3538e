"""Model files: hand-built documents for every method evaluate their formula; anything else is one ModelFileError."""

from __future__ import annotations

import copy
import gzip
import json
import os
import pickle
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fogd.core import modelfile
from fogd.core.estimator import EstimatorSettings
from fogd.core.frozen import FrozenModel
from fogd.core.inputs import TEMP, TEMP_RATE, default_inputs
from fogd.errors import ModelFileError

X_MEAN = np.array([20.0, 0.001])
X_SCALE = np.array([10.0, 0.01])
Y_MEAN, Y_SCALE = 0.3, 2.0
DOMAIN_MIN = np.array([-10.0, -0.05])
DOMAIN_MAX = np.array([50.0, 0.05])
PARAMS: dict[str, dict[str, Any]] = {
    "linear": {"coef": [0.5, -1.5], "intercept": 0.1},
    "ls-poly": {
        "powers": [[1, 0], [0, 1], [2, 0], [1, 1], [0, 3]],
        "coef": [0.5, -1.2, 0.3, 0.7, -0.05],
        "intercept": 0.2,
    },
    "rbf-nn": {
        "centres": [[0.0, 0.0], [1.0, -1.0], [-0.5, 0.5]],
        "width": 0.8,
        "coef": [1.0, -0.5, 0.25],
        "intercept": -0.1,
    },
    "pso-svr": {
        "support_vectors": [[0.1, 0.2], [-1.0, 0.5], [0.7, -0.3], [1.5, 1.5]],
        "dual_coef": [0.9, -0.4, 0.3, -1.0],
        "gamma": 0.6,
        "trend_coef": [0.25, -0.5],
        "intercept": 0.05,
    },
}
METHODS = tuple(PARAMS)


def make_doc(method: str) -> dict[str, Any]:
    return modelfile.document(
        name=f"test-{method}",
        method=method,
        inputs=default_inputs(EstimatorSettings(window_s=20.0, average_s=1.0, step_s=0.0)),
        x_mean=X_MEAN,
        x_scale=X_SCALE,
        y_mean=Y_MEAN,
        y_scale=Y_SCALE,
        domain_min=DOMAIN_MIN,
        domain_max=DOMAIN_MAX,
        params=copy.deepcopy(PARAMS[method]),
        reference_dph=0.5,
        training={"runs": ["a.csv", "b.csv"], "rate_hz": 10.0},
        metrics={"rmse_dph": 0.01},
        created_utc="2024-01-01T00:00:00Z",
    )


def expected(method: str, x: np.ndarray) -> np.ndarray:
    """The method's formula, written out here term by term (not with fogd's evaluators)."""
    xs = (np.asarray(x, dtype=np.float64) - X_MEAN) / X_SCALE
    p = PARAMS[method]
    out = np.empty(len(xs))
    for r, row in enumerate(xs):
        if method == "linear":
            g = p["coef"][0] * row[0] + p["coef"][1] * row[1]
        elif method == "ls-poly":
            g = sum(c * row[0] ** a * row[1] ** b for c, (a, b) in zip(p["coef"], p["powers"]))
        elif method == "rbf-nn":
            g = sum(
                c * np.exp(-np.sum((row - np.array(centre)) ** 2) / (2 * p["width"] ** 2))
                for c, centre in zip(p["coef"], p["centres"])
            )
        else:
            g = sum(
                a * np.exp(-p["gamma"] * np.sum((row - np.array(sv)) ** 2))
                for a, sv in zip(p["dual_coef"], p["support_vectors"])
            ) + sum(t * value for t, value in zip(p["trend_coef"], row))
        out[r] = Y_MEAN + Y_SCALE * (g + p["intercept"])
    return out


def inside_points(n: int = 25, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return DOMAIN_MIN + (DOMAIN_MAX - DOMAIN_MIN) * rng.random((n, 2))


def write_json(tmp_path: Path, doc: Any, name: str = "model.json") -> Path:
    path = tmp_path / name
    path.write_text(json.dumps(doc, indent=1), encoding="utf-8")
    return path


def rejected(path: Path) -> str:
    """load's ModelFileError message, checked to be one line naming the file."""
    with pytest.raises(ModelFileError) as caught:
        modelfile.load(path)
    message = str(caught.value)
    assert "\n" not in message and "\r" not in message, message
    assert str(path) in message, message
    return message.replace(str(path), "<file>")  # tmp_path holds the test's name: keep it out of word checks


# --- valid documents ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("method", METHODS)
def test_save_load_predicts_the_formula(tmp_path, method):
    path = tmp_path / f"{method}.json"
    modelfile.save(path, make_doc(method))
    model = modelfile.load(path)

    assert isinstance(model, FrozenModel)
    assert model.method == method and model.name == f"test-{method}"
    assert [spec.kind for spec in model.inputs] == [TEMP, TEMP_RATE]
    assert model.inputs[1].estimator == EstimatorSettings(window_s=20.0, average_s=1.0, step_s=0.0)
    assert model.meta["training"]["runs"] == ["a.csv", "b.csv"]
    assert model.meta["created_utc"] == "2024-01-01T00:00:00Z"

    x = np.vstack([inside_points(), X_MEAN, DOMAIN_MIN, DOMAIN_MAX])
    y, clamped = model.predict(x)
    np.testing.assert_allclose(y, expected(method, x), rtol=1e-12, atol=1e-12)
    assert not clamped.any()
    assert y.shape == clamped.shape == (len(x),)


@pytest.mark.parametrize("method", METHODS)
def test_one_row_and_many_rows_agree(tmp_path, method):
    path = tmp_path / "m.json"
    modelfile.save(path, make_doc(method))
    model = modelfile.load(path)
    x = inside_points(5000, seed=2)  # more rows than one evaluation chunk
    y, _ = model.predict(x)
    for index in (0, 4095, 4096, 4999):
        one, _ = model.predict(x[index])
        assert one[0] == y[index]
    np.testing.assert_allclose(y[:50], expected(method, x[:50]), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("method", METHODS)
def test_inputs_outside_domain_are_clamped_and_flagged(tmp_path, method):
    path = tmp_path / "m.json"
    modelfile.save(path, make_doc(method))
    model = modelfile.load(path)
    outside = np.array([[80.0, 0.0], [-40.0, 0.01], [20.0, 0.3], [20.0, -1.0], [100.0, 100.0]])
    inside = np.array([[20.0, 0.0], [50.0, 0.05], [-10.0, -0.05]])
    y, clamped = model.predict(np.vstack([outside, inside]))
    assert clamped.tolist() == [True] * 5 + [False] * 3
    by_hand = np.minimum(np.maximum(outside, DOMAIN_MIN), DOMAIN_MAX)
    np.testing.assert_allclose(y[:5], expected(method, by_hand), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(y[5:], expected(method, inside), rtol=1e-12, atol=1e-12)
    assert model.predict_unclamped(outside[:1])[0] == pytest.approx(expected(method, outside[:1])[0], rel=1e-12)


def test_saved_file_is_plain_json(tmp_path):
    path = tmp_path / "m.json"
    modelfile.save(path, make_doc("pso-svr"))
    parsed = json.loads(path.read_text(encoding="utf-8"))
    assert parsed["format"] == "fogd-model" and parsed["version"] == 2
    assert parsed["params"] == PARAMS["pso-svr"]
    rate_input = {"kind": "temp_rate_cps", "window_s": 20.0, "average_s": 1.0, "step_s": 0.0}
    assert parsed["inputs"] == [{"kind": "temp_c"}, rate_input]


def test_version_1_files_still_load_and_give_the_same_compensation():
    """A version-1 file (what fogd wrote before the polynomial trend) loads and evaluates as before."""
    doc = make_doc("pso-svr")
    old = json.loads(json.dumps(doc))
    old["version"] = 1
    x = np.array([[20.0, 0.001], [5.0, -0.002]])
    np.testing.assert_array_equal(modelfile.from_document(old).predict(x)[0], modelfile.from_document(doc).predict(x)[0])


def test_polynomial_trend_is_version_2_and_checked():
    doc = make_doc("pso-svr")
    doc["params"]["trend_powers"] = [[1, 0], [0, 1], [2, 0], [3, 0]]
    doc["params"]["trend_coef"] = [0.1, -0.2, 0.03, -0.004]
    model = modelfile.from_document(doc)
    x = np.array([[20.0, 0.001]])
    xs = (x - model.x_mean) / model.x_scale
    trend = xs[0, 0] * 0.1 - 0.2 * xs[0, 1] + 0.03 * xs[0, 0] ** 2 - 0.004 * xs[0, 0] ** 3
    without = json.loads(json.dumps(doc))
    del without["params"]["trend_powers"]
    without["params"]["trend_coef"] = [0.0, 0.0]
    kernel = modelfile.from_document(without).predict(x)[0][0]
    assert model.predict(x)[0][0] == pytest.approx(kernel + model.y_scale * trend, rel=1e-12)
    doc["params"]["trend_coef"] = [0.1, -0.2]  # one coefficient per monomial
    with pytest.raises(ModelFileError, match="trend_coef"):
        modelfile.from_document(doc)
    doc["params"]["trend_powers"] = [[1.5, 0]]
    with pytest.raises(ModelFileError, match="trend_powers"):
        modelfile.from_document(doc)


def test_a_coil_trend_reads_the_mix_of_the_inputs_and_is_checked():
    """`trend_mix`: the trend's monomials read q = mix . xs after the inputs (a hand-written formula)."""
    doc = make_doc("pso-svr")
    doc["params"]["trend_mix"] = [0.75, 0.25]
    doc["params"]["trend_powers"] = [[1, 0, 0], [0, 1, 0], [0, 0, 2], [0, 0, 3]]
    doc["params"]["trend_coef"] = [0.1, -0.2, 0.03, -0.004]
    model = modelfile.from_document(doc)
    x = np.array([[20.0, 0.001]])
    xs = (x - model.x_mean) / model.x_scale
    q = 0.75 * xs[0, 0] + 0.25 * xs[0, 1]
    trend = 0.1 * xs[0, 0] - 0.2 * xs[0, 1] + 0.03 * q**2 - 0.004 * q**3
    without = json.loads(json.dumps(doc))
    for key in ("trend_mix", "trend_powers"):
        del without["params"][key]
    without["params"]["trend_coef"] = [0.0, 0.0]
    kernel = modelfile.from_document(without).predict(x)[0][0]
    assert model.predict(x)[0][0] == pytest.approx(kernel + model.y_scale * trend, rel=1e-12)
    assert model.predict_one((20.0, 0.001))[0] == pytest.approx(kernel + model.y_scale * trend, rel=1e-12)
    bad = json.loads(json.dumps(doc))
    bad["params"]["trend_powers"] = [[1, 0], [0, 1]]  # q is a column of its own
    with pytest.raises(ModelFileError, match="trend_powers"):
        modelfile.from_document(bad)
    bad = json.loads(json.dumps(doc))
    bad["params"]["trend_mix"] = [0.75]
    with pytest.raises(ModelFileError, match="trend_mix"):
        modelfile.from_document(bad)
    del doc["params"]["trend_powers"]
    with pytest.raises(ModelFileError, match="trend_mix.*needs params.trend_powers"):
        modelfile.from_document(doc)


def test_save_refuses_an_invalid_document_and_writes_nothing(tmp_path):
    doc = make_doc("linear")
    doc["params"]["coef"] = [1.0]
    path = tmp_path / "m.json"
    with pytest.raises(ModelFileError):
        modelfile.save(path, doc)
    assert not path.exists()


def test_single_temperature_input(tmp_path):
    doc = make_doc("linear")
    doc["inputs"] = [{"kind": "temp_c"}]
    doc["input_scaling"] = {"mean": [20.0], "scale": [10.0]}
    doc["domain"] = {"min": [-10.0], "max": [50.0]}
    doc["params"] = {"coef": [0.5], "intercept": 0.1}
    model = modelfile.load(write_json(tmp_path, doc))
    y, clamped = model.predict(np.array([[30.0], [60.0]]))
    np.testing.assert_allclose(y, [Y_MEAN + Y_SCALE * (0.5 * 1.0 + 0.1), Y_MEAN + Y_SCALE * (0.5 * 3.0 + 0.1)])
    assert clamped.tolist() == [False, True]


# --- files that are not model files ---------------------------------------------------------------------------


def test_missing_file(tmp_path):
    assert "No such file" in rejected(tmp_path / "absent.json")


def test_directory(tmp_path):
    (tmp_path / "d").mkdir()
    rejected(tmp_path / "d")


def test_empty_file(tmp_path):
    path = tmp_path / "m.json"
    path.write_bytes(b"")
    assert "empty" in rejected(path)


def test_truncated_json(tmp_path):
    path = tmp_path / "m.json"
    modelfile.save(path, make_doc("pso-svr"))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    assert "JSON" in rejected(path)


@pytest.mark.parametrize("content", [b"hello, world", b"{'format': 'fogd-model'}", b"{\"a\": 1,}", b"\xef\xbb\xbf{}"])
def test_not_json(tmp_path, content):
    path = tmp_path / "m.json"
    path.write_bytes(content)
    assert "JSON" in rejected(path)


def test_not_utf8(tmp_path):
    path = tmp_path / "m.json"
    path.write_bytes(b'{"name": "\xff\xfe"}')
    assert "UTF-8" in rejected(path)


@pytest.mark.parametrize("content", ["[]", "3", '"fogd-model"', "null", "true"])
def test_top_level_not_an_object(tmp_path, content):
    path = tmp_path / "m.json"
    path.write_text(content)
    assert "object" in rejected(path)


def test_pickle_of_a_dict(tmp_path):
    path = tmp_path / "m.pkl"
    path.write_bytes(pickle.dumps(make_doc("linear")))
    assert "pickle" in rejected(path)


class _Hostile:
    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def test_hostile_pickle_is_never_run(tmp_path):
    canary = tmp_path / "canary"
    pickle.loads(pickle.dumps(_Hostile(canary)))  # proves the payload does run when unpickled
    assert canary.exists()

    marker = tmp_path / "pwned"
    for protocol in (0, 2, pickle.HIGHEST_PROTOCOL):
        path = tmp_path / f"m{protocol}.pkl"
        path.write_bytes(pickle.dumps(_Hostile(marker), protocol=protocol))
        rejected(path)
    assert "pickle" in rejected(tmp_path / f"m{pickle.HIGHEST_PROTOCOL}.pkl")
    assert not marker.exists()


def test_npy_and_npz(tmp_path):
    np.save(tmp_path / "a.npy", np.arange(4.0))
    np.savez(tmp_path / "b.npz", coef=np.arange(4.0))
    assert "npy" in rejected(tmp_path / "a.npy")
    assert "npz" in rejected(tmp_path / "b.npz")


def test_gzip(tmp_path):
    path = tmp_path / "m.json.gz"
    path.write_bytes(gzip.compress(json.dumps(make_doc("linear")).encode()))
    assert "gzip" in rejected(path)


def test_larger_than_limit_sparse(tmp_path):
    path = tmp_path / "m.json"
    modelfile.save(path, make_doc("linear"))
    with open(path, "r+b") as stream:
        stream.truncate(modelfile.MAX_MODEL_BYTES + 1)
    assert "larger" in rejected(path)


def test_larger_than_limit_whitespace(tmp_path):
    text = json.dumps(make_doc("linear"))
    path = tmp_path / "m.json"
    path.write_bytes(text.encode() + b" " * (modelfile.MAX_MODEL_BYTES + 1 - len(text)))
    assert "larger" in rejected(path)
    path.write_bytes(text.encode() + b" " * (modelfile.MAX_MODEL_BYTES - len(text)))  # exactly at the limit
    assert modelfile.load(path).method == "linear"


def test_deeply_nested_json(tmp_path):
    path = tmp_path / "m.json"
    path.write_text("[" * 100000 + "]" * 100000)
    assert "nested" in rejected(path)
    path.write_text('{"a":' * 100000 + "1" + "}" * 100000)
    assert "nested" in rejected(path)


@pytest.mark.parametrize("key", ["format", "name", "training"])
def test_nesting_just_inside_the_parser_limit(tmp_path, key):
    """A value nested as deep as the parser allows must still give a ModelFileError, not a RecursionError."""
    outcomes = set()
    for depth in range(sys.getrecursionlimit() + 50, 0, -25):
        doc = make_doc("linear")
        text = json.dumps(doc).replace(f'"{key}": ', f'"{key}": ' + "[" * depth + "1" + "]" * depth + ", \"_old\": ", 1)
        path = tmp_path / "m.json"
        path.write_text(text)
        message = rejected(path)
        outcomes.add("nested" in message)
    assert outcomes == {True, False}  # some depths parsed and were rejected by the field checks


# --- documents with a bad field -------------------------------------------------------------------------------


def set_at(doc: dict, dotted: str, value: Any) -> None:
    *parents, last = dotted.split(".")
    target = doc
    for part in parents:
        target = target[int(part)] if isinstance(target, list) else target[part]
    if isinstance(target, list):
        target[int(last)] = value
    else:
        target[last] = value


def delete_at(doc: dict, dotted: str) -> None:
    *parents, last = dotted.split(".")
    target = doc
    for part in parents:
        target = target[int(part)] if isinstance(target, list) else target[part]
    del target[int(last) if isinstance(target, list) else last]


# (method, dotted field, new value, words the message must hold)
BAD_FIELDS = [
    ("linear", "format", "fogd-modle", ["format", "fogd-modle"]),
    ("linear", "format", None, ["format"]),
    ("linear", "version", 6, ["version", "6"]),
    ("linear", "version", 0, ["version"]),
    ("linear", "version", "1", ["version", "integer"]),
    ("linear", "version", True, ["version", "integer"]),
    ("linear", "version", 1.0, ["version", "integer"]),
    ("linear", "method", "svr", ["method", "svr"]),
    ("linear", "method", 3, ["method", "string"]),
    ("linear", "name", 5, ["name", "string"]),
    ("linear", "name", "x" * 1000, ["name"]),
    ("linear", "created_utc", None, ["created_utc"]),
    ("linear", "fogd_version", [], ["fogd_version"]),
    ("linear", "reference_dph", "0.5", ["reference_dph", "number"]),
    ("linear", "training", [], ["training", "object"]),
    ("linear", "metrics", "good", ["metrics", "object"]),
    ("linear", "inputs", [], ["inputs"]),
    ("linear", "inputs", {"kind": "temp_c"}, ["inputs"]),
    ("linear", "inputs", [{"kind": "temp_c"}] * 17, ["inputs"]),
    ("linear", "inputs.0", {"kind": "pressure"}, ["inputs[0]", "kind"]),
    ("linear", "inputs.0", "temp_c", ["inputs[0]"]),
    ("linear", "inputs.0", {"kind": "temp_c", "window_s": 20.0}, ["inputs[0]", "window_s"]),
    ("linear", "inputs.1.average_s", 0.0, ["inputs[1]", "average_s"]),
    ("linear", "inputs.1.average_s", -1.0, ["inputs[1]", "average_s"]),
    ("linear", "inputs.1.average_s", 10.5, ["inputs[1]", "window_s"]),
    ("linear", "inputs.1.window_s", 1.5, ["inputs[1]", "window_s"]),
    ("linear", "inputs.1.window_s", 100000.0, ["inputs[1]", "86400"]),
    ("linear", "inputs.1.step_s", -1.0, ["inputs[1]", "step_s"]),
    ("linear", "inputs.1.step_s", 21.0, ["inputs[1]", "step_s"]),
    ("linear", "inputs.1.window_s", "20", ["inputs[1].window_s", "number"]),
    ("linear", "inputs.1.step_s", True, ["inputs[1].step_s", "number"]),
    ("linear", "input_scaling.scale", [10.0, -0.01], ["input_scaling.scale[1]", "positive"]),
    ("linear", "input_scaling.scale", [0.0, 0.01], ["input_scaling.scale[0]", "positive"]),
    ("linear", "input_scaling.scale", [10.0], ["input_scaling.scale"]),
    ("linear", "input_scaling.mean", [20.0, 0.0, 1.0], ["input_scaling.mean"]),
    ("linear", "input_scaling.mean", "20", ["input_scaling.mean"]),
    ("linear", "input_scaling.mean", [20.0, "0"], ["input_scaling.mean[1]", "number"]),
    ("linear", "input_scaling.mean", [20.0, False], ["input_scaling.mean[1]", "number"]),
    ("linear", "output_scaling.scale", -2.0, ["output_scaling.scale", "positive"]),
    ("linear", "output_scaling.scale", 0, ["output_scaling.scale", "positive"]),
    ("linear", "output_scaling.mean", None, ["output_scaling.mean", "number"]),
    ("linear", "domain.min", [60.0, -0.05], ["domain", "min above max"]),
    ("linear", "domain.max", [50.0, -0.06], ["domain", "min above max"]),
    ("linear", "domain.max", [50.0], ["domain.max"]),
    ("linear", "params.coef", [0.5, -1.5, 2.0], ["params.coef"]),
    ("linear", "params.coef", [0.5], ["params.coef"]),
    ("linear", "params.intercept", "0.1", ["params.intercept", "number"]),
    ("linear", "params", {"coef": [0.5, -1.5], "intercept": 0.1, "gamma": 1.0}, ["params", "gamma"]),
    ("ls-poly", "params.powers.0", [1.5, 0], ["params.powers", "integers"]),
    ("ls-poly", "params.powers.2", [-1, 0], ["params.powers", "integers"]),
    ("ls-poly", "params.powers.2", [21, 0], ["params.powers", "integers"]),
    ("ls-poly", "params.powers.2", ["2", 0], ["params.powers[2][0]", "number"]),
    ("ls-poly", "params.powers.1", [0, 1, 0], ["params.powers[1]"]),
    ("ls-poly", "params.powers", [], ["params.powers"]),
    ("ls-poly", "params.coef", [0.5, -1.2, 0.3, 0.7], ["params.coef"]),
    ("rbf-nn", "params.centres.1", [1.0], ["params.centres[1]"]),
    ("rbf-nn", "params.coef", [1.0, -0.5], ["params.coef"]),
    ("rbf-nn", "params.width", 0.0, ["params.width", "positive"]),
    ("rbf-nn", "params.width", -0.8, ["params.width", "positive"]),
    ("pso-svr", "params.support_vectors.2", [0.7, -0.3, 1.0], ["params.support_vectors[2]"]),
    ("pso-svr", "params.support_vectors", [], ["params.dual_coef"]),  # no vectors is valid; 4 weights are not
    ("pso-svr", "params.support_vectors", [0.1, 0.2], ["params.support_vectors[0]"]),
    ("pso-svr", "params.dual_coef", [0.9, -0.4, 0.3], ["params.dual_coef"]),
    ("pso-svr", "params.dual_coef", [0.9, -0.4, 0.3, -1.0, 2.0], ["params.dual_coef"]),
    ("pso-svr", "params.gamma", 0.0, ["params.gamma", "positive"]),
    ("pso-svr", "params.gamma", True, ["params.gamma", "number"]),
    ("pso-svr", "params.gamma", 10**400, ["params.gamma", "number"]),
    ("pso-svr", "params.dual_coef", [0.9, -(10**400), 0.3, -1.0], ["params.dual_coef[1]", "number"]),
    ("pso-svr", "params.kernel_columns", [2], ["params.kernel_columns", "increasing order"]),
    ("pso-svr", "params.kernel_columns", [1, 0], ["params.kernel_columns", "increasing order"]),
    ("pso-svr", "params.kernel_columns", [0, 0], ["params.kernel_columns", "each once"]),
    ("pso-svr", "params.kernel_columns", [], ["params.kernel_columns"]),
    ("pso-svr", "params.kernel_columns", [True], ["params.kernel_columns"]),
    ("pso-svr", "params.kernel_columns", "0", ["params.kernel_columns"]),
    ("pso-svr", "params.kernel_columns", [0], ["params.support_vectors[0]", "1 numbers"]),  # vectors of both inputs
]


@pytest.mark.parametrize(("method", "field", "value", "words"), BAD_FIELDS, ids=[f"{c[0]}:{c[1]}" for c in BAD_FIELDS])
def test_bad_field(tmp_path, method, field, value, words):
    doc = make_doc(method)
    set_at(doc, field, value)
    message = rejected(write_json(tmp_path, doc))
    for word in words:
        assert word in message, (word, message)


@pytest.mark.parametrize(
    ("method", "field"),
    [("linear", key) for key in sorted(modelfile.TOP_KEYS)]
    + [
        ("linear", "input_scaling.scale"),
        ("linear", "output_scaling.mean"),
        ("linear", "domain.min"),
        ("linear", "inputs.1.window_s"),
        ("linear", "inputs.0.kind"),
        ("ls-poly", "params.powers"),
        ("rbf-nn", "params.width"),
        ("pso-svr", "params.dual_coef"),
        ("pso-svr", "params.intercept"),
    ],
)
def test_missing_key(tmp_path, method, field):
    doc = make_doc(method)
    delete_at(doc, field)
    message = rejected(write_json(tmp_path, doc))
    assert field.rsplit(".", 1)[-1] in message


@pytest.mark.parametrize("where", ["", "params", "input_scaling", "domain", "inputs.1"])
def test_unknown_key(tmp_path, where):
    doc = make_doc("pso-svr")
    target = doc
    for part in where.split(".") if where else []:
        target = target[int(part)] if isinstance(target, list) else target[part]
    target["sneaky"] = 1
    message = rejected(write_json(tmp_path, doc))
    assert "unknown" in message and "sneaky" in message


@pytest.mark.parametrize("literal", ["NaN", "Infinity", "-Infinity", "1e400", "-1e999"])
@pytest.mark.parametrize(
    ("method", "field"),
    [
        ("pso-svr", "params.gamma"),
        ("pso-svr", "params.intercept"),
        ("pso-svr", "params.dual_coef.2"),
        ("pso-svr", "params.support_vectors.1.0"),
        ("rbf-nn", "params.width"),
        ("ls-poly", "params.powers.0.0"),
        ("linear", "output_scaling.mean"),
        ("linear", "output_scaling.scale"),
        ("linear", "input_scaling.scale.1"),
        ("linear", "input_scaling.mean.0"),
        ("linear", "domain.min.0"),
        ("linear", "domain.max.1"),
        ("linear", "reference_dph"),
        ("linear", "inputs.1.window_s"),
    ],
)
def test_non_finite_literals(tmp_path, method, field, literal):
    doc = make_doc(method)
    set_at(doc, field, "@@here@@")
    path = tmp_path / "m.json"
    path.write_text(json.dumps(doc).replace('"@@here@@"', literal))
    message = rejected(path)
    assert literal.lstrip("-") in message or field.split(".")[0] in message, message


def test_huge_support_vector_table(tmp_path):
    doc = make_doc("pso-svr")
    rows = modelfile.MAX_ROWS + 1
    doc["params"]["support_vectors"] = [[0.0, 0.0]] * rows
    doc["params"]["dual_coef"] = [0.0] * rows
    message = rejected(write_json(tmp_path, doc))
    assert "params.support_vectors" in message and str(modelfile.MAX_ROWS) in message


def test_huge_polynomial(tmp_path):
    doc = make_doc("ls-poly")
    rows = modelfile.MAX_ROWS + 1
    doc["params"]["powers"] = [[0, 0]] * rows
    doc["params"]["coef"] = [0.0] * rows
    message = rejected(write_json(tmp_path, doc))
    assert "params.powers" in message and str(modelfile.MAX_ROWS) in message


def test_from_document_rejects_python_values_json_cannot_hold():
    for value in (float("nan"), float("inf"), (1, 2), {1, 2}, "0.6", None):
        doc = make_doc("pso-svr")
        doc["params"]["gamma"] = value
        with pytest.raises(ModelFileError):
            modelfile.from_document(doc)
    with pytest.raises(ModelFileError):
        modelfile.from_document(None)


# --- fuzzing --------------------------------------------------------------------------------------------------

json_scalars = (
    st.none()
    | st.booleans()
    | st.integers()
    | st.integers(min_value=-(10**400), max_value=10**400)
    | st.floats()
    | st.text(max_size=8)
    | st.sampled_from(["temp_c", "temp_rate_cps", "fogd-model", "pso-svr", "linear", "ls-poly", "rbf-nn", 0, 1, 0.5])
)
json_values = st.recursive(
    json_scalars,
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4),
    max_leaves=12,
)


def paths(value: Any, prefix: tuple = ()) -> list[tuple]:
    """Every location in a JSON value, as a tuple of keys and indices."""
    found = [prefix]
    if isinstance(value, dict):
        for key, item in value.items():
            found += paths(item, prefix + (key,))
    elif isinstance(value, list):
        for index, item in enumerate(value):
            found += paths(item, prefix + (index,))
    return found


@st.composite
def mutated_documents(draw) -> dict:
    doc = make_doc(draw(st.sampled_from(METHODS)))
    for _ in range(draw(st.integers(1, 3))):
        where = draw(st.sampled_from(paths(doc)[1:]))
        parent = doc
        for part in where[:-1]:
            parent = parent[part]
        action = draw(st.sampled_from(["delete", "replace", "replace", "add"]))
        if action == "delete":
            del parent[where[-1]]
        elif action == "replace":
            parent[where[-1]] = draw(json_values)
        elif isinstance(parent, dict):
            parent[draw(st.text(max_size=6))] = draw(json_values)
        else:
            parent.insert(where[-1], draw(json_values))
    return doc


def load_or_model_file_error(path: Path) -> FrozenModel | None:
    try:
        model = modelfile.load(path)
    except ModelFileError as error:
        assert "\n" not in str(error)
        return None
    d = len(model.inputs)
    with np.errstate(all="ignore"):
        y, clamped = model.predict(np.zeros((3, d)))
    assert y.shape == clamped.shape == (3,)
    return model


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(doc=mutated_documents())
def test_fuzz_mutated_documents_load_or_raise_model_file_error(tmp_path, doc):
    path = tmp_path / "fuzz.json"
    path.write_text(json.dumps(doc), encoding="utf-8")  # NaN/Infinity written as literals on purpose
    load_or_model_file_error(path)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_fuzz_byte_damage_load_or_raise_model_file_error(tmp_path, data):
    raw = bytearray(json.dumps(make_doc(data.draw(st.sampled_from(METHODS))), indent=1).encode())
    for _ in range(data.draw(st.integers(1, 4))):
        at = data.draw(st.integers(0, len(raw) - 1))
        action = data.draw(st.sampled_from(["set", "delete", "insert"]))
        byte = data.draw(st.integers(0, 255))
        if action == "set":
            raw[at] = byte
        elif action == "delete":
            del raw[at]
        else:
            raw.insert(at, byte)
    path = tmp_path / "fuzz.json"
    path.write_bytes(bytes(raw))
    load_or_model_file_error(path)


def test_mutation_helpers_do_mutate():
    doc = make_doc("linear")
    set_at(doc, "inputs.1.window_s", 5.0)
    delete_at(doc, "params.intercept")
    assert doc["inputs"][1]["window_s"] == 5.0 and "intercept" not in doc["params"]
    assert ("params", "coef", 1) in paths(doc)



def test_a_kernel_of_some_inputs_reads_those_only(tmp_path):
    """kernel_columns [1]: one-column support vectors, the kernel of the second input alone (written out here),
    the trend over both; the one-row path agrees with the array path (within 1e-12, its sums in Python floats)."""
    doc = make_doc("pso-svr")
    doc["params"].update(kernel_columns=[1], support_vectors=[[0.2], [-0.5], [1.1], [0.0]])
    model = modelfile.load(write_json(tmp_path, doc))
    p = doc["params"]
    x = inside_points()
    xs = (x - X_MEAN) / X_SCALE
    kernel = [sum(a * np.exp(-p["gamma"] * (row[1] - sv[0]) ** 2) for a, sv in zip(p["dual_coef"], p["support_vectors"]))
              for row in xs]  # fmt: skip
    want = Y_MEAN + Y_SCALE * (np.array(kernel) + xs @ np.array(p["trend_coef"]) + p["intercept"])
    got, _ = model.predict(x)
    np.testing.assert_allclose(got, want, rtol=1e-12)
    np.testing.assert_allclose([model.predict_one(row)[0] for row in x.tolist()], got, rtol=1e-12)
