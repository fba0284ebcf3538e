"""The compensator the daemon and replay share: chunking independence, warm-up, holds, flags, clamping."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from fogd.core.compensator import Compensator
from fogd.core.estimator import EstimatorSettings, temp_rate_batch
from fogd.core.flags import Flag
from fogd.core.frozen import FrozenModel, Linear
from fogd.core.inputs import default_inputs

RATE_HZ = 10.0
ESTIMATOR = EstimatorSettings(window_s=5.0, average_s=0.5)
WINDOW = 50


def linear_model(domain_min=(-40.0, -0.1), domain_max=(80.0, 0.1)) -> FrozenModel:
    """comp = 0.01 * T + 20 * dT/dt in deg/h, written so the test can compute it by hand."""
    return FrozenModel(
        method="linear",
        inputs=default_inputs(ESTIMATOR),
        x_mean=np.zeros(2),
        x_scale=np.ones(2),
        y_mean=0.0,
        y_scale=1.0,
        domain_min=np.array(domain_min),
        domain_max=np.array(domain_max),
        evaluator=Linear(np.array([0.01, 20.0]), 0.0),
    )


def by_hand(temp_c: np.ndarray) -> np.ndarray:
    return 0.01 * temp_c + 20.0 * temp_rate_batch(temp_c, ESTIMATOR, RATE_HZ)


def run_in_chunks(compensator, rate, temp, chunks):
    parts, start = [], 0
    for size in [*chunks, rate.size]:
        parts.append(compensator.process(rate[start : start + size], temp[start : start + size]))
        start += size
        if start >= rate.size:
            break
    return {name: np.concatenate([getattr(p, name) for p in parts]) for name in ("temp_c", "temp_rate_cps", "comp_dph", "rate_comp_dph", "flags")}


def test_compensation_is_the_model_of_temperature_and_eq16_rate():
    temp = 20 + 0.02 * np.arange(400) / RATE_HZ
    rate = np.full(400, 7.5)
    out = Compensator(linear_model(), RATE_HZ).process(rate, temp)
    expected = by_hand(temp)
    np.testing.assert_allclose(out.comp_dph, expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(out.rate_comp_dph, rate - expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(out.temp_rate_cps[WINDOW:], 0.02, rtol=1e-6)


def test_warmup_rows_are_flagged_and_use_zero_rate():
    temp = 20 + 0.02 * np.arange(100) / RATE_HZ
    out = Compensator(linear_model(), RATE_HZ).process(np.zeros(100), temp)
    warm = (out.flags & Flag.WARMUP) != 0
    assert warm[: WINDOW - 1].all() and not warm[WINDOW - 1 :].any()
    assert np.all(out.temp_rate_cps[: WINDOW - 1] == 0)
    np.testing.assert_allclose(out.comp_dph[: WINDOW - 1], 0.01 * temp[: WINDOW - 1])


@settings(max_examples=50, deadline=None)
@given(
    chunks=st.lists(st.integers(1, 120), max_size=10),
    bad_temp=st.lists(st.integers(0, 299), max_size=20),
    bad_rate=st.lists(st.integers(0, 299), max_size=20),
)
def test_output_does_not_depend_on_chunking(chunks, bad_temp, bad_rate):
    rng = np.random.default_rng(len(chunks))
    temp = 30 + np.cumsum(rng.normal(0, 0.05, 300))
    rate = rng.normal(5, 1, 300)
    temp[bad_temp] = np.nan
    rate[bad_rate] = np.inf
    whole = Compensator(linear_model(), RATE_HZ).process(rate, temp)
    pieces = run_in_chunks(Compensator(linear_model(), RATE_HZ), rate, temp, chunks)
    for name, values in pieces.items():
        np.testing.assert_array_equal(values, getattr(whole, name), err_msg=name)


def test_invalid_temperature_holds_the_last_valid_one():
    temp = 20 + 0.004 * np.arange(200)  # 0.04 C/s, inside the domain
    broken = temp.copy()
    broken[[60, 61, 120]] = [np.nan, 500.0, -np.inf]
    out = Compensator(linear_model(), RATE_HZ).process(np.zeros(200), broken)
    assert np.all((out.flags[[60, 61, 120]] & Flag.TEMP_INVALID) != 0)
    assert out.temp_c[60] == out.temp_c[61] == temp[59]
    assert out.temp_c[120] == temp[119]
    assert np.count_nonzero(out.flags & Flag.TEMP_INVALID) == 3
    held = temp.copy()
    held[[60, 61]] = temp[59]
    held[120] = temp[119]
    np.testing.assert_allclose(out.comp_dph, by_hand(held), atol=1e-12)


def test_nothing_is_compensated_before_the_first_valid_temperature():
    temp = np.full(80, np.nan)
    temp[10:] = 25.0
    out = Compensator(linear_model(), RATE_HZ).process(np.ones(80), temp)
    assert np.all(out.comp_dph[:10] == 0) and np.all(out.rate_comp_dph[:10] == 1)
    assert np.all((out.flags[:10] & (Flag.WARMUP | Flag.TEMP_INVALID)) == Flag.WARMUP | Flag.TEMP_INVALID)
    # the estimator starts with the first valid temperature: its window is full WINDOW samples later
    warm = (out.flags & Flag.WARMUP) != 0
    assert warm[: 10 + WINDOW - 1].all() and not warm[10 + WINDOW - 1 :].any()


def test_invalid_rate_passes_through_and_is_flagged():
    rate = np.ones(100)
    rate[[5, 70]] = [np.nan, np.inf]
    valid = np.ones(100, dtype=bool)
    valid[80] = False
    out = Compensator(linear_model(), RATE_HZ).process(rate, np.full(100, 20.0), rate_valid=valid)
    bad = [5, 70, 80]
    assert np.all((out.flags[bad] & Flag.RATE_INVALID) != 0)
    assert np.count_nonzero(out.flags & Flag.RATE_INVALID) == 3
    np.testing.assert_array_equal(out.rate_comp_dph[bad], rate[bad])
    np.testing.assert_allclose(out.rate_comp_dph[90:], 1 - 0.2)


def test_inputs_outside_the_domain_are_clamped_and_flagged():
    model = linear_model(domain_min=(0.0, -0.1), domain_max=(30.0, 0.1))
    temp = np.concatenate([np.full(60, 25.0), np.full(60, 45.0)])
    out = Compensator(model, RATE_HZ).process(np.zeros(120), temp)
    clamped = (out.flags & Flag.CLAMPED) != 0
    # 45 C is clamped to 30 C; the step's rate (20 C over 4.5 s) exceeds 0.1 C/s and is clamped too
    assert not clamped[:60].any() and clamped[60:].all()
    np.testing.assert_allclose(out.comp_dph[-1], 0.01 * 30.0)
    assert np.max(out.comp_dph) <= 0.01 * 30.0 + 20 * 0.1 + 1e-12


def test_stale_temperature_is_flagged():
    stale = np.zeros(10, dtype=bool)
    stale[4:] = True
    out = Compensator(linear_model(), RATE_HZ).process(np.zeros(10), np.full(10, 20.0), temp_stale=stale)
    assert np.array_equal((out.flags & Flag.TEMP_STALE) != 0, stale)


def test_an_invalid_rate_shows_no_compensation_applied():
    """Issue 35 item 6: comp_dph is what was subtracted, so 0 where the rate passed through uncompensated."""
    rate = np.ones(100)
    rate[[5, 70]] = [np.nan, np.inf]
    valid = np.ones(100, dtype=bool)
    valid[80] = False
    temp = np.full(100, 20.0)  # comp 0.2 deg/h everywhere the rate is valid
    batch = Compensator(linear_model(), RATE_HZ).process(rate, temp, rate_valid=valid)
    few = Compensator(linear_model(), RATE_HZ).process_few(rate.tolist(), temp.tolist(), valid.tolist(), [False] * 100)
    for out in (batch, few):
        comp = np.asarray(out.comp_dph)
        np.testing.assert_array_equal(comp[[5, 70, 80]], 0.0)
        np.testing.assert_allclose(np.delete(comp, [5, 70, 80]), 0.2)
