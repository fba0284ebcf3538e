"""ChannelCompensator: every channel equals a Compensator of its own on that channel, whatever the chunking,
with the inputs computed once per batch for each distinct input configuration."""

from __future__ import annotations

from dataclasses import fields

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_modelfile import make_doc

from fogd.core import modelfile
from fogd.core.channels import ChannelCompensator, ChannelModels
from fogd.core.compensator import Compensated, Compensator
from fogd.core.flags import Flag
from fogd.core.frozen import FrozenModel, Linear
from fogd.core.inputs import InputBank, parse_inputs
from fogd.core.runio import Run

RATE_HZ = 10.0
ROWS = 700
NAMES = [f.name for f in fields(Compensated)]


def lag_model() -> FrozenModel:
    inputs = parse_inputs("temp,lags@30,120")
    return FrozenModel(
        method="linear", inputs=inputs, x_mean=np.zeros(3), x_scale=np.ones(3), y_mean=0.0, y_scale=1.0,
        domain_min=np.full(3, 0.0), domain_max=np.full(3, 45.0), evaluator=Linear(np.array([0.02, -0.5, 0.45]), 0.1),
    )  # fmt: skip


def models() -> dict[str, FrozenModel]:
    """Two channels on the same inputs (temp, rate@20: one bank), a kernel model among them, one on lags."""
    return {
        "rate_x_dph": modelfile.from_document(make_doc("linear")),
        "rate_y_dph": lag_model(),
        "accel_z_g": modelfile.from_document(make_doc("pso-svr")),
    }


STACKED = ("rate_x_dph", "accel_z_g")  # the bank's two channels: evaluated together, fogd.core.frozen.StackedModels


def exact(channel: str) -> bool:
    """Whether the channel's compensation is its own Compensator's bit for bit: a channel alone on its bank goes
    through one (the same code on the same rows); stacked channels' kernel and trend sums run in another order
    (StackedModels), within 1e-12 relative."""
    return channel not in STACKED


def imu_run(seed: int, bad_temp: list[int], bad_rate: list[int]) -> Run:
    rng = np.random.default_rng(seed)
    temp = 20 + np.cumsum(rng.normal(0, 0.02, ROWS)) + np.linspace(0, 8, ROWS)
    temp[bad_temp] = np.nan
    channels = {name: rng.normal(level, 1, ROWS) for name, level in (("rate_x_dph", 5), ("rate_y_dph", -3),
                                                                    ("rate_z_dph", 0), ("accel_z_g", 1))}  # fmt: skip
    for name, rows in zip(channels, (bad_rate, bad_rate[::2], [], bad_rate[1::2])):
        channels[name][rows] = np.inf
    t_s = np.arange(ROWS) / RATE_HZ
    return Run("imu.csv", t_s, channels["rate_x_dph"], temp, RATE_HZ, "0" * 64, channels=channels)


def chunked(process, rows: int, chunks: list[int]) -> list:
    parts, start = [], 0
    for size in [*chunks, rows]:
        parts.append(process(start, min(start + size, rows)))
        start += size
        if start >= rows:
            break
    return parts


def joined(parts: list[Compensated]) -> dict[str, np.ndarray]:
    return {name: np.concatenate([np.asarray(getattr(part, name)) for part in parts]) for name in NAMES}


@settings(max_examples=40, deadline=None)
@given(
    chunks=st.lists(st.integers(1, 150), max_size=12),
    bad_temp=st.lists(st.integers(0, ROWS - 1), max_size=15),
    bad_rate=st.lists(st.integers(0, ROWS - 1), max_size=15),
    seed=st.integers(0, 3),
)
def test_every_channel_equals_its_own_compensator_whatever_the_chunking(chunks, bad_temp, bad_rate, seed):
    run = imu_run(seed, bad_temp, bad_rate)
    stale = np.zeros(ROWS, dtype=bool)
    stale[bad_temp[:3]] = True
    # a channel's own validity, on a channel alone on its bank and on one of the stacked channels
    valid = {"rate_y_dph": np.arange(ROWS) % 97 != 0, "accel_z_g": np.arange(ROWS) % 89 != 3}
    several = ChannelCompensator(models(), RATE_HZ)
    assert several.banks == 2 and several.stacked == (STACKED,)
    streamed = chunked(lambda a, b: several.process(
        {name: values[a:b] for name, values in run.channels.items()}, run.temp_c[a:b],
        rate_valid={name: v[a:b] for name, v in valid.items()}, temp_stale=stale[a:b]), ROWS, chunks)  # fmt: skip
    whole = ChannelCompensator(models(), RATE_HZ).process(run.channels, run.temp_c, rate_valid=valid, temp_stale=stale)
    assert set(whole) == set(models())
    for channel, model in models().items():
        alone = run.channel(channel)  # the channel as a single-axis run, as fogd-replay of one axis sees it
        single = Compensator(model, RATE_HZ)
        own = joined(chunked(lambda a, b: single.process(alone.rate_dph[a:b], alone.temp_c[a:b],
                                                         rate_valid=valid[channel][a:b] if channel in valid else None,
                                                         temp_stale=stale[a:b]), ROWS, chunks))  # fmt: skip
        mine = joined([part[channel] for part in streamed])
        for name in NAMES:  # temperatures, rates and flags bit for bit; the compensation as `exact` says
            if name in ("comp_dph", "rate_comp_dph") and not exact(channel):
                scale = np.max(np.abs(own["comp_dph"]))
                np.testing.assert_allclose(mine[name], own[name], rtol=1e-12, atol=1e-12 * scale, err_msg=f"{channel} {name}")
            else:
                np.testing.assert_array_equal(mine[name], own[name], err_msg=f"{channel} {name}")
        for name in NAMES:  # streaming against one batch: bit for bit (a stacked row's floats are those of many,
            # and the linear models' per-sample sums are the batch's; a kernel model alone on its bank would
            # agree within 1e-12, fogd.core.compensator)
            np.testing.assert_array_equal(mine[name], np.asarray(getattr(whole[channel], name)), err_msg=f"{channel} {name}")


def test_inputs_are_computed_once_per_batch_for_each_configuration(monkeypatch):
    run = imu_run(0, [], [])
    calls: list[int] = []
    update, update_one = InputBank.update, InputBank.update_one
    monkeypatch.setattr(InputBank, "update", lambda self, temp: calls.append(len(self.specs)) or update(self, temp))
    monkeypatch.setattr(InputBank, "update_one", lambda self, temp: calls.append(len(self.specs)) or update_one(self, temp))
    several = ChannelCompensator(models(), RATE_HZ)
    several.process(run.channels, run.temp_c[:ROWS])  # one batch: each bank once
    assert sorted(calls) == [2, 3]
    calls.clear()
    several.process({name: values[:5] for name, values in run.channels.items()}, run.temp_c[:5])  # 5 samples, one by one
    assert sorted(calls) == [2] * 5 + [3] * 5


def test_a_channel_the_models_cover_must_be_given():
    with pytest.raises(ValueError, match="accel_z_g"):
        ChannelCompensator(models(), RATE_HZ).process({"rate_x_dph": np.ones(3), "rate_y_dph": np.ones(3)}, np.full(3, 20.0))


def test_reset_forgets_every_channel():
    run = imu_run(1, [], [])
    several = ChannelCompensator(models(), RATE_HZ)
    first = several.process(run.channels, run.temp_c)
    several.reset()
    again = several.process(run.channels, run.temp_c)
    for channel in first:
        np.testing.assert_array_equal(first[channel].comp_dph, again[channel].comp_dph)
    assert several.warmup == 199  # rate@20 s at 10 Hz


def test_process_few_takes_lists_and_gives_lists():
    several = ChannelCompensator(ChannelModels(models(), name="m", version=3), RATE_HZ)
    out = several.process_few({"rate_x_dph": [1.0], "rate_y_dph": [2.0], "accel_z_g": [1.0]}, [20.0],
                              {"rate_x_dph": [True], "rate_y_dph": [False], "accel_z_g": [True]}, [False])  # fmt: skip
    assert isinstance(out["rate_y_dph"].rate_comp_dph, list) and out["rate_y_dph"].rate_comp_dph == [2.0]


@pytest.mark.parametrize("chunk", [1, 7, 40, 600])
def test_stacked_channels_with_a_domain_guard_flag_and_fall_back_as_their_own(chunk):
    """A guarded model stacked beside an unguarded one: each channel's OUT_OF_DOMAIN samples and fallback as
    its own Compensator's, in one-sample and batch chunks."""
    from test_domain import guarded_document

    guarded = modelfile.from_document(guarded_document())
    plain = modelfile.from_document({k: v for k, v in guarded_document().items() if k != "domain_guard"})
    several = ChannelCompensator({"rate_x_dph": plain, "rate_y_dph": guarded}, 10.0)
    assert several.stacked == (("rate_x_dph", "rate_y_dph"),)
    temps = np.r_[np.full(200, 5.0), 5.0 + 0.01 * np.arange(400) / 10.0]
    rates = np.random.default_rng(0).normal(size=600)
    parts = [several.process({"rate_x_dph": rates[a : a + chunk], "rate_y_dph": rates[a : a + chunk]}, temps[a : a + chunk])
             for a in range(0, 600, chunk)]  # fmt: skip
    for channel, model in (("rate_x_dph", plain), ("rate_y_dph", guarded)):
        own = Compensator(model, 10.0).process(rates, temps)
        mine = joined([part[channel] for part in parts])
        np.testing.assert_array_equal(mine["flags"], own.flags)
        np.testing.assert_allclose(mine["comp_dph"], own.comp_dph, rtol=1e-12, atol=1e-12 * np.max(np.abs(own.comp_dph)))
    assert (joined([p["rate_y_dph"] for p in parts])["flags"] & Flag.OUT_OF_DOMAIN).any()
    assert not (joined([p["rate_x_dph"] for p in parts])["flags"] & Flag.OUT_OF_DOMAIN).any()


def test_one_channel_is_not_stacked():
    one = ChannelCompensator({"rate_dph": models()["accel_z_g"]}, RATE_HZ)
    assert one.stacked == ()


def guarded_model(kind: str) -> FrozenModel:
    """The kernel model with a domain guard of `kind` around 20-25 C and 0.091-0.121 C/s (scaled 0..0.5 and
    9..12): imu_run's rows (20-28 C, 0.09-0.13 C/s) go in and out of it."""
    doc = make_doc("pso-svr")
    doc["domain_guard"] = {"points": [[s, r] for s in np.linspace(0.0, 0.5, 11) for r in (9.0, 10.0, 11.0, 12.0)],
                           "threshold": 0.2, "kind": kind,
                           "fallback": {"method": "linear", "params": {"coef": [0.05, 0.0], "intercept": 0.1}}}  # fmt: skip
    return modelfile.from_document(doc)


ROW_MODEL_SETS = {"three channels": (None, None), "linear alone": ("rate_x_dph", None),
                  "lags alone": ("rate_y_dph", None), "kernel alone": ("accel_z_g", None),
                  "range-guarded kernel alone": ("accel_z_g", "range"), "joint-guarded kernel alone": ("accel_z_g", "joint"),
                  "three channels, the kernel range-guarded": (None, "range")}  # fmt: skip


@pytest.mark.parametrize(("alone", "guard"), ROW_MODEL_SETS.values(), ids=ROW_MODEL_SETS.keys())
@settings(max_examples=30, deadline=None)
@given(
    chunks=st.lists(st.integers(1, 40), max_size=8),
    bad_temp=st.lists(st.integers(0, ROWS - 1), max_size=15),
    bad_rate=st.lists(st.integers(0, ROWS - 1), max_size=15),
    seed=st.integers(0, 3),
)
def test_process_row_is_process_few_of_one_sample(alone, guard, chunks, bad_temp, bad_rate, seed):
    """The daemon's pre-bound one-sample path gives the floats and flags of `process_few` (a one-sample batch),
    bit for bit, and leaves the same state behind: batches after a run of rows go on as after process_few.
    One channel alone takes its own row form (no walk over banks and parts), checked the same way; a domain
    guard sends some rows to its fallback on both paths."""
    run = imu_run(seed, bad_temp, bad_rate)
    stale = (np.arange(ROWS) % 53 == 0).tolist()
    usable = {name: (np.arange(ROWS) % 97 != 0).tolist() if name in ("rate_y_dph", alone) else [True] * ROWS for name in models()}
    def chosen() -> dict[str, FrozenModel]:
        every = {**models(), **({"accel_z_g": guarded_model(guard)} if guard else {})}
        return every if alone is None else {alone: every[alone]}

    fallbacks = set()
    by_row, by_few = ChannelCompensator(chosen(), RATE_HZ), ChannelCompensator(chosen(), RATE_HZ)
    assert (getattr(by_row.process_row, "__func__", None) is ChannelCompensator._process_one) == (alone is not None)
    names = by_row.channels
    values = {name: run.channels[name].tolist() for name in names}
    temps = run.temp_c.tolist()
    start = 0
    for size in [*chunks, ROWS]:  # rows one by one, then a batch through process_few on both, alternately
        stop = min(start + size, ROWS)
        for i in range(start, stop):
            temp_used, temp_rate, comps, outs, flags = by_row.process_row(
                [values[n][i] for n in names], [usable[n][i] for n in names], temps[i], stale[i])
            want = by_few.process_few({n: [values[n][i]] for n in names}, [temps[i]],
                                      {n: [usable[n][i]] for n in names}, [stale[i]])  # fmt: skip
            first = want[names[0]]
            assert (np.float64(temp_used).tobytes(), np.float64(temp_rate).tobytes()) == (
                np.float64(first.temp_c[0]).tobytes(), np.float64(first.temp_rate_cps[0]).tobytes())
            for k, name in enumerate(names):
                assert np.float64(comps[k]).tobytes() == np.float64(want[name].comp_dph[0]).tobytes(), name
                assert np.float64(outs[k]).tobytes() == np.float64(want[name].rate_comp_dph[0]).tobytes(), name
                assert flags[k] == want[name].flags[0], name
                if name == "accel_z_g" and not flags[k] & Flag.WARMUP:
                    fallbacks.add(bool(flags[k] & Flag.OUT_OF_DOMAIN))
        start = stop
        if start >= ROWS:
            break
        stop = min(start + 7, ROWS)
        batch = [by.process_few({n: values[n][start:stop] for n in names}, temps[start:stop],
                                {n: usable[n][start:stop] for n in names}, stale[start:stop]) for by in (by_row, by_few)]
        for name in names:
            for field_name in NAMES:
                assert np.asarray(getattr(batch[0][name], field_name)).tobytes() == \
                    np.asarray(getattr(batch[1][name], field_name)).tobytes(), (name, field_name)
        start = stop
        if start >= ROWS:
            break
    assert guard is None or fallbacks == {True, False}, "the guard sends some rows (not all) to its fallback"


@pytest.mark.parametrize("alone", [None, "rate_y_dph"])
def test_process_row_and_sample_one_go_on_with_a_bank_handed_over(alone):
    """A reload hands the running input banks and held temperatures to a new compensator (carry_state_from,
    serving.daemon's reload): process_row, and a one-channel compensator's sample_one (the daemon's row path),
    must go on from them, not from the new compensator's own fresh banks."""
    import copy

    chosen = models() if alone is None else {alone: models()[alone]}
    run = imu_run(0, [], [])
    names = list(chosen)
    rows = [([run.channels[n][i] for n in names], [True] * len(names), run.temp_c[i]) for i in range(ROWS)]
    running = ChannelCompensator(chosen, RATE_HZ)
    for values, usable, temp in rows[:300]:
        running.process_row(values, usable, temp, False)
    same = copy.deepcopy(running)
    new = ChannelCompensator(chosen, RATE_HZ)
    assert new.carry_state_from(running)
    for values, usable, temp in rows[300:320]:
        assert repr(new.process_row(values, usable, temp, False)) == repr(same.process_row(values, usable, temp, False))
    if alone is not None:
        values, usable, temp = rows[320]
        got = new.sample_one(values[0], temp, usable[0], False)
        want = same.process_row(values, usable, temp, False)
        assert repr(got) == repr((want[0], want[1], want[2][0], want[3][0], want[4][0]))



@pytest.mark.parametrize("alone", [None, "rate_y_dph"])
def test_a_channel_whose_rate_is_invalid_shows_no_compensation_applied(alone):
    """Issue 35 item 6, on every path of the channel compensator (batch, few, one row, one channel alone)."""
    run = imu_run(1, [], [3, 40, 90])
    chosen = models() if alone is None else {alone: models()[alone]}
    names = list(chosen)
    usable = {name: (np.arange(ROWS) % 97 != 5).tolist() for name in names}
    whole = ChannelCompensator(chosen, RATE_HZ).process(
        {n: run.channels[n] for n in names}, run.temp_c, rate_valid={n: np.array(usable[n]) for n in names})
    few = ChannelCompensator(chosen, RATE_HZ).process_few({n: run.channels[n][:200].tolist() for n in names},
                                                         run.temp_c[:200].tolist(), {n: usable[n][:200] for n in names},
                                                         [False] * 200)  # fmt: skip
    by_row = ChannelCompensator(chosen, RATE_HZ)
    rows = [by_row.process_row([run.channels[n][i] for n in names], [usable[n][i] for n in names], run.temp_c[i], False)
            for i in range(200)]  # fmt: skip
    checked = 0
    for k, name in enumerate(names):
        row_comps = [row[2][k] for row in rows]
        row_flags = [row[4][k] for row in rows]
        for comp, flags in ((whole[name].comp_dph, whole[name].flags), (few[name].comp_dph, few[name].flags),
                            (row_comps, row_flags)):  # fmt: skip
            invalid = (np.asarray(flags) & Flag.RATE_INVALID) != 0
            assert np.all(np.asarray(comp)[invalid] == 0.0), name
            assert np.any(np.asarray(comp)[~invalid] != 0.0), name
            checked += int(invalid.sum())
    assert checked > 0
