"""fogd.core.warming: the WARMING bound clears within minutes of a start at equilibrium, holds mid-ramp, and
bounds the true error of the equilibrium assumption wherever it has cleared; the warming modes."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from thermal_runs import RATE_HZ, bank_document

from fogd.core import modelfile
from fogd.core.compensator import Compensator
from fogd.core.warming import PROBE_S, TOLERANCE_DPH, WarmingBound, replay_rules

WARMING = 64


@pytest.fixture(scope="module")
def model():
    return modelfile.from_document(bank_document())


def profile(duration_s: float, seed: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Soak at 20 C to 1,800 s, a ramp of 0.003 C/s to 5,400 s, then a soak at 30.8 C; 0.01 C of noise."""
    rng = np.random.default_rng(seed)
    t_s = np.arange(int(duration_s * RATE_HZ)) / RATE_HZ
    temp_c = 20.0 + 0.003 * np.clip(t_s - 1800.0, 0.0, 3600.0) + rng.normal(0.0, 0.01, t_s.size)
    return t_s, rng.normal(0.0, 0.005, t_s.size), temp_c


def cold(model, t_s, rate_dph, temp_c, start: int, mode: str = "compensate"):
    """The run compensated from row `start` with no history (a cold start), as the daemon and fogd-replay do."""
    rows = slice(start, None)
    return replay_rules(Compensator(model, RATE_HZ), t_s[rows], rate_dph[rows], temp_c[rows], 0, mode=mode)


def test_at_equilibrium_the_flag_clears_right_after_the_probe(model):
    t_s, rate_dph, temp_c = profile(1500.0)
    flags = cold(model, t_s, rate_dph, temp_c, 0).flags
    warming = (flags & WARMING) != 0
    cleared_s = t_s[np.argmin(warming)]
    assert warming[0] and PROBE_S <= cleared_s <= PROBE_S + 60.0
    assert not warming[np.argmin(warming):].any()


def test_wherever_the_flag_has_cleared_the_assumption_costs_less_than_the_tolerance(model):
    """Started mid-ramp: flagged for as long as the truth (the whole run replayed) is off by more than the
    tolerance, and cleared later on the soak, the bound measured, not a fixed time."""
    t_s, rate_dph, temp_c = profile(30000.0)
    start = int(4000 * RATE_HZ)
    truth = Compensator(model, RATE_HZ).process(rate_dph, temp_c).comp_dph[start:]
    result = cold(model, t_s, rate_dph, temp_c, start)
    warming = (result.flags & WARMING) != 0
    error_dph = np.abs(result.comp_dph - truth)
    assert warming[: int(3600 * RATE_HZ)].all() and not warming[-1]
    assert error_dph[~warming].max() <= TOLERANCE_DPH
    assert error_dph[warming].max() > 5 * TOLERANCE_DPH  # the flag was needed
    print(f"mid-ramp start: WARMING for {np.argmin(warming) / RATE_HZ:.0f} s; the error when it cleared "
          f"{error_dph[np.argmin(warming)]:.2g} deg/h")


@pytest.mark.parametrize("mode", ["pass", "fallback"])
def test_pass_and_fallback_without_a_guard_leave_warming_samples_uncompensated(model, mode):
    t_s, rate_dph, temp_c = profile(400.0)
    compensated, passed = cold(model, t_s, rate_dph, temp_c, 0), cold(model, t_s, rate_dph, temp_c, 0, mode)
    warming = (passed.flags & WARMING) != 0
    assert warming.any() and (~warming).any()
    assert (passed.comp_dph[warming] == 0).all()
    np.testing.assert_allclose(passed.rate_comp_dph[warming], rate_dph[warming], rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(passed.comp_dph[~warming], compensated.comp_dph[~warming])
    assert passed.flags.tolist() == compensated.flags.tolist()


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from([5.0, 50.0]), st.sampled_from([0.0, 0.002]),
       st.lists(st.integers(1, 40), min_size=1, max_size=30))
def test_the_bound_fed_a_check_at_a_time_says_what_it_says_fed_sample_by_sample(model, seed, rate_hz, ramp_cps, reads):
    """WarmingBound feeds its banks the samples since the last check in one go; reading `row` after every
    sample makes it feed them one at a time (each sample's own update_one, as it once did): the verdicts, the
    bound and the rows must not tell the two apart, through the probe, the checks, gaps without a temperature
    and the clearing (at 50 Hz at rest it clears). `reads`: where the one-at-a-time bound's row is read (odd:
    after every sample of the run)."""
    rng = np.random.default_rng(seed)
    n = int(2.5 * 60.0 * rate_hz)
    t_s = np.arange(n) / rate_hz
    temp_c = 20.0 + ramp_cps * t_s + rng.normal(0.0, 0.01, n)
    temp_c[rng.random(n) < 0.02] = np.nan  # readings missing now and then
    chunked, stepped = (WarmingBound(model, rate_hz, probe_s=60.0, tolerance_dph=2e-3) for _ in range(2))
    read_every = [k for k in reads for _ in range(k)]
    for index, (time_s, temp) in enumerate(zip(t_s.tolist(), temp_c.tolist())):
        value = None if temp != temp else temp
        assert chunked.update(time_s, value) == stepped.update(time_s, value), index
        if read_every[index % len(read_every)] % 2:
            stepped.row
        assert chunked.bound_dph == pytest.approx(stepped.bound_dph, rel=1e-12, abs=1e-15) or (
            math.isinf(chunked.bound_dph) and math.isinf(stepped.bound_dph))
    assert chunked.row == pytest.approx(stepped.row, rel=1e-12)
    assert chunked.samples == stepped.samples and chunked.active == stepped.active
