"""Table 4's block grid: one per run, the same rows for every model; settling skipped; shares of fallback and
clamping over the grid's rows."""

from __future__ import annotations

import numpy as np
import pytest

from fogd.calibration.replay import SETTLE_S, block_grid, replay, replay_table
from fogd.core import modelfile
from fogd.core.columns import TRUE_ERROR_COLUMN
from fogd.core.errorstats import detrended_stats
from fogd.core.estimator import EstimatorSettings
from fogd.core.flags import Flag
from fogd.core.frozen import FrozenModel
from fogd.core.inputs import default_inputs
from fogd.core.runio import Run

RATE_HZ = 10.0


def make_run(temp_c: np.ndarray, rate_dph: np.ndarray, truth_dph: np.ndarray | None = None) -> Run:
    extra = {} if truth_dph is None else {TRUE_ERROR_COLUMN: truth_dph}
    t_s = np.arange(temp_c.size) / RATE_HZ
    return Run("mem/run.csv", t_s, rate_dph, temp_c, RATE_HZ, "0" * 64, extra)


def chamber_run(hours: float = 2.0, seed: int = 1) -> Run:
    """A ramp with a wobble; error = 0.002*T + 5*dT/dt deg/h plus white noise."""
    t_s = np.arange(0.0, hours * 3600.0, 1.0 / RATE_HZ)
    temp_c = 10.0 + 20.0 * t_s / t_s[-1] + 2.0 * np.sin(2.0 * np.pi * t_s / 1500.0)
    truth = 0.002 * temp_c + 5.0 * np.gradient(temp_c, t_s)
    rate = 0.4 + truth + np.random.default_rng(seed).normal(0.0, 0.02, t_s.size)
    return make_run(np.round(temp_c, 3), rate, truth)


def linear_model(
    window_s: float, coef: tuple[float, float] = (0.002, 5.0), domain_max: tuple[float, float] = (80.0, 1.0),
    guard: dict | None = None,
) -> FrozenModel:
    document = modelfile.document(
        name=f"linear-{window_s:g}s", method="linear", inputs=default_inputs(EstimatorSettings(window_s, 0.5)),
        x_mean=np.zeros(2), x_scale=np.array([1.0, 0.001]), y_mean=0.0, y_scale=1.0,
        domain_min=np.array([-50.0, -1.0]), domain_max=np.array(domain_max),
        params={"coef": list(coef), "intercept": 0.0}, reference_dph=0.0, training={}, metrics={},
        created_utc="2026-01-01T00:00:00+00:00", domain_guard=guard,
    )  # fmt: skip
    return modelfile.from_document(document)


@pytest.mark.parametrize("settle_s", [0.0, SETTLE_S])
def test_before_row_is_the_same_for_models_with_different_warmups(settle_s):
    run = chamber_run()
    short, long = linear_model(5.0), linear_model(900.0)  # warm-ups of 50 and 9000 rows
    short_result, long_result = replay(short, run), replay(long, run)
    tables = [replay_table(run, result, 100.0, settle_s=settle_s) for result in (short_result, long_result)]
    # the long window's warm-up reaches into the grid: the old rule (warm rows only) gave it other blocks
    in_grid_warmup = (long_result.flags[tables[1].grid.rows] & Flag.WARMUP) != 0
    assert in_grid_warmup.sum() > 2000
    assert tables[0].before == tables[1].before and tables[0].best == tables[1].best
    assert tables[0].blocks == tables[1].blocks == int(2 * 3600 - settle_s) // 100
    np.testing.assert_array_equal(tables[0].grid.rows, tables[1].grid.rows)
    assert tables[0].after != tables[1].after  # the models do differ
    assert tables[0].settle_s == settle_s and not tables[0].settle_fallback


def test_grid_starts_settle_s_after_the_first_row_and_skips_only_invalid_rows():
    run = chamber_run(hours=1.0, seed=2)
    run.temp_c[:200] = np.nan  # no temperature for the first 20 s
    run.rate_dph[7000:7300] = np.nan  # a stretch of invalid rates inside the grid
    run.temp_c[8000:8100] = 300.0  # and of out-of-range temperatures
    result = replay(linear_model(50.0), run)
    table = replay_table(run, result, 100.0, settle_s=600.0)
    valid = np.isfinite(run.rate_dph) & np.isfinite(run.temp_c) & (run.temp_c < 200.0)
    expected = []
    for start in range(6000, run.rows - 999, 1000):  # blocks of 1000 rows from row 6000 (600 s at 10 Hz)
        use = valid[start : start + 1000]
        expected.append(run.rate_dph[start : start + 1000][use].mean())
    assert table.blocks == len(expected) == 30
    assert table.before.rmse_dph == pytest.approx(detrended_stats(np.array(expected)).rmse_dph, rel=1e-12)
    assert not table.grid.rows[:6000].any()
    assert table.grid.rows.sum() == 30_000 - 300 - 100

    from_start = replay_table(run, result, 100.0, settle_s=0.0)
    assert not from_start.grid.rows[:200].any() and from_start.grid.rows[200:1000].all()
    assert from_start.blocks == 36


def test_a_run_too_short_for_a_block_after_settling_is_gridded_from_its_first_row():
    run = chamber_run(hours=700.0 / 3600.0)
    result = replay(linear_model(5.0), run)
    table = replay_table(run, result, 100.0, settle_s=650.0)  # 50 s left: no block
    assert table.settle_fallback and table.settle_s == 0.0 and table.blocks == 7
    assert table.before == replay_table(run, result, 100.0, settle_s=0.0).before
    kept = replay_table(run, result, 100.0, settle_s=500.0)
    assert not kept.settle_fallback and kept.settle_s == 500.0 and kept.blocks == 2


def test_a_settled_block_with_too_few_valid_rows_also_falls_back():
    run = chamber_run(hours=800.0 / 3600.0)
    run.rate_dph[6000:] = np.nan  # the only block after 600 s has no valid rate
    table = replay_table(run, replay(linear_model(5.0), run), 100.0)
    assert table.settle_fallback and table.blocks == 6


def test_shares_of_linear_fallback_and_clamping_over_the_grid_rows():
    steady = np.full(10_000, 5.0)  # 1000 s at 5 C
    ramp = 5.0 + 0.01 * np.arange(10_000) / RATE_HZ  # then 1000 s at 0.01 C/s, up to 15 C
    temp = np.r_[steady, ramp]
    rate = np.zeros(temp.size)
    rate[12_000:12_500] = np.nan  # invalid rows count neither way
    guard = {"points": [[t, 0.0] for t in np.linspace(0.0, 20.0, 41)], "threshold": 0.5,
             "fallback": {"method": "linear", "params": {"coef": [0.002, 0.0], "intercept": 0.0}}}  # fmt: skip
    model = linear_model(5.0, domain_max=(10.0, 1.0), guard=guard)  # clamped above 10 C
    result = replay(model, make_run(temp, rate))
    table = replay_table(make_run(temp, rate), result, 100.0, settle_s=0.0)
    grid_rows = 20_000 - 500
    outside = (result.flags & Flag.OUT_OF_DOMAIN) != 0
    clamped = (result.flags & Flag.CLAMPED) != 0
    valid = np.isfinite(rate)
    # the ramp is out of domain once the 5 s window sees it; it is clamped above 10 C (after 500 s of ramp)
    assert outside[valid].sum() == pytest.approx(10_000 - 500, abs=60)
    assert table.fallback_share == outside[valid].sum() / grid_rows
    assert table.clamped_share == clamped[valid].sum() / grid_rows
    assert table.clamped_share == pytest.approx(5_000 / grid_rows, abs=2e-3)
    unguarded = replay_table(make_run(temp, rate), replay(linear_model(5.0), make_run(temp, rate)), 100.0, settle_s=0.0)
    assert unguarded.fallback_share == 0.0 and unguarded.clamped_share == 0.0


def test_block_grid_counts_no_row_of_a_dropped_block():
    run = chamber_run(hours=0.5)
    flags = np.zeros(run.rows, dtype=np.uint16)
    flags[1000:1600] = Flag.RATE_INVALID  # block 1 keeps 400 of 1000 rows: dropped, and its rows with it
    grid = block_grid(run, flags, 100.0, settle_s=0.0)
    assert grid.blocks == 17 and not grid.rows[1000:2000].any() and grid.rows[:1000].all()
    assert grid.share(flags | Flag.CLAMPED, Flag.CLAMPED) == 1.0
