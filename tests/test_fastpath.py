"""The fast paths give the very results of the paths they stand in for: the scalar estimator update (bit for
bit), the per-point model evaluation (to 1e-12), the compensator's one-sample chunks (flags and inputs bit for
bit, compensation to 1e-12), the distinct-row reuse and the column-wise kernel sums in batch evaluation (bit
for bit), and the CSV reader (bit for bit against numpy's)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fogd.core import frozen
from fogd.core.compensator import Compensator
from fogd.core.estimator import EstimatorSettings, TempRateEstimator, temp_rate_batch
from fogd.core.flags import Flag
from fogd.core.frozen import (
    FrozenModel,
    Linear,
    Polynomial,
    RbfNetwork,
    Svr,
    unique_rows,
)
from fogd.core.inputs import clamp_rows, default_inputs, parse_inputs, shifted_columns
from fogd.core.runio import read_run


def chamber_temps(n: int, seed: int) -> np.ndarray:
    """Quantised (0.0625 C) sensor readings held for several samples, like the simulator's."""
    rng = np.random.default_rng(seed)
    drift = 20 + np.cumsum(rng.normal(0.0, 0.02, n // 5 + 1))
    return np.round(np.repeat(drift, 5)[:n] / 0.0625) * 0.0625


# -- the scalar estimator update ------------------------------------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(
    temps=st.lists(st.floats(-100, 200, allow_nan=False), min_size=1, max_size=200),
    window=st.integers(2, 40),
    average=st.integers(1, 10),
    step=st.integers(1, 7),
    chunks=st.lists(st.integers(0, 30), max_size=10),
)
def test_update_one_is_bit_identical_to_update_and_batch(temps, window, average, step, chunks):
    rate_hz = 10.0
    average = min(average, window // 2) or 1
    spec = EstimatorSettings(window / rate_hz, average / rate_hz, step / rate_hz if step > 1 else 0.0)
    temp_c = np.array(temps)
    one = TempRateEstimator(spec, rate_hz)
    scalar = np.array([one.update_one(value) for value in temp_c.tolist()])
    assert scalar.tobytes() == temp_rate_batch(temp_c, spec, rate_hz).tobytes()
    # mixed: chunks through update, single samples through update_one, on one estimator
    mixed, pieces, start = TempRateEstimator(spec, rate_hz), [], 0
    for size in chunks:
        pieces.append(mixed.update(temp_c[start : start + size]))
        start += size
        if start < temp_c.size:
            pieces.append(np.array([mixed.update_one(float(temp_c[start]))]))
            start += 1
    pieces.append(mixed.update(temp_c[start:]))
    assert np.concatenate(pieces).tobytes() == scalar.tobytes()


def test_update_one_after_wraparound_and_reset():
    spec = EstimatorSettings(window_s=2.0, average_s=0.5)
    temp_c = chamber_temps(5000, 1)
    batch = temp_rate_batch(temp_c, spec, 20.0)
    estimator = TempRateEstimator(spec, 20.0)
    estimator.update_one(21.0)
    estimator.reset()
    estimator._ring[:] = estimator._last_prefix[0] = np.iinfo(np.int64).max - 5  # prefix sums wrap at once
    got = np.array([estimator.update_one(value) for value in temp_c.tolist()])
    assert got.tobytes() == batch.tobytes()


# -- per-point model evaluation --------------------------------------------------------------------------------


def model(evaluator, d: int = 2) -> FrozenModel:
    return FrozenModel(
        method="test", inputs=default_inputs()[:d], x_mean=np.array([20.0, 0.001])[:d], x_scale=np.array([15.0, 0.004])[:d],
        y_mean=0.3, y_scale=0.08, domain_min=np.array([-10.0, -0.01])[:d], domain_max=np.array([50.0, 0.01])[:d],
        evaluator=evaluator,
    )  # fmt: skip


def evaluators(rng: np.random.Generator) -> dict[str, object]:
    powers = np.array([(i, j) for total in range(1, 6) for i in range(total, -1, -1) for j in [total - i]])
    return {
        "linear": Linear(rng.normal(size=2), 0.1),
        "ls-poly": Polynomial(powers, rng.normal(size=len(powers)), -0.2),
        "rbf-nn": RbfNetwork(rng.normal(size=(12, 2)), 0.7, rng.normal(size=12), 0.05),
        "svr-small": Svr(rng.normal(size=(8, 2)), rng.normal(size=8) * 50, 0.3, rng.normal(size=2), 0.4),
        "svr-large": Svr(rng.normal(size=(300, 2)), rng.normal(size=300) * 50, 2.0, np.zeros(2), -0.4),
        "svr-none": Svr(np.zeros((0, 2)), np.zeros(0), 0.5, np.array([0.3, -0.1]), 0.0),
    }


@pytest.mark.parametrize("name", ["linear", "ls-poly", "rbf-nn", "svr-small", "svr-large", "svr-none"])
def test_predict_one_equals_predict(name):
    rng = np.random.default_rng(3)
    frozen_model = model(evaluators(rng)[name])
    x = np.column_stack((rng.uniform(-20, 60, 500), rng.uniform(-0.02, 0.02, 500)))  # some rows clamped
    x[:50] = x[50]  # repeats (the memo)
    x[60] = [np.nan, 0.0]
    x[61] = [-0.0, 0.0]
    want, want_clamped = frozen_model.predict(x)
    got = [frozen_model.predict_one(row) for row in x.tolist()]
    values = np.array([value for value, _ in got])
    np.testing.assert_allclose(values, want, rtol=1e-12, atol=1e-12 * np.max(np.abs(want[np.isfinite(want)])), equal_nan=True)
    assert [flag for _, flag in got] == want_clamped.tolist()


@pytest.mark.parametrize("trend", ["short", "long", "mix"])  # a few monomials, more than POINT_TREND_TERMS, over q
@pytest.mark.parametrize("read", [None, (0,), (0, 2, 5)])  # the kernel's inputs: every one, or some
@pytest.mark.parametrize("centres", [5, 40, 400])  # a Python loop over few centres, numpy over many
def test_predict_one_equals_predict_with_a_lag_bank_and_a_coil_trend(centres, read, trend):
    """Six inputs (temp and five lags): the trend's monomials with zero and unit powers skipped, the kernel sum
    over the whole (centres, inputs) difference at once; a large kernel with a long trend goes through the stack."""
    rng = np.random.default_rng(8)
    specs = parse_inputs("temp,lags@30..3000/5")
    extra = {"short": 9, "long": frozen.POINT_TREND_TERMS, "mix": 0}[trend]
    powers = np.vstack([np.eye(6, dtype=np.int64), rng.integers(0, 3, size=(extra, 6))])
    mix = None
    if trend == "mix":  # as fogd-train writes its default: each input, then q ** 2 and q ** 3
        powers = np.vstack([np.eye(6, 7, dtype=np.int64), [[0] * 6 + [2], [0] * 6 + [3]]])
        mix = rng.dirichlet(np.ones(6))
    evaluator = Svr(rng.normal(size=(centres, 6 if read is None else len(read))), rng.normal(size=centres) * 50, 0.05,
                    rng.normal(size=len(powers)), 0.4, powers, read, mix)  # fmt: skip
    frozen_model = FrozenModel(method="pso-svr", inputs=specs, x_mean=np.full(6, 20.0), x_scale=np.full(6, 15.0),
                               y_mean=0.3, y_scale=0.08, domain_min=np.full(6, -10.0), domain_max=np.full(6, 50.0),
                               evaluator=evaluator)  # fmt: skip
    x = rng.uniform(-20.0, 60.0, (300, 6))  # some rows clamped
    want, want_clamped = frozen_model.predict(x)
    got = [frozen_model.predict_one(row) for row in x.tolist()]
    values = np.array([value for value, _ in got])
    np.testing.assert_allclose(values, want, rtol=1e-12, atol=1e-12 * np.max(np.abs(want)))
    assert [flag for _, flag in got] == want_clamped.tolist()
    large_kernel = centres * (6 if read is None else len(read)) > frozen.POINT_NUMPY_WORK
    assert bool(frozen_model.__dict__["_rows"]) == (large_kernel and trend == "long")


def test_a_kernel_on_some_inputs_evaluated_once_per_distinct_row_is_bit_identical():
    """A kernel on the temperature alone: rows whose temperature repeats while the lags differ share one kernel
    sum, the very floats each row gives alone."""
    rng = np.random.default_rng(21)
    evaluator = Svr(rng.normal(size=(60, 1)), rng.normal(size=60), 0.4, rng.normal(size=4), 0.1, None, (0,))
    xs = rng.normal(size=(500, 4))
    xs[:, 0] = np.round(xs[:, 0] * 4) / 4  # a quantised temperature: a dozen distinct values
    want = np.concatenate([evaluator(xs[i : i + 1]) for i in range(len(xs))])
    assert evaluator(xs).tobytes() == want.tobytes()


def test_a_large_kernel_reuses_its_previous_sum_only_for_the_same_inputs():
    """One row at a time, a kernel on the temperature alone: consecutive rows with the same temperature and other
    lags reuse the kernel's sum, the very float a fresh evaluator gives; NaN is never reused."""
    rng = np.random.default_rng(22)
    centres, weights = rng.normal(size=(200, 1)), rng.normal(size=200)

    def make() -> Svr:
        return Svr(centres, weights, 0.4, np.array([0.3, -0.2, 0.1]), 0.1, None, (0,))

    served = make()
    rows = rng.normal(size=(300, 3))
    rows[:, 0] = np.repeat(rng.normal(size=30), 10)  # the temperature holds for ten samples, the lags move
    rows[[40, 41], 0] = np.nan
    got = [served.point(row) for row in rows.tolist()]
    want = [make().point(row) for row in rows.tolist()]
    assert np.array(got).tobytes() == np.array(want).tobytes()
    assert np.isnan(got[41])


def test_predict_one_with_a_plain_callable_evaluator():
    frozen_model = model(lambda xs: xs.sum(axis=1))
    value, clamped = frozen_model.predict_one((100.0, 0.0))
    want, want_clamped = frozen_model.predict(np.array([[100.0, 0.0]]))
    assert value == want[0] and clamped == want_clamped[0]


# -- batch evaluation: column-wise kernel sums and distinct-row reuse ------------------------------------------


def reference_gaussian_sum(xs, centres, weights, gamma):
    """fogd.core.frozen._gaussian_sum as first written: one (rows, centres, inputs) temporary per block."""
    out = np.empty(xs.shape[0])
    for start in range(0, xs.shape[0], 4096):
        block = xs[start : start + 4096]
        squared = ((block[:, None, :] - centres[None, :, :]) ** 2).sum(axis=2)
        out[start : start + 4096] = frozen._row_dot(np.exp(-gamma * squared), weights)
    return out


@pytest.mark.parametrize("d", [1, 2, 3])
def test_gaussian_sum_is_bit_identical_to_the_first_form(d):
    rng = np.random.default_rng(d)
    xs, centres, weights = rng.normal(size=(9000, d)), rng.normal(size=(57, d)), rng.normal(size=57)
    got = frozen._gaussian_sum(xs, centres, weights, 0.8)
    assert got.tobytes() == reference_gaussian_sum(xs, centres, weights, 0.8).tobytes()


def test_unique_rows_round_trip_bit_for_bit():
    rng = np.random.default_rng(0)
    x = np.round(rng.normal(size=(20000, 2)) * 2) / 4
    x[10:20] = [-0.0, 0.0]
    x[20:25] = [0.0, 0.0]
    x[30] = [np.nan, 1.0]
    rows, inverse = unique_rows(x)
    assert rows[inverse].tobytes() == x.tobytes()
    assert len(rows) == len(np.unique(x.view(np.int64), axis=0))


@pytest.mark.parametrize("name", ["ls-poly", "rbf-nn", "svr-small", "svr-large"])
def test_predict_reusing_distinct_rows_is_bit_identical(name, monkeypatch):
    rng = np.random.default_rng(5)
    frozen_model = model(evaluators(rng)[name])
    temp_c = chamber_temps(30000, 2)
    x = np.column_stack((temp_c, temp_rate_batch(temp_c, EstimatorSettings(5.0, 0.5), 20.0)))
    x[100] = [np.nan, 0.0]
    x[200:210] = [-0.0, 0.0]
    got, got_clamped = frozen_model.predict(x)
    monkeypatch.setattr(frozen, "_UNIQUE_MIN_ROWS", 1 << 62)  # every row evaluated
    want, want_clamped = frozen_model.predict(x)
    assert got.tobytes() == want.tobytes() and np.array_equal(got_clamped, want_clamped)
    # and a row's value does not depend on what came with it
    single = np.concatenate([frozen_model.predict(x[i : i + 1])[0] for i in range(0, 30000, 997)])
    assert single.tobytes() == got[::997].tobytes()


# -- reading runs ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("bom", [False, True])
def test_read_run_equals_numpy_loadtxt(tmp_path, bom):
    rng = np.random.default_rng(1)
    n = 5000
    table = np.column_stack((np.arange(n) / 100.0, rng.normal(size=n) * 10, 20 + rng.normal(size=n)))
    text = "t_s,rate_dph,temp_c\n" + "\n".join(f"{t:.6f},{r!r},{c:.17g}" for t, r, c in table.tolist()) + "\n"
    path = tmp_path / "run.csv"
    path.write_bytes((b"\xef\xbb\xbf" if bom else b"") + text.encode())
    run = read_run(path)
    want = np.loadtxt(path, delimiter=",", skiprows=1, encoding="utf-8-sig")
    assert np.column_stack((run.t_s, run.rate_dph, run.temp_c)).tobytes() == want.tobytes()
    assert len(run.sha256) == 64


def compensated_in_chunks(frozen_model: FrozenModel, rate: np.ndarray, temp: np.ndarray, size: int) -> dict:
    compensator = Compensator(frozen_model, 10.0)
    parts = [compensator.process(rate[i : i + size], temp[i : i + size]) for i in range(0, rate.size, size)]
    return {name: np.concatenate([getattr(p, name) for p in parts]) for name in ("temp_c", "temp_rate_cps", "comp_dph", "rate_comp_dph", "flags")}


@pytest.mark.parametrize("name", ["linear", "ls-poly", "rbf-nn", "svr-small", "svr-large", "svr-none"])
def test_the_daemons_one_sample_chunks_equal_replays_big_chunks(name):
    """Chunks of one sample take the scalar path (update_one, predict_one), a whole run the array path: the
    same temperatures, rates and flags bit for bit, the compensation within 1e-12 (exact for linear)."""
    rng = np.random.default_rng(8)
    frozen_model = model(evaluators(rng)[name])
    temp = 20 + np.round(np.cumsum(rng.normal(0, 0.02, 1500)) / 0.0625) * 0.0625  # leaves the domain too
    rate = rng.normal(0, 1, 1500)
    temp[[3, 700, 701]] = [np.nan, np.inf, 500.0]
    rate[[5, 900]] = [np.nan, np.inf]
    whole = compensated_in_chunks(frozen_model, rate, temp, rate.size)
    one = compensated_in_chunks(frozen_model, rate, temp, 1)
    assert ((whole["flags"] & Flag.CLAMPED) != 0).any() and ((whole["flags"] & Flag.WARMUP) == 0).any()
    for column in ("temp_c", "temp_rate_cps", "flags"):
        assert one[column].tobytes() == whole[column].tobytes(), column
    if name == "linear":
        assert one["comp_dph"].tobytes() == whole["comp_dph"].tobytes()
    np.testing.assert_allclose(one["comp_dph"], whole["comp_dph"], rtol=1e-12, atol=1e-12 * np.abs(whole["comp_dph"]).max())
    np.testing.assert_allclose(one["rate_comp_dph"], whole["rate_comp_dph"], rtol=1e-12, atol=1e-12 * np.abs(whole["comp_dph"]).max())


def test_lagged_and_multi_window_inputs_one_sample_at_a_time_equal_the_array_path():
    specs = parse_inputs("temp,rate@5,rate@30,lag@60")
    frozen_model = FrozenModel(
        method="linear", inputs=specs, x_mean=np.zeros(4), x_scale=np.ones(4), y_mean=0.0, y_scale=1.0,
        domain_min=np.full(4, -1e3), domain_max=np.full(4, 1e3), evaluator=Linear(np.array([0.01, 20.0, -7.0, 0.03]), 0.2),
    )  # fmt: skip
    rng = np.random.default_rng(9)
    temp = 20 + np.round(np.cumsum(rng.normal(0, 0.02, 2000)) / 0.0625) * 0.0625
    rate = rng.normal(0, 1, 2000)
    whole = compensated_in_chunks(frozen_model, rate, temp, rate.size)
    for size in (1, 7, 16, 17):
        chunked = compensated_in_chunks(frozen_model, rate, temp, size)
        for column, values in chunked.items():
            assert values.tobytes() == whole[column].tobytes(), (size, column)


def lag_bank_model() -> FrozenModel:
    """An SVR on a polynomial trend over temp and three lags, its domain narrower than the data."""
    specs = parse_inputs("temp,lags@5,50,500")
    powers = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1], [2, 0, 0, 0], [0, 3, 0, 0]])
    evaluator = Svr(np.array([[0.1, 0.0, -0.1, 0.2], [-0.3, 0.2, 0.1, 0.0]]), np.array([0.4, -0.2]), 0.7,
                    np.array([0.3, -0.2, 0.1, 0.05, 0.02, -0.01]), 0.05, powers)  # fmt: skip
    return FrozenModel(
        method="pso-svr", inputs=specs, x_mean=np.full(4, 20.0), x_scale=np.full(4, 3.0), y_mean=0.0, y_scale=1.0,
        domain_min=np.array([15.0, 16.0, 17.0, 18.0]), domain_max=np.array([25.0, 24.0, 23.0, 22.0]), evaluator=evaluator,
    )  # fmt: skip


def test_lag_bank_clamp_moves_the_temperatures_together():
    """Outside the calibrated range the fastest temperature is clamped and every lag moves by the same amount,
    so the differences between lags (the coil's thermal state) are kept; inside, nothing moves."""
    model = lag_bank_model()
    x = np.array([[30.0, 28.0, 25.0, 21.0], [20.0, 19.0, 18.5, 18.2], [10.0, 11.0, 12.0, 14.0]])
    clamped = clamp_rows(x, model.domain_min, model.domain_max, shifted_columns(model.inputs))
    np.testing.assert_array_equal(clamped[1], x[1])
    np.testing.assert_allclose(clamped[0], x[0] - 5.0)
    np.testing.assert_allclose(clamped[2], x[2] + 5.0)
    _, flags = model.predict(x)
    assert flags.tolist() == [True, False, True]


def test_lag_bank_polynomial_trend_predict_one_equals_predict():
    model = lag_bank_model()
    rng = np.random.default_rng(3)
    x = 20.0 + rng.normal(0.0, 5.0, (300, 4))
    want, want_clamped = model.predict(x)
    got = [model.predict_one(tuple(row)) for row in x.tolist()]
    np.testing.assert_allclose([value for value, _ in got], want, rtol=1e-12, atol=1e-12)
    assert [flag for _, flag in got] == want_clamped.tolist()
    assert 0 < want_clamped.sum() < len(x)


def test_lag_bank_one_sample_chunks_equal_big_chunks():
    """The daemon's one-sample chunks and replay's big chunks through a lag-bank model: inputs and flags bit
    for bit, the compensation within 1e-12."""
    model = lag_bank_model()
    rng = np.random.default_rng(11)
    temp = np.round(20 + np.linspace(0.0, 10.0, 3000) + rng.normal(0, 0.3, 3000))  # whole degrees, out of the domain
    rate = rng.normal(0, 1, temp.size)
    whole = compensated_in_chunks(model, rate, temp, temp.size)
    assert ((whole["flags"] & Flag.CLAMPED) != 0).any()
    for size in (1, 16):
        chunked = compensated_in_chunks(model, rate, temp, size)
        assert chunked["flags"].tobytes() == whole["flags"].tobytes()
        np.testing.assert_allclose(chunked["comp_dph"], whole["comp_dph"], rtol=1e-12, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(
    st.integers(1, 6),
    st.integers(0, 4),
    st.integers(0, 2**32 - 1),
)
def test_monomials_reusing_leading_factors_equal_the_products_written_out(inputs, degree, seed):
    """`frozen.monomials` forms each monomial once per distinct prefix of factors; each must equal the
    product of its own factors x_j ** p (numpy's power against an array of exponents, as StackedModels'
    table), formed left to right in column order, bit for bit, in any order of the rows, the constant too."""
    rng = np.random.default_rng(seed)
    powers = rng.integers(0, degree + 1, size=(rng.integers(1, 30), inputs))
    xs = rng.normal(0.0, 2.0, size=(7, inputs))
    got = frozen.monomials(xs, powers)
    for k, row in enumerate(powers.tolist()):
        expected = np.ones(xs.shape[0])
        for column, power in enumerate(row):
            if power:
                expected = expected * np.power(xs[:, column : column + 1], np.arange(power + 1.0))[:, power]
        assert np.array_equal(got[:, k], expected), (row, got[:, k], expected)
