"""Multi-channel model files (version 3): one model per channel, each validated as a version-2 document;
single-channel files load as before, and as the one channel rate_dph through load_channels."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_modelfile import (
    DOMAIN_MAX,
    DOMAIN_MIN,
    METHODS,
    expected,
    inside_points,
    json_values,
    make_doc,
    paths,
    write_json,
)

from fogd.core import modelfile
from fogd.core.channels import ChannelModels
from fogd.errors import ModelFileError

ASSIGNED = {"rate_x_dph": "linear", "rate_y_dph": "pso-svr", "accel_z_g": "ls-poly"}


def multi_doc(assigned: dict[str, str] = ASSIGNED) -> dict:
    return modelfile.channels_document(
        name="unit-7", documents={channel: make_doc(method) for channel, method in assigned.items()},
        created_utc="2024-01-01T00:00:00Z",
    )  # fmt: skip


def rejected(path: Path, loader=modelfile.load_channels) -> str:
    with pytest.raises(ModelFileError) as caught:
        loader(path)
    message = str(caught.value)
    assert "\n" not in message and "\r" not in message, message
    assert str(path) in message, message
    return message.replace(str(path), "<file>")


def test_each_channel_evaluates_its_own_formula(tmp_path):
    path = tmp_path / "imu.json"
    modelfile.save(path, multi_doc())
    models = modelfile.load_channels(path)
    assert isinstance(models, ChannelModels)
    assert models.channels == tuple(ASSIGNED) and models.name == "unit-7" and models.version == 3
    x = np.vstack([inside_points(), DOMAIN_MIN, DOMAIN_MAX])
    for channel, method in ASSIGNED.items():
        assert models[channel].method == method
        np.testing.assert_allclose(models[channel].predict(x)[0], expected(method, x), rtol=1e-12, atol=1e-12)
    assert json.loads(path.read_text())["version"] == 3


def test_split_names_the_channels_covered_and_passed_through(tmp_path):
    models = modelfile.load_channels(write_json(tmp_path, multi_doc()))
    available = ("rate_x_dph", "rate_y_dph", "rate_z_dph", "accel_x_g", "accel_y_g", "accel_z_g")
    assert models.split(available) == (("rate_x_dph", "rate_y_dph", "accel_z_g"), ("rate_z_dph", "accel_x_g", "accel_y_g"))


@pytest.mark.parametrize("version", [1, 2])
def test_single_channel_files_are_the_one_channel_rate_dph(tmp_path, version):
    doc = make_doc("rbf-nn")
    doc["version"] = version
    path = write_json(tmp_path, doc)
    models = modelfile.load_channels(path)
    assert models.channels == ("rate_dph",) and models.version == version and models.name == "test-rbf-nn"
    x = inside_points()
    np.testing.assert_array_equal(models["rate_dph"].predict(x)[0], modelfile.load(path).predict(x)[0])


def test_single_channel_files_are_still_version_2_byte_for_byte(tmp_path):
    """What an older fogd reads: a single-axis model is written exactly as before (indent 1, version 2)."""
    doc = make_doc("pso-svr")
    path = tmp_path / "m.json"
    modelfile.save(path, doc)
    assert path.read_text(encoding="utf-8") == json.dumps(doc, indent=1, allow_nan=False) + "\n"
    assert doc["version"] == 2


def test_load_refuses_a_multi_channel_file_in_one_line(tmp_path):
    message = rejected(write_json(tmp_path, multi_doc()), loader=modelfile.load)
    assert "version" in message and "rate_x_dph, rate_y_dph, accel_z_g" in message and "single-channel" in message


def _bad(doc: dict, where: str, value) -> dict:
    doc = copy.deepcopy(doc)
    parts = where.split(".")
    target = doc
    for part in parts[:-1]:
        target = target[part]
    if value is _DELETE:
        del target[parts[-1]]
    else:
        target[parts[-1]] = value
    return doc


_DELETE = object()
BAD = [
    ("name", _DELETE, ["lacks name"]),
    ("channels", _DELETE, ["lacks channels"]),
    ("sneaky", 1, ["unknown", "sneaky"]),
    ("format", "other", ["format"]),
    ("channels", [], ["channels", "object"]),
    ("channels", {}, ["channels", "empty"]),
    ("channels.rate_w_dph", make_doc("linear"), ["unknown channel", "rate_w_dph"]),
    ("channels.rate_dph", make_doc("linear"), ["unknown channel", "rate_dph"]),
    ("channels.rate_x_dph", "a model", ["channel rate_x_dph", "object"]),
    ("channels.rate_x_dph.params.coef", [1.0], ["channel rate_x_dph", "params.coef"]),
    ("channels.rate_y_dph.params.gamma", -1.0, ["channel rate_y_dph", "params.gamma", "positive"]),
    ("channels.accel_z_g.version", 3, ["channel accel_z_g", "version"]),
    ("channels.rate_x_dph.sneaky", 1, ["channel rate_x_dph", "unknown", "sneaky"]),
    ("channels.rate_x_dph", multi_doc(), ["channels.rate_x_dph", "multi-channel"]),
    ("name", "unit\n7", ["control character"]),
    ("channels.rate_x_dph.name", "x\x1b[2J", ["control character"]),
    ("created_utc", 7, ["created_utc", "string"]),
]


@pytest.mark.parametrize(("where", "value", "words"), BAD, ids=[case[0] + ":" + str(i) for i, case in enumerate(BAD)])
def test_bad_multi_channel_fields_give_one_line(tmp_path, where, value, words):
    message = rejected(write_json(tmp_path, _bad(multi_doc(), where, value)))
    for word in words:
        assert word in message, (word, message)


def test_control_character_in_a_channel_name(tmp_path):
    doc = multi_doc()
    doc["channels"]["rate_x_dph\n"] = doc["channels"].pop("rate_x_dph")
    assert "control character" in rejected(write_json(tmp_path, doc))


def test_save_refuses_a_bad_multi_channel_document_and_writes_nothing(tmp_path):
    path = tmp_path / "m.json"
    with pytest.raises(ModelFileError):
        modelfile.save(path, _bad(multi_doc(), "channels.rate_x_dph.params.coef", [1.0]))
    assert not path.exists()


@st.composite
def mutated(draw) -> dict:
    doc = multi_doc({channel: draw(st.sampled_from(METHODS)) for channel in ("rate_x_dph", "accel_y_g")})
    for _ in range(draw(st.integers(1, 3))):
        where = draw(st.sampled_from(paths(doc)[1:]))
        parent = doc
        for part in where[:-1]:
            parent = parent[part]
        if draw(st.booleans()):
            del parent[where[-1]]
        else:
            parent[where[-1]] = draw(json_values)
    return doc


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(doc=mutated())
def test_fuzz_mutated_multi_channel_documents_load_or_raise_one_line(tmp_path, doc):
    path = tmp_path / "fuzz.json"
    path.write_text(json.dumps(doc), encoding="utf-8")
    try:
        models = modelfile.load_channels(path)
    except ModelFileError as error:
        assert "\n" not in str(error)
        return
    for model in models.values():
        y, _ = model.predict(np.zeros((2, len(model.inputs))))
        assert y.shape == (2,)
