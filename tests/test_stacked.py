"""StackedModels: several channels' models evaluated in one numpy pass give each model's own `predict` (within
1e-12, the sums in another order) and its clamp flags exactly; one row gives the floats of many, bit for bit,
whatever the blocks and the distinct-row reuse."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fogd.core import frozen
from fogd.core.frozen import (
    FrozenModel,
    Linear,
    Polynomial,
    RbfNetwork,
    StackedModels,
    Svr,
)
from fogd.core.inputs import parse_inputs

INPUTS = {"paper": parse_inputs("temp,rate@5"), "lag bank": parse_inputs("temp,lags@30..3000/5")}
METHODS = ("linear", "ls-poly", "rbf-nn", "svr", "svr-coil", "svr-trend-only", "svr-some-inputs", "svr-mix")


def random_model(rng: np.random.Generator, method: str, inputs: str) -> FrozenModel:
    specs = INPUTS[inputs]
    d = len(specs)
    powers = rng.integers(0, 4, size=(int(rng.integers(1, 20)), d))
    centres = int(rng.integers(1, 60))
    read = tuple(sorted(rng.choice(d, size=int(rng.integers(1, d + 1)), replace=False).tolist()))  # a kernel's inputs
    evaluator = {
        "linear": lambda: Linear(rng.normal(size=d), float(rng.normal())),
        "ls-poly": lambda: Polynomial(powers, rng.normal(size=len(powers)) * 10, float(rng.normal())),
        "rbf-nn": lambda: RbfNetwork(rng.normal(size=(centres, d)), float(rng.uniform(0.3, 3)), rng.normal(size=centres), 0.05),
        "svr": lambda: Svr(rng.normal(size=(centres, d)), rng.normal(size=centres) * 50, float(rng.uniform(1e-4, 2)),
                           rng.normal(size=d), float(rng.normal())),
        "svr-coil": lambda: Svr(rng.normal(size=(centres, d)), rng.normal(size=centres) * 50, float(rng.uniform(1e-4, 2)),
                                rng.normal(size=len(powers)) * 100, float(rng.normal()), powers),
        "svr-trend-only": lambda: Svr(np.zeros((0, d)), np.zeros(0), 0.5, rng.normal(size=len(powers)), 0.2, powers),
        "svr-some-inputs": lambda: Svr(rng.normal(size=(centres, len(read))), rng.normal(size=centres) * 50,
                                       float(rng.uniform(1e-4, 2)), rng.normal(size=len(powers)) * 100,
                                       float(rng.normal()), powers, read),
        # as fogd-train writes its default: the kernel on the temperature, the trend over the inputs and q
        "svr-mix": lambda: Svr(rng.normal(size=(centres, 1)), rng.normal(size=centres) * 50, float(rng.uniform(1e-4, 2)),
                               rng.normal(size=d + 2) * 100, float(rng.normal()), mix_powers(d), (0,),
                               rng.dirichlet(np.ones(d))),
    }[method]()  # fmt: skip
    low = 20.0 + rng.uniform(-15, -5, d)
    return FrozenModel(
        method=method, inputs=specs, x_mean=20.0 + rng.normal(size=d), x_scale=rng.uniform(2, 15, d),
        y_mean=float(rng.normal()), y_scale=float(rng.uniform(0.01, 1)), domain_min=low, domain_max=low + rng.uniform(10, 30, d),
        evaluator=evaluator,
    )  # fmt: skip


def mix_powers(d: int) -> np.ndarray:
    """The coil trend's monomials over d inputs and q: each input, then q ** 2 and q ** 3."""
    return np.vstack((np.eye(d, d + 1, dtype=np.int64), [[0] * d + [2], [0] * d + [3]]))


def input_rows(rng: np.random.Generator, d: int, n: int) -> np.ndarray:
    """Rows around the domains (some clamped), with repeats, as a lag bank's or eq. 16's inputs come."""
    x = 20.0 + rng.normal(0, 12, (n, d))
    x[: n // 4] = x[n // 4]  # repeats: the distinct-row reuse
    x[n // 2 :, 0] = rng.choice(x[n // 2 :, 0], 3)[rng.integers(0, 3, n - n // 2)]  # a quantised temperature beside
    return x  # lags that differ: a kernel on the temperature alone sees few distinct rows


@st.composite
def stacks(draw) -> tuple[list[FrozenModel], np.ndarray]:
    inputs = draw(st.sampled_from(sorted(INPUTS)))
    methods = draw(st.lists(st.sampled_from(METHODS), min_size=1, max_size=6))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    models = [random_model(rng, method, inputs) for method in methods]
    # an IMU's channels trained on the same runs share their inputs' domain and scaling: some share the first's
    shares = draw(st.lists(st.booleans(), min_size=len(models), max_size=len(models)))
    first = models[0]
    models = [replace(model, x_mean=first.x_mean, x_scale=first.x_scale, domain_min=first.domain_min,
                      domain_max=first.domain_max) if share else model for model, share in zip(models, shares)]  # fmt: skip
    return models, input_rows(rng, len(INPUTS[inputs]), draw(st.integers(1, 300)))


@settings(max_examples=80, deadline=None)
@given(case=stacks())
def test_every_column_is_its_models_predict(case):
    models, x = case
    comp, clamped = StackedModels(models).predict(x)
    assert comp.shape == clamped.shape == (len(x), len(models))
    for column, model in enumerate(models):
        want, want_clamped = model.predict(x)
        np.testing.assert_array_equal(clamped[:, column], want_clamped)
        np.testing.assert_allclose(comp[:, column], want, rtol=1e-12, atol=1e-12 * np.max(np.abs(want)),
                                   err_msg=model.method)  # fmt: skip


@settings(max_examples=60, deadline=None)
@given(case=stacks(), cuts=st.lists(st.integers(1, 300), max_size=6), block=st.integers(1, 2000))
def test_one_row_gives_the_floats_of_many(case, cuts, block):
    """What makes the channel compensator's streaming equal its batch bit for bit: a row's result depends on
    that row alone, whatever came with it (blocks, distinct-row reuse, predict_one)."""
    models, x = case
    stacked = StackedModels(models)
    comp, clamped = stacked.predict(x)
    pieces, start = [], 0
    for size in [*cuts, len(x)]:
        pieces.append(stacked.predict(x[start : start + size])[0])
        start += size
    assert np.concatenate(pieces)[: len(x)].tobytes() == comp.tobytes()
    one = [stacked.predict_one(row) for row in x.tolist()]
    assert np.array([values for values, _ in one]).tobytes() == comp.tobytes()
    assert [flags for _, flags in one] == clamped.tolist()
    saved = frozen._STACK_ELEMENTS
    frozen._STACK_ELEMENTS = block  # small blocks
    try:
        assert StackedModels(models).predict(x)[0].tobytes() == comp.tobytes()
    finally:
        frozen._STACK_ELEMENTS = saved


def test_nan_rows_count_as_clamped_and_are_not_remembered():
    rng = np.random.default_rng(4)
    models = [random_model(rng, method, "paper") for method in ("linear", "svr")]
    stacked = StackedModels(models)
    row = (float("nan"), 0.0)
    assert stacked.predict_one(row)[1] == [True, True]
    assert stacked._last is None
    want = [model.predict(np.array([row]))[0][0] for model in models]
    assert np.all(np.isnan(stacked.predict_one(row)[0])) == np.all(np.isnan(want))


def test_only_method_evaluators_on_the_same_inputs_stack():
    rng = np.random.default_rng(1)
    plain = random_model(rng, "linear", "paper")
    plain = replace(plain, evaluator=lambda xs: xs.sum(axis=1))
    assert not StackedModels.supports(plain)
    with pytest.raises(ValueError):
        StackedModels([random_model(rng, "linear", "paper"), plain])
    with pytest.raises(ValueError):
        StackedModels([random_model(rng, "linear", "paper"), random_model(rng, "linear", "lag bank")])
