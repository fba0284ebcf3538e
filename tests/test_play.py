"""The play input: the operator's streaming form equals its batch form bit for bit for any chunking; it holds
the direction of the last move; it is parsed, computed in the input bank and kept by the model file; so is the
play of a lagged temperature, which turns after the reading does."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fogd.core import modelfile
from fogd.core.inputs import (
    TEMP_PLAY,
    InputBank,
    InputSpec,
    dequantised,
    describe_inputs,
    inputs_batch,
    parse_inputs,
)
from fogd.core.lag import lag_batch
from fogd.core.play import PlayFilter, play_batch
from fogd.errors import ModelFileError


def chunked(values: np.ndarray, sizes: list[int], stream: PlayFilter | InputBank) -> np.ndarray:
    """`stream` fed `values` in chunks of `sizes` (then the rest), its outputs joined."""
    parts, start = [], 0
    for size in [*sizes, values.size]:
        parts.append(stream.update(values[start : start + size]))
        start += size
        if start >= values.size:
            break
    return np.concatenate(parts)


@settings(max_examples=200, deadline=None)
@given(
    temps=st.lists(st.floats(-50, 120, allow_nan=False), min_size=1, max_size=300),
    sizes=st.lists(st.integers(0, 40), max_size=30),
    width_c=st.floats(0.01, 50.0),
)
def test_streaming_equals_batch_bit_for_bit_for_any_chunking(temps, sizes, width_c):
    values = np.array(temps)
    assert np.array_equal(chunked(values, sizes, PlayFilter(width_c)), play_batch(values, width_c))


def test_it_holds_the_direction_of_the_last_move():
    up = np.linspace(20.0, 30.0, 101)  # 0.1 C a sample
    history = np.r_[np.full(10, 20.0), up, np.full(50, 30.0), up[::-1][:11], np.full(20, 29.0), up[::-1]]
    out = play_batch(history, 2.0)
    assert np.all(out[:10] == 0.0)  # at rest from the start
    assert out[10 + 10] == pytest.approx(0.5)  # 1 C into the heating: half way
    assert np.all(out[10 + 20 : 10 + 101 + 50] == 1.0)  # heated from rest by the width or more, held through the soak
    turned = out[161 : 161 + 11]  # cooling by 1 C after the turn: from +1 down, linearly, to the middle of 2 widths
    np.testing.assert_allclose(turned, np.linspace(1.0, 0.5, 11), atol=1e-12)
    assert np.all(out[-50:] == -1.0)  # cooled by twice the width or more


def test_noise_narrower_than_the_width_moves_it_little():
    rng = np.random.default_rng(5)
    ramp = np.r_[np.linspace(0.0, 10.0, 2000), np.full(2000, 10.0)]
    noisy = np.round((ramp + rng.normal(0.0, 0.01, ramp.size)) / 0.0625) * 0.0625
    out = play_batch(noisy, 2.0)
    assert np.all(out[1000:] > 0.95)


def test_parsed_computed_in_the_bank_and_described():
    specs = parse_inputs("temp,lags@30,300,play@2")
    assert specs[-1] == InputSpec(TEMP_PLAY, width_c=2.0)
    assert describe_inputs(specs) == "temp,lags@30,300,play@2"
    assert specs[-1].label == "temp_play@2C"
    temps = 20 + np.cumsum(np.random.default_rng(6).normal(0.0, 0.05, 3000))
    batch = inputs_batch(temps, specs, 10.0)
    np.testing.assert_array_equal(batch[:, -1], play_batch(temps, 2.0))
    bank = InputBank(specs, 10.0)
    streamed = np.vstack([bank.update(temps[i : i + 7]) for i in range(0, temps.size, 7)])
    assert np.array_equal(streamed, batch)
    one = InputBank(specs, 10.0)
    assert np.array_equal(np.array([one.update_one(t) for t in temps.tolist()]), batch)
    with pytest.raises(ValueError, match="play"):
        parse_inputs("temp,play@0")
    with pytest.raises(ValueError, match="width_c"):
        InputSpec("temp_lag_c", tau_s=30.0, width_c=1.0)


def _document(specs):
    d = len(specs)
    return modelfile.document(
        name="m", method="linear", inputs=specs, x_mean=np.zeros(d), x_scale=np.ones(d), y_mean=0.0, y_scale=1.0,
        domain_min=np.full(d, -100.0), domain_max=np.full(d, 100.0), params={"coef": [0.1] * d, "intercept": 0.0},
        reference_dph=0.0, training={}, metrics={}, created_utc="2026-01-01T00:00:00+00:00")  # fmt: skip


@pytest.mark.parametrize("resolution_c", [None, 1.0])
def test_model_file_keeps_a_play_input_as_version_5(tmp_path, resolution_c):
    specs = dequantised(parse_inputs("temp,lags@30,300,play@2"), resolution_c)
    document = _document(specs)
    assert document["version"] == 5  # an older fogd refuses it by its version
    path = tmp_path / "m.json"
    modelfile.save(path, document)
    assert modelfile.load(path).inputs == specs
    assert _document(parse_inputs("temp,lags@30,300"))["version"] == 2  # without a play input, as before


@pytest.mark.parametrize("version", [2, 4])
def test_a_play_input_in_an_older_version_is_refused(tmp_path, version):
    document = _document(parse_inputs("temp,play@2"))
    document["version"] = version
    with pytest.raises(ModelFileError, match="inputs\\[1\\]"):
        modelfile.from_document(document)


def test_a_bad_play_width_is_refused():
    document = _document(parse_inputs("temp,play@2"))
    document["inputs"][1]["width_c"] = 0.0
    with pytest.raises(ModelFileError, match="width_c"):
        modelfile.from_document(document)


@settings(max_examples=100, deadline=None)
@given(
    temps=st.lists(st.floats(-50, 120, allow_nan=False), min_size=1, max_size=300),
    sizes=st.lists(st.integers(0, 40), max_size=30),
    lag_s=st.floats(0.5, 3000.0),
)
def test_a_lagged_play_streams_as_its_batch_whatever_the_chunking(temps, sizes, lag_s):
    """The play of a lag, in chunks or a sample at a time, is the batch input bit for bit (and is the play of the
    lag: the lag's batch filter then the operator)."""
    values = np.array(temps)
    (spec,) = parse_inputs(f"play@1.5:{lag_s!r}")
    batch = inputs_batch(values, (spec,), 2.0)[:, 0]
    assert np.array_equal(chunked(values, sizes, InputBank((spec,), 2.0))[:, 0], batch)
    one = InputBank((spec,), 2.0)
    assert np.array_equal(np.array([one.update_one(t)[0] for t in values.tolist()]), batch)
    assert np.array_equal(batch, play_batch(lag_batch(values, lag_s, 2.0), 1.5))


def test_a_lagged_play_turns_after_the_reading_turns():
    """A triangle of 1 C/min: the play of the reading leaves +1 at the turn; the play of a 600 s lag keeps heating
    for minutes after it (the lag still rising), as a coil behind its sensor does."""
    t_s = np.arange(0.0, 7200.0)
    temp_c = 20.0 + np.where(t_s < 3600.0, t_s, 7200.0 - t_s) / 60.0
    plain, lagged = (inputs_batch(temp_c, parse_inputs(text), 1.0)[:, 0] for text in ("play@2", "play@2:600"))
    first_below = lambda out: int(np.argmax((t_s > 3600.0) & (out < 1.0)))  # noqa: E731
    assert first_below(plain) - 3600 < 5
    assert first_below(lagged) - 3600 > 300


def test_a_lagged_play_is_parsed_described_and_kept_by_the_model_file(tmp_path):
    specs = parse_inputs("temp,lags@30,300,play@2:600")
    assert specs[-1] == InputSpec(TEMP_PLAY, width_c=2.0, play_lag_s=600.0)
    assert describe_inputs(specs) == "temp,lags@30,300,play@2:600" and specs[-1].label == "temp_play@2C@lag600s"
    path = tmp_path / "m.json"
    modelfile.save(path, _document(specs))
    assert modelfile.load(path).inputs == specs
    document = _document(specs)
    document["inputs"][-1]["lag_s"] = -1.0
    with pytest.raises(ModelFileError, match="lag_s"):
        modelfile.from_document(document)
    (auto,) = parse_inputs("play@2:auto")
    assert auto.play_lag_auto and auto.play_lag_s is None and auto.short == "play@2:auto"
    with pytest.raises(ValueError, match="chosen by fogd-train"):
        auto.to_dict()
    with pytest.raises(ValueError, match="must be chosen"):
        inputs_batch(np.zeros(3), (auto,), 1.0)
    for bad in ("play@2:0", "play@2:x", "lag@30:5"):
        with pytest.raises(ValueError):
            parse_inputs(bad)
