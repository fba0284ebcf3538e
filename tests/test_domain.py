"""The joint-space domain guard: distances, threshold, model-file round trip, fallback and flags in the compensator."""

import json

import numpy as np
import pytest

from fogd.core import modelfile
from fogd.core.compensator import Compensator
from fogd.core.domain import choose_threshold, nearest_distance, thin
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
