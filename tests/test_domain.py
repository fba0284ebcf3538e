"""The domain guard (joint and range): distances, margins, model-file round trip, fallback and flags in the compensator
and in training."""

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fogd.core import modelfile
from fogd.core.compensator import Compensator
from fogd.core.domain import (
    MIN_RANGE_MARGIN,
    DomainGuard,
    choose_range_margin,
    choose_threshold,
    nearest_distance,
    range_box,
    thin,
)
from fogd.core.estimator import EstimatorSettings
from fogd.core.flags import Flag
from fogd.core.inputs import default_inputs
from fogd.errors import ModelFileError

RATE_HZ = 10.0
INPUTS = default_inputs(EstimatorSettings(5.0, 0.5))


def test_nearest_distance_and_threshold():
    points = np.array([[0.0, 0.0], [1.0, 0.0], [3.0, 0.0]])
    np.testing.assert_allclose(nearest_distance(np.array([[0.0, 2.0], [2.9, 0.0]]), points), [2.0, 0.1])
    assert choose_threshold(points) == pytest.approx(2.0 * 2.0)  # twice the largest neighbour gap
    samples = np.array([[0.0, 0.5]] * 999 + [[0.0, 9.0]])  # one outlier sample does not set it
    assert choose_threshold(points, samples, factor=1.0) == pytest.approx(2.0)
    assert len(thin(np.arange(2000.0).reshape(-1, 2), 100)) == 100


def guarded_document(threshold: float = 0.5) -> dict:
    """Main model: 0.01 T + 1000 * rate (a wild slope); fallback: 0.01 T; calibration near T 0..10, rate 0."""
    points = [[t, 0.0] for t in np.linspace(0.0, 10.0, 21)]
    return {
        "format": "fogd-model", "version": 1, "name": "guarded", "method": "linear",
        "inputs": [spec.to_dict() for spec in INPUTS],
        "input_scaling": {"mean": [0.0, 0.0], "scale": [1.0, 0.001]},
        "output_scaling": {"mean": 0.0, "scale": 1.0},
        "domain": {"min": [-50.0, -1.0], "max": [80.0, 1.0]},
        "params": {"coef": [0.01, 1.0], "intercept": 0.0},
        "reference_dph": 0.0, "training": {}, "metrics": {}, "created_utc": "2026-01-01T00:00:00+00:00",
        "fogd_version": "0",
        "domain_guard": {"points": points, "threshold": threshold,
                         "fallback": {"method": "linear", "params": {"coef": [0.01, 0.0], "intercept": 0.0}}},
    }  # fmt: skip


def test_far_samples_are_flagged_and_use_the_fallback(tmp_path):
    path = tmp_path / "m.json"
    modelfile.save(path, guarded_document())
    model = modelfile.load(path)
    steady = np.full(200, 5.0)
    ramp = 5.0 + 0.01 * np.arange(200) / RATE_HZ  # 0.01 C/s = 10 scaled units of rate: far from calibration
    out = Compensator(model, RATE_HZ).process(np.zeros(400), np.r_[steady, ramp])
    far = (out.flags & Flag.OUT_OF_DOMAIN) != 0
    warm = (out.flags & Flag.WARMUP) == 0
    assert not far[:200].any() and far[260:].all()
    assert not (far & ~warm).any()
    temps = np.r_[steady, ramp]
    np.testing.assert_allclose(out.comp_dph[far], 0.01 * temps[far], rtol=0, atol=1e-12)
    inside = warm & ~far
    np.testing.assert_allclose(out.comp_dph[inside], 0.01 * temps[inside] + 1000 * out.temp_rate_cps[inside], atol=1e-9)


def test_guarded_compensation_does_not_depend_on_chunking(tmp_path):
    path = tmp_path / "m.json"
    modelfile.save(path, guarded_document())
    model = modelfile.load(path)
    temps = 5.0 + np.cumsum(np.random.default_rng(2).choice([-0.0625, 0, 0.0625], 600))
    whole = Compensator(model, RATE_HZ).process(np.zeros(600), temps)
    one = Compensator(model, RATE_HZ)
    parts = [one.process(np.zeros(1), temps[i : i + 1]) for i in range(600)]
    assert np.array_equal(np.concatenate([p.comp_dph for p in parts]), whole.comp_dph)
    assert np.array_equal(np.concatenate([p.flags for p in parts]), whole.flags)
    assert ((whole.flags & Flag.OUT_OF_DOMAIN) != 0).any()


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda g: g.update(threshold=-1), "positive"),
        (lambda g: g.update(points=[[1.0]]), "points"),
        (lambda g: g["fallback"].update(method="pso-svr"), "fallback is 'linear'"),
        (lambda g: g.update(extra=1), "unknown key"),
        (lambda g: g["fallback"]["params"].update(coef=[1.0]), "coef"),
    ],
)
def test_bad_guard_is_refused_in_one_line(tmp_path, change, message):
    doc = guarded_document()
    change(doc["domain_guard"])
    path = tmp_path / "m.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(ModelFileError, match=message):
        modelfile.load(path)


def test_old_model_files_without_a_guard_still_load():
    model = modelfile.load("fogd/data/demo-model.json")
    assert "domain_guard" not in model.meta


def test_range_guard_flags_rows_beyond_the_margin_and_temperatures_share_one_range():
    points = np.array([[0.0, 0.0, -1.0], [1.0, 0.5, 1.0]])  # scaled units; columns 0 and 1 are temperatures
    x_mean, x_scale = np.array([10.0, 10.0, 0.0]), np.array([2.0, 2.0, 1.0])
    low, high = range_box(points, x_mean, x_scale, (0, 1))
    np.testing.assert_allclose(low, [0.0, 0.0, -1.0])
    np.testing.assert_allclose(high, [1.0, 1.0, 1.0])  # the slow column's range widened to the sensor's
    guard = DomainGuard(points, 0.25, x_mean, x_scale, fallback=None, kind="range", shared=(0, 1))
    raw = np.array([
        [12.0, 11.9, 0.0],   # inside: column 1 beyond its own blocks (11.0) but within the temperatures' range
        [12.4, 12.0, 0.0],   # 0.2 scaled units beyond: within the margin
        [12.6, 12.0, 0.0],   # 0.3 beyond: outside
        [10.0, 10.0, -1.3],  # the third input 0.3 below its range: outside
        [np.nan, 10.0, 0.0],  # NaN: outside
    ])  # fmt: skip
    assert guard.outside(raw).tolist() == [False, False, True, True, True]
    assert DomainGuard(points, 0.25, x_mean, x_scale, None, "range").outside(raw[:1]).tolist() == [True]


def test_range_margin_covers_the_samples_and_has_a_floor():
    low, high = np.zeros(2), np.ones(2)
    samples = np.array([[0.5, 1.2]] * 1999 + [[0.5, 9.0]])  # one outlier sample does not set it
    assert choose_range_margin(low, high, samples, factor=2.0) == pytest.approx(0.4)
    assert choose_range_margin(low, high, np.full((10, 2), 0.5)) == MIN_RANGE_MARGIN


def test_range_guard_round_trips_through_the_model_file(tmp_path):
    doc = guarded_document(threshold=0.5)
    doc["domain_guard"]["kind"] = "range"
    path = tmp_path / "m.json"
    modelfile.save(path, doc)
    guard = modelfile.load(path).meta["domain_guard"]
    assert guard.kind == "range" and guard.shared == (0,)  # the paper's inputs: temp is the one temperature
    # calibration T 0..10, rate 0 (scaled); margin 0.5 scaled units: 0.5 C of temperature, 0.0005 C/s of rate
    rows = np.array([[10.4, 0.0], [10.6, 0.0], [5.0, 0.0004], [5.0, -0.0006]])
    assert guard.outside(rows).tolist() == [False, True, False, True]
    doc["domain_guard"]["kind"] = "box"
    path.write_text(json.dumps(doc))
    with pytest.raises(ModelFileError, match=r"domain_guard\.kind.*joint, range"):
        modelfile.load(path)


def _chamber_run(name: str, temp_c: np.ndarray, seed: int):
    from fogd.core.runio import Run

    t_s = np.arange(temp_c.size) / 1.0
    rate = 0.01 * temp_c + np.random.default_rng(seed).normal(0.0, 0.01, temp_c.size)
    return Run(f"{name}.csv", t_s, rate, temp_c, 1.0, str(seed), {})


def test_training_guards_a_lag_bank_by_range_and_serves_every_history_inside_it():
    """Calibrated 0..40 C by a heating and a cooling ramp; a held-out cycle and soak inside that range (a
    history no calibration run had) is never sent to the fallback, a run that goes to 60 C is."""
    from fogd.calibration.models import FitOptions
    from fogd.calibration.training import TrainConfig, train
    from fogd.core.inputs import parse_inputs

    ramp = np.r_[np.full(600, 0.0), np.linspace(0.0, 40.0, 6000), np.full(1200, 40.0)]
    runs = [_chamber_run("heat", ramp, 1), _chamber_run("cool", ramp[::-1].copy(), 2)]
    config = TrainConfig(method="linear", inputs=parse_inputs("temp,lags@100..1000/3"), block_s=50.0,
                         fit=FitOptions(progress=False), domain_guard=True)  # fmt: skip
    model = train(runs, config).model
    guard = model.meta["domain_guard"]
    assert guard.kind == "range"
    t = np.arange(8000.0)
    inside = 20.0 + 15.0 * np.sin(t / 300.0) * (t < 5000) + 15.0 * (t >= 5000)  # fast cycles, then a soak at 35 C
    hot = np.minimum(20.0 + t / 100.0, 60.0)
    for temps, expect_outside in ((inside, False), (hot, True)):
        out = Compensator(model, 1.0).process(np.zeros(t.size), temps)
        assert ((out.flags & Flag.OUT_OF_DOMAIN) != 0).any() == expect_outside


def test_training_keeps_the_joint_guard_for_the_papers_inputs():
    from fogd.calibration.models import FitOptions
    from fogd.calibration.training import TrainConfig, train
    from fogd.core.inputs import parse_inputs

    ramp = np.r_[np.full(600, 0.0), np.linspace(0.0, 40.0, 6000), np.full(1200, 40.0)]
    runs = [_chamber_run("heat", ramp, 1), _chamber_run("cool", ramp[::-1].copy(), 2)]
    config = TrainConfig(method="linear", inputs=parse_inputs("temp,rate@50"), block_s=50.0,
                         fit=FitOptions(progress=False), domain_guard=True)  # fmt: skip
    assert train(runs, config).model.meta["domain_guard"].kind == "joint"


@settings(max_examples=60, deadline=None)
@given(
    kind=st.sampled_from(["range", "joint"]),
    seed=st.integers(0, 2**16),
    threshold=st.floats(0.01, 2.0),
    special=st.lists(st.sampled_from([math.nan, math.inf, -math.inf]), max_size=2),
)
def test_outside_one_answers_as_outside_does(kind, seed, threshold, special):
    """The row path's `outside_one` (Python floats for a range guard) gives `outside`'s answer for every row:
    inside, just beyond the margin in either direction, far out, NaN and infinite inputs."""
    rng = np.random.default_rng(seed)
    columns = int(rng.integers(2, 6))
    points = rng.normal(0.0, 1.0, (int(rng.integers(1, 30)), columns))
    x_mean, x_scale = rng.normal(20.0, 5.0, columns), rng.uniform(0.001, 10.0, columns)
    shared = tuple(sorted(set(rng.integers(0, columns, 2).tolist()))) if kind == "range" else ()
    guard = DomainGuard(points, threshold, x_mean, x_scale, fallback=None, kind=kind, shared=shared)
    low, high = range_box(points, x_mean, x_scale, shared) if kind == "range" else (points.min(axis=0), points.max(axis=0))
    scaled = rng.uniform(low - 2 * threshold, high + 2 * threshold, (200, columns))
    edge = rng.integers(0, columns, 100)
    scaled[np.arange(100), edge] = np.where(rng.random(100) < 0.5, low[edge] - threshold, high[edge] + threshold)
    scaled[100:130] = points[rng.integers(0, len(points), 30)] + rng.normal(0.0, threshold / 8, (30, columns))
    scaled[130:140] = high + 1.0 + 3 * threshold  # far beyond every point and the box in every column
    raw = scaled * x_scale + x_mean
    for row, value in enumerate(special):
        raw[row, row % columns] = value
    want = guard.outside(raw).tolist()
    assert [guard.outside_one(tuple(row)) for row in raw.tolist()] == want
    assert True in want and False in want
