"""fogd.core.straightline: a frozen model's row written out gives the very floats and flags of predict_one's loop,
bit for bit, on every evaluator it writes out (clamped rows, the lag bank's moving clamp, NaN, -0.0, the
outside-range policy); its source names nothing but its own locals and `exp`; what it cannot write out is left
to the loop."""

from __future__ import annotations

import io
import math
import tokenize

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fogd.core import straightline
from fogd.core.frozen import FrozenModel, Linear, Polynomial, RbfNetwork, Svr
from fogd.core.inputs import parse_inputs
from fogd.core.outside_range import OutsideRange

INPUTS = {1: "temp", 2: "temp,rate@50", 4: "temp,lags@30..3000/3", 6: "temp,lags@30..3000/4,play@2"}


def evaluator(kind: str, d: int, rng: np.random.Generator, centres: int, read: tuple[int, ...] | None, mix: bool):
    if kind == "linear":
        return Linear(rng.normal(size=d), float(rng.normal()))
    if kind == "ls-poly":
        powers = rng.integers(0, 4, size=(7, d))
        powers[0] = 0  # a constant monomial: no factor at all
        return Polynomial(powers, rng.normal(size=7), float(rng.normal()))
    if kind == "rbf-nn":
        return RbfNetwork(rng.normal(size=(centres, d)), 0.3 + rng.random(), rng.normal(size=centres), float(rng.normal()))
    columns = d if read is None else len(read)
    if mix:  # fogd-train's default: each input, then q ** 2 and q ** 3 of q = mix . x
        powers = np.vstack([np.eye(d, d + 1, dtype=np.int64), [[0] * d + [2], [0] * d + [3]]])
        return Svr(rng.normal(size=(centres, columns)), rng.normal(size=centres) * 50, 0.05 + rng.random(),
                   rng.normal(size=d + 2), float(rng.normal()), powers, read, rng.dirichlet(np.ones(d)))  # fmt: skip
    return Svr(rng.normal(size=(centres, columns)), rng.normal(size=centres) * 50, 0.05 + rng.random(),
               rng.normal(size=d), float(rng.normal()), None, read)  # fmt: skip


def frozen_model(ev, d: int, policy: str, rng: np.random.Generator) -> FrozenModel:
    outside = None if policy == "clamp" else OutsideRange(policy, rng.normal(size=d), float(rng.normal()))
    return FrozenModel(method="test", inputs=parse_inputs(INPUTS[d]), x_mean=np.full(d, 20.0) + rng.normal(size=d),
                       x_scale=np.full(d, 15.0) * (1 + rng.random(d)), y_mean=float(rng.normal()),
                       y_scale=float(0.01 + rng.random()), domain_min=np.full(d, -10.0), domain_max=np.full(d, 50.0),
                       evaluator=ev, outside=outside)  # fmt: skip


def the_loop(model: FrozenModel) -> FrozenModel:
    """The same model served by predict_one's loop (its plan without the written-out row)."""
    twin = FrozenModel(**{name: getattr(model, name) for name in model.__dataclass_fields__})
    assert straightline.written_out(model._one_plan()), "the model under test has a straight-line row"
    assert not straightline.written_out(twin._one_plan(straight=False))
    return twin


@settings(max_examples=80, deadline=None)
@given(
    kind=st.sampled_from(["linear", "ls-poly", "rbf-nn", "svr"]),
    d=st.sampled_from(sorted(INPUTS)),
    centres=st.integers(0, 6),
    read_first=st.booleans(),
    mix=st.booleans(),
    policy=st.sampled_from(["clamp", "trend", "linear"]),
    seed=st.integers(0, 2**32 - 1),
)
def test_the_row_written_out_is_the_loop_bit_for_bit(kind, d, centres, read_first, mix, policy, seed):
    rng = np.random.default_rng(seed)
    read = (0,) if read_first and kind == "svr" else None
    centres = max(centres, 1) if kind == "rbf-nn" else centres
    model = frozen_model(evaluator(kind, d, rng, centres, read, mix and kind == "svr"), d, policy, rng)
    loop = the_loop(model)
    rows = rng.uniform(-20.0, 60.0, (200, d))  # some beyond the domain: clamped, the lag bank moved together
    rows[:20] = rng.uniform(-9.0, 49.0, (20, d))  # inside
    rows[20] = np.nan
    rows[21, 0] = -0.0
    rows[22] = rows[23]  # a repeat (predict_one's memo)
    for row in rows.tolist():
        got, want = model.predict_one(row), loop.predict_one(row)
        assert got[1] == want[1]
        assert np.array([got[0]]).tobytes() == np.array([want[0]]).tobytes(), (row, got, want)


def test_the_default_trained_form_is_written_out_and_names_only_its_own_locals():
    """fogd-train's default (a lag bank, a kernel on the temperature, the coil trend over q): written out, and
    its source's names are its arguments, temporaries and `exp`, nothing a model's numbers could make."""
    rng = np.random.default_rng(5)
    model = frozen_model(evaluator("svr", 6, rng, 5, (0,), True), 6, "trend", rng)
    columns, first = model.row_columns()
    source = straightline.row_source(model.evaluator, columns, first, model.y_mean, model.y_scale, True)
    names = {token.string for token in tokenize.generate_tokens(io.StringIO(source).readline) if token.type == tokenize.NAME}
    allowed = {"def", "row", "x", "if", "else", "return", "or", "True", "exp", "shift", "clamped", "kernel", "trend",
               "q", "value"}  # fmt: skip
    assert {name for name in names if not name[0] in "xuvd" or not name[1:].lstrip("x").isdigit()} <= allowed
    assert straightline.written_out(model._one_plan())


@pytest.mark.parametrize("bad", [math.inf, -math.inf, math.nan])
def test_a_non_finite_constant_is_left_to_the_loop(bad):
    rng = np.random.default_rng(1)
    model = frozen_model(Linear(np.array([bad, 1.0]), 0.0), 2, "clamp", rng)
    assert not straightline.written_out(model._one_plan())
    assert model.predict_one([20.0, 0.001])[1] is False


def test_a_kernel_large_enough_for_numpy_and_a_huge_trend_are_left_to_the_loop():
    rng = np.random.default_rng(2)
    large = Svr(rng.normal(size=(300, 2)), rng.normal(size=300), 0.5, rng.normal(size=2), 0.0)
    huge = Polynomial(rng.integers(0, 3, size=(straightline.MAX_TERMS + 1, 2)), rng.normal(size=straightline.MAX_TERMS + 1), 0.0)
    small = Polynomial(rng.integers(0, 3, size=(5, 2)), rng.normal(size=5), 0.0)
    for ev, written in ((large, False), (huge, False), (small, True)):
        model = frozen_model(ev, 2, "clamp", rng)
        assert straightline.written_out(model._one_plan()) == written
        value, _ = model.predict_one([20.0, 0.001])
        assert value == pytest.approx(float(model.predict(np.array([[20.0, 0.001]]))[0][0]), rel=1e-12)
