"""Outside the calibrated range (fogd.core.outside_range): inside it every policy is the model, bit for bit; beyond
it each policy does what it says, on the row path and the array path alike, and every such sample is CLAMPED."""

import json

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from fogd.calibration.training import TrainConfig, train
from fogd.core import modelfile
from fogd.core.compensator import Compensator
from fogd.core.flags import Flag
from fogd.core.frozen import FrozenModel, Linear, StackedModels, Svr
from fogd.core.inputs import clamp_rows, parse_inputs
from fogd.core.outside_range import DEFAULT_POLICY, POLICIES, OutsideRange
from fogd.core.runio import Run
from fogd.errors import FogdError

INPUTS = parse_inputs("temp,lag@100,lag@300,rate@20")  # temperatures moved together, a rate clipped alone
LOW = np.array([10.0, 10.5, 11.0, -0.002])
HIGH = np.array([20.0, 19.5, 19.0, 0.002])
MEAN = np.array([15.0, 15.0, 15.0, 0.0])
SCALE = np.array([3.0, 2.8, 2.5, 0.001])
COEF = np.array([0.4, -0.1, 0.3, 0.2])
INTERCEPT = 0.05


def kernel_model(policy: str = "clamp") -> FrozenModel:
    """A small SVR over a linear trend (a kernel on the temperature alone), with `policy` beyond its domain."""
    evaluator = Svr(np.array([[-1.0], [0.0], [0.7]]), np.array([0.3, -0.2, 0.5]), 0.8, np.array([0.2, 0.1, -0.3, 0.4]),
                    0.1, kernel_columns=(0,))  # fmt: skip
    outside = None if policy == "clamp" else OutsideRange(policy, COEF, INTERCEPT)
    return FrozenModel("pso-svr", INPUTS, MEAN, SCALE, 0.01, 0.5, LOW, HIGH, evaluator, outside=outside)


def linear_model(policy: str = "clamp") -> FrozenModel:
    outside = None if policy == "clamp" else OutsideRange(policy, COEF, INTERCEPT)
    return FrozenModel("linear", INPUTS, MEAN, SCALE, 0.01, 0.5, LOW, HIGH, Linear(COEF, INTERCEPT), outside=outside)


def rows(draw_unit: np.ndarray, reach: float) -> np.ndarray:
    """Rows from unit draws in [0, 1): inside the box, or reaching `reach` box-widths beyond it."""
    return LOW + (draw_unit * (1 + 2 * reach) - reach) * (HIGH - LOW)


units = st.lists(st.lists(st.floats(0, 1, exclude_max=True), min_size=4, max_size=4), min_size=1, max_size=30)


@settings(max_examples=60, deadline=None)
@given(unit=units, policy=st.sampled_from(POLICIES), kernel=st.booleans())
def test_inside_the_range_every_policy_is_the_model_bit_for_bit(unit, policy, kernel):
    make = kernel_model if kernel else linear_model
    x = rows(np.array(unit), 0.0)
    x[:, 1:3] = np.clip(x[:, 1:3], x[:, :1] - 0.5, x[:, :1] + 0.5)  # lags near the temperature: nothing moves
    x = clamp_rows(x, LOW, HIGH, make()._shifted)
    comp, clamped = make(policy).predict(x)
    reference, _ = make().predict(x)
    assert not clamped.any()
    np.testing.assert_array_equal(comp, reference)
    for row in x.tolist():
        assert make(policy).predict_one(row) == make().predict_one(row)


def _outside(unit: list) -> np.ndarray:
    x = rows(np.array(unit), 0.6)
    x = x[np.any(clamp_rows(x, LOW, HIGH, linear_model()._shifted) != x, axis=1)]
    assume(len(x) > 0)
    return x


@settings(max_examples=60, deadline=None)
@given(unit=units, kernel=st.booleans())
def test_trend_continues_the_edge_along_the_linear_fits_slope(unit, kernel):
    x = _outside(unit)
    make = kernel_model if kernel else linear_model
    comp, clamped = make("trend").predict(x)
    at_edge, _ = make().predict(x)  # the clamp: the model at the edge
    edge = clamp_rows(x, LOW, HIGH, make()._shifted)
    expected = at_edge + 0.5 * (((x - edge) / SCALE) * COEF).sum(axis=1)
    assert clamped.all()
    np.testing.assert_allclose(comp, expected, rtol=1e-12, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(unit=units, kernel=st.booleans())
def test_linear_is_the_linear_fit_unclamped(unit, kernel):
    x = _outside(unit)
    comp, clamped = (kernel_model if kernel else linear_model)("linear").predict(x)
    assert clamped.all()
    np.testing.assert_allclose(comp, 0.01 + 0.5 * (((x - MEAN) / SCALE) @ COEF + INTERCEPT), rtol=1e-12, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(unit=units)
def test_edge_and_trend_of_a_linear_model_are_the_model_unclamped(unit):
    x = _outside(unit)
    unclamped = linear_model().predict_unclamped(x)
    for policy in ("edge", "trend"):
        comp, clamped = linear_model(policy).predict(x)
        assert clamped.all()
        np.testing.assert_allclose(comp, unclamped, rtol=1e-9, atol=1e-9, err_msg=policy)
    assert not np.allclose(linear_model().predict(x)[0], unclamped)  # the clamp does not extrapolate


@settings(max_examples=60, deadline=None)
@given(unit=units, policy=st.sampled_from(POLICIES), kernel=st.booleans())
def test_row_path_and_stack_give_the_array_paths_floats(unit, policy, kernel):
    x = rows(np.array(unit), 0.6)
    model = (kernel_model if kernel else linear_model)(policy)
    comp, clamped = model.predict(x)
    stacked, stacked_clamped = StackedModels([model, linear_model(policy)]).predict(x)
    np.testing.assert_allclose(stacked[:, 0], comp, rtol=1e-12, atol=1e-13)
    np.testing.assert_array_equal(stacked_clamped[:, 0], clamped)
    stack = StackedModels([model, linear_model(policy)])
    for row, value, was in zip(x.tolist(), comp, clamped):
        one, one_clamped = model.predict_one(row)
        assert one_clamped == was
        assert one == pytest.approx(value, rel=1e-10, abs=1e-12)
        values, flags = stack.predict_one(row)
        assert flags[0] == was and values[0] == pytest.approx(value, rel=1e-10, abs=1e-12)


def _temperatures(n: int, seed: int) -> np.ndarray:
    """From 15 C out to 24 C and down to 6 C (the domain is 10-20 C), a ramp slow enough to keep the rate inside."""
    t = np.arange(n)
    path = 15 + 9 * np.sin(2 * np.pi * t / n)
    return path + np.random.default_rng(seed).normal(0, 0.002, n)


@settings(max_examples=20, deadline=None)
@given(policy=st.sampled_from(POLICIES), seed=st.integers(0, 1000), chunk=st.integers(1, 40))
def test_compensator_flags_every_sample_beyond_the_range_and_daemon_equals_replay(policy, seed, chunk):
    temp = _temperatures(4000, seed)
    rate = np.zeros(temp.size)
    whole = Compensator(kernel_model(policy), 1.0).process(rate, temp)
    clamp = Compensator(kernel_model(), 1.0).process(rate, temp)
    beyond = (whole.temp_c < LOW[0]) | (whole.temp_c > HIGH[0])
    flagged = (whole.flags & Flag.CLAMPED) != 0
    assert beyond.any() and flagged[beyond].all()
    np.testing.assert_array_equal(whole.flags, clamp.flags)  # every policy flags the same samples
    np.testing.assert_array_equal(whole.comp_dph[~flagged], clamp.comp_dph[~flagged])
    if policy != "clamp":
        assert not np.allclose(whole.comp_dph[beyond], clamp.comp_dph[beyond])
    daemon = Compensator(kernel_model(policy), 1.0)  # small chunks: the daemon's row path
    parts = [daemon.process(rate[i : i + chunk], temp[i : i + chunk]) for i in range(0, temp.size, chunk)]
    np.testing.assert_array_equal(np.concatenate([p.flags for p in parts]), whole.flags)
    np.testing.assert_allclose(np.concatenate([p.comp_dph for p in parts]), whole.comp_dph, rtol=1e-10, atol=1e-12)


def _run(temp_c: np.ndarray, seed: int) -> Run:
    rng = np.random.default_rng(seed)
    t = np.arange(temp_c.size, dtype=np.float64)
    error = 0.02 * (temp_c - 15) + 0.002 * (temp_c - 15) ** 2
    return Run(f"run{seed}.csv", t, error + rng.normal(0, 0.001, t.size), temp_c, 1.0, "")


def test_training_stores_the_measured_default_and_the_file_serves_it(tmp_path):
    hours = np.arange(6 * 3600) / 3600
    calibration = _run(15 + 5 * np.sin(2 * np.pi * hours / 3), 1)  # 10-20 C
    trained = train([calibration], TrainConfig(method="pso-svr", inputs=parse_inputs("temp,rate@50"),
                                               fit=dataclass_options()))  # fmt: skip
    assert DEFAULT_POLICY == "trend" and trained.document["outside_range"]["policy"] == "trend"
    path = tmp_path / "model.json"
    modelfile.save(path, trained.document)
    model = modelfile.load(path)
    hot = np.array([[30.0, 0.0]])
    comp, clamped = model.predict(hot)
    at_edge = model.predict(np.array([[model.domain_max[0], 0.0]]))[0]
    assert clamped[0] and comp[0] > at_edge[0] + 0.1  # the trend rises on past the edge (0.02 deg/h per C and more)
    document = json.loads(path.read_text())
    del document["outside_range"]
    assert modelfile.from_document(document).predict(hot)[0][0] == pytest.approx(at_edge[0])  # without it: the clamp


def dataclass_options():
    from fogd.calibration.models import FitOptions

    return FitOptions(particles=4, iterations=3, progress=False, search=False)


@pytest.mark.parametrize(
    "change, message",
    [
        ({"policy": "extrapolate"}, "outside_range.policy"),
        ({"policy": "trend"}, "needs coef and intercept"),
        ({"policy": "clamp", "coef": [0.0, 0.0], "intercept": 0.0}, "needs coef and intercept"),
        ({"policy": "linear", "coef": [1.0], "intercept": 0.0}, "outside_range.coef"),
        ({"policy": "trend", "coef": [1.0, float("inf")], "intercept": 0.0}, "outside_range.coef"),
        ({"policy": "edge", "slope": 1}, "unknown key"),
        ({"policy": "trend", "coef": [1e12, 0.0], "intercept": 0.0}, "inside its own domain"),
    ],
)
def test_a_bad_outside_range_is_refused_in_one_line(change, message):
    document = linear_document()
    document["outside_range"] = change
    with pytest.raises(FogdError) as caught:
        modelfile.from_document(document)
    assert message in str(caught.value) and "\n" not in str(caught.value)


def linear_document() -> dict:
    return modelfile.document(
        name="t", method="linear", inputs=parse_inputs("temp,rate@50"), x_mean=np.zeros(2), x_scale=np.ones(2),
        y_mean=0.0, y_scale=1.0, domain_min=np.array([10.0, -0.01]), domain_max=np.array([20.0, 0.01]),
        params={"coef": [0.01, 1.0], "intercept": 0.0}, reference_dph=0.0, training={}, metrics={}, created_utc="x",
    )  # fmt: skip


def test_the_daemon_serves_the_files_policy_as_fogd_replay_does(tmp_path):
    """The real daemon on a pty, a ramp from 20 to 26 C through a model calibrated on 20-22 C: what it writes
    equals fogd-replay, the samples beyond 22 C are CLAMPED and continued along the stored slope."""
    from test_daemon_e2e import assert_same_as_replay, replayed, run_samples, stream_through_fogd
    from test_hardening import model_document

    trend = {"policy": "trend", "coef": [0.2, 0.0], "intercept": 0.0}
    document = model_document(name="e2e-trend", domain={"min": [20.0, -5.0], "max": [22.0, 5.0]}, outside_range=trend)
    path = tmp_path / "model.json"
    modelfile.save(path, document)
    samples = run_samples("fogd")
    out, _, _ = stream_through_fogd(tmp_path, path, samples, "fogd")
    written = np.loadtxt(out, delimiter=",", skiprows=1, ndmin=2)
    assert_same_as_replay(written, replayed(tmp_path, path, samples))
    del document["outside_range"]
    clamp_path = tmp_path / "clamp.json"
    modelfile.save(clamp_path, document)
    (tmp_path / "clamp").mkdir()
    clamped = replayed(tmp_path / "clamp", clamp_path, samples)
    temp, comp, flags = written[:, 2], written[:, 4], written[:, 6].astype(int)
    beyond = temp > 22.0
    assert beyond.any() and ((flags[beyond] & Flag.CLAMPED) != 0).all()
    np.testing.assert_allclose(comp[beyond], clamped[beyond, 4] + 0.2 * (temp[beyond] - 22.0), rtol=1e-9)
