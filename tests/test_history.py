"""fogd.core.history: the lag's closed form for a ramp against the batch lag filter, and a bank primed from a
history against the batch inputs of the whole run (exact with the raw samples, within the decimation's
measured error from block means alone), whatever the inputs."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from thermal_runs import BANK_INPUTS, ramp_run

from fogd.core.history import TempHistory, lag_through
from fogd.core.inputs import InputBank, inputs_batch, parse_inputs
from fogd.core.lag import lag_batch

RATE_HZ = 5.0


@settings(max_examples=60, deadline=None)
@given(
    knots=st.lists(st.tuples(st.integers(1, 400), st.floats(-40.0, 80.0)), min_size=1, max_size=8),
    start_c=st.floats(-40.0, 80.0),
    tau_s=st.floats(0.5, 5000.0),
)
def test_the_closed_form_is_the_batch_lag_of_the_piecewise_linear_run(knots, start_c, tau_s):
    """Knots on the sample grid: the line through them sampled at RATE_HZ, through fogd.core.lag's batch filter,
    ends where lag_through's closed form does."""
    times = [0.0]
    for steps, _ in knots:
        times.append(times[-1] + steps / RATE_HZ)
    points = list(zip(times, [start_c, *(temp_c for _, temp_c in knots)]))
    grid = np.arange(int(round(times[-1] * RATE_HZ)) + 1) / RATE_HZ
    samples = np.interp(grid, [t for t, _ in points], [c for _, c in points])
    expected = lag_batch(samples, tau_s, RATE_HZ)[-1]
    assert abs(lag_through(points, tau_s, RATE_HZ) - expected) <= 1e-9 * max(1.0, abs(expected))


def run_and_inputs(specs_text: str, seed: int) -> tuple[dict, tuple, np.ndarray]:
    run = ramp_run(7200.0, seed=seed, soak_s=1800.0, ramp_cps=0.004)
    specs = parse_inputs(specs_text)
    nxt = np.append(run["temp_c"], run["temp_c"][-1] + 0.01)
    return run, specs, inputs_batch(nxt, specs, RATE_HZ)[-1]


def primed_row(history: TempHistory, specs: tuple, next_c: float) -> np.ndarray:
    bank = InputBank(specs, RATE_HZ)
    history.prime(bank)
    return np.array(bank.update_one(next_c))


def from_block_means(run: dict, next_c: float) -> TempHistory:
    """What a restart finds: the run's 1 s block means alone (the state file), bridged to the next sample."""
    full = TempHistory(RATE_HZ)
    full.extend(run["t_s"].tolist(), run["temp_c"].tolist())
    restored = TempHistory(RATE_HZ)
    restored.restore(full.points(), full.samples)
    restored.bridge(run["t_s"][-1] + 1 / RATE_HZ, next_c)
    return restored


@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 1000),
       inputs=st.sampled_from([BANK_INPUTS, "temp,rate@50", "lags@30,300,play@1,rate@120", "temp,lags@30,300,play@1:600"]))
def test_a_bank_primed_from_the_raw_history_is_the_whole_run_through_it(seed, inputs):
    """A raw tail as long as the run: the primed bank's next row is the batch inputs' (play and lags to 1e-9)."""
    run, specs, expected = run_and_inputs(inputs, seed)
    history = TempHistory(RATE_HZ, tail_s=8000.0)
    history.extend(run["t_s"].tolist(), run["temp_c"].tolist())
    np.testing.assert_allclose(primed_row(history, specs, expected[0] if specs[0].kind == "temp_c" else run["temp_c"][-1] + 0.01),
                               expected, rtol=0, atol=1e-9)  # fmt: skip


def test_block_means_alone_cost_the_lags_far_less_than_the_noise():
    """The state file holds 1 s block means only (no raw tail) and a restart bridges to the next sample: the
    lags' error is a thousandth of a degree at most, against 0.01 C of sensor noise (figures in
    docs/reference/thermal-state.md); without the history (a cold start) it is degrees."""
    run, specs, expected = run_and_inputs(BANK_INPUTS, 1)
    restored = from_block_means(run, expected[0])
    # the bridge ends at the sample before the next one, which is the last sample itself: prime and feed it
    row = primed_row(restored, specs, expected[0])
    lags = slice(1, 8)
    error_c = np.abs(row[lags] - expected[lags])
    print("block means only, lag errors (C):", np.array2string(error_c, precision=6))
    assert error_c.max() < 1e-3
    cold = np.array(InputBank(specs, RATE_HZ).update_one(expected[0]))
    assert np.abs(cold[lags] - expected[lags]).max() > 1.0


def test_a_lagged_play_primed_from_block_means_is_the_whole_run_through_it():
    """The play of a 600 s lag, primed from 1 s block means alone (the lag at each point, then the play): within a
    hundredth of its range of the batch input after a ramp and a soak, where a cold start is at 0."""
    run, specs, expected = run_and_inputs("temp,play@1:600", 2)
    restored = from_block_means(run, expected[0])
    row = primed_row(restored, specs, expected[0])
    assert abs(expected[1]) > 0.5  # the lag has risen well past the play's width: the operator is far from rest
    assert abs(row[1] - expected[1]) < 0.02
    assert abs(InputBank(specs, RATE_HZ).update_one(expected[0])[1] - expected[1]) > 0.5


def test_a_gap_in_a_linear_ramp_is_bridged_exactly():
    """The bridge is the closed form of the lag fed a straight line: across a 10-minute gap in a noiseless ramp
    the lags come out as if the samples had been there."""
    t_s = np.arange(int(7200 * RATE_HZ)) / RATE_HZ
    temp_c = 20.0 + 0.003 * t_s
    specs = parse_inputs("temp,lags@10..3000/7")
    gap = slice(int(5000 * RATE_HZ), int(5600 * RATE_HZ))
    history = TempHistory(RATE_HZ)
    history.extend(t_s[: gap.start].tolist(), temp_c[: gap.start].tolist())
    restored = TempHistory(RATE_HZ)
    restored.restore(history.points(), history.samples)
    assert abs(restored.bridge(t_s[gap.stop], temp_c[gap.stop]) - (600.0 + 1 / RATE_HZ)) < 1e-6
    expected = inputs_batch(temp_c[: gap.stop + 1], specs, RATE_HZ)[-1]
    np.testing.assert_allclose(primed_row(restored, specs, temp_c[gap.stop]), expected, rtol=0, atol=1e-6)


def test_priming_an_empty_history_changes_nothing():
    bank = InputBank(parse_inputs("temp,lag@100"), RATE_HZ)
    TempHistory(RATE_HZ).prime(bank)
    assert bank.update_one(21.0) == (21.0, 21.0)


@settings(max_examples=80, deadline=None)
@given(
    steps=st.lists(st.integers(1, 30), min_size=1, max_size=120),
    temps=st.lists(st.floats(-40.0, 80.0), min_size=120, max_size=120),
    cuts=st.lists(st.integers(0, 120), max_size=6),
    span_s=st.sampled_from([3.0, 8.0, 1000.0]),
)
def test_the_history_is_the_same_however_its_samples_are_grouped(steps, temps, cuts, span_s):
    """Samples added one at a time and in chunks give the same history, and its block means are the plain
    means of each 1 s block's samples (a short span fills the blocks and drops the run's start too)."""
    times = np.cumsum(np.array(steps) / 10.0).tolist()
    temps = temps[: len(times)]
    one = TempHistory(10.0, span_s=span_s, tail_s=2.0)
    for t_s, temp_c in zip(times, temps):
        one.add(t_s, temp_c)
    chunked = TempHistory(10.0, span_s=span_s, tail_s=2.0)
    bounds = sorted({0, len(times), *(cut for cut in cuts if cut <= len(times))})
    for lo, hi in zip(bounds, bounds[1:]):
        chunked.extend(times[lo:hi], temps[lo:hi])
    assert chunked.points() == one.points()
    assert (chunked.first, chunked.last, chunked.samples, list(chunked.tail)) == (one.first, one.last, one.samples, list(one.tail))
    blocks: dict[int, list[tuple[float, float]]] = {}
    for t_s, temp_c in zip(times, temps):
        blocks.setdefault(int(np.floor(t_s)), []).append((t_s, temp_c))
    expected = [(np.mean([t for t, _ in b]), np.mean([c for _, c in b])) for b in blocks.values()]
    held = int(span_s) + 2 + 1  # the closed blocks the history keeps and the open one
    kept = expected[-held:]
    start = [(times[0], temps[0])] if len(expected) <= held else []
    got = chunked.points()
    if got[-1] == (times[-1], temps[-1]) and len(got) > len(start) + len(kept):
        got = got[:-1]  # the newest sample, after its block's mean
    assert len(got) == len(start) + len(kept)
    assert got[: len(start)] == start
    np.testing.assert_allclose(np.array(got[len(start) :]), np.array(kept), rtol=1e-12, atol=1e-9)
