"""Daemon.compensate: the same output times, columns, counters and latest sample whatever batches the ring
hands over (one frame at a time as at real rates, a few, or many through numpy), for a single-channel model,
a one-channel version-3 file and a multi-channel one."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import fogd
from fogd.core import modelfile
from fogd.protocols.base import ALL_AXES, Frame
from fogd.protocols.kvh import KvhProtocol
from fogd.protocols.lexer import Lexer
from fogd.serving.channels import as_models, plan
from fogd.serving.daemon import MAX_BATCH, Daemon
from fogd.serving.outputs import Formatter, Writer, open_sink
from fogd.serving.ring import Ring

DEMO = json.loads((Path(fogd.__file__).parent / "data" / "demo-model.json").read_text())
CHANNEL_SETS = {"single": None, "one of version 3": ("rate_z_dph",), "three": ("rate_x_dph", "rate_z_dph", "accel_y_g")}


def _daemon(channels: tuple[str, ...] | None) -> Daemon:
    if channels is None:
        model = modelfile.from_document(DEMO)
    else:
        document = modelfile.channels_document(name="batches", documents=dict.fromkeys(channels, DEMO),
                                               created_utc=DEMO["created_utc"])  # fmt: skip
        model = modelfile.from_channels_document(document)
    return Daemon(reader=SimpleNamespace(ring=Ring(1 << 12)), writer=None, formatter=None, model=model, rate_hz=1000.0,
                  axis=2, channels=plan(as_models(model), KvhProtocol(), 2), temp_stale_s=0.05,
                  status_interval_s=60.0)  # fmt: skip


def _stream(count: int, seed: int) -> tuple[list[Frame], list[float]]:
    """KVH-like frames with temperature frames between them, some invalid axes, device times that are None,
    NaN or real, a temperature that goes stale, and a NaN temperature."""
    rng = np.random.default_rng(seed)
    frames, t_rx_s = [], []
    for i in range(count):
        temp_c = 20.0 + 0.002 * i + float(rng.normal(0.0, 0.03))
        rx_s = 100.0 + 0.001 * i + (0.2 if i > count // 2 else 0.0)
        if i % 9 == 4:
            frames.append(Frame("kvh-a", "temp", "T", None, None, None, temp_c=math.nan if i % 27 == 4 else temp_c))
        else:
            valid = (i % 5 != 1, True, i % 11 != 2)
            t_s = (None, math.nan, 0.001 * i)[i % 3]
            has_temp = i < count // 2  # then the rate frames carry none: the held one goes stale
            frames.append(Frame("kvh-a", "imu" if has_temp else "rate", "B", i % 128, t_s,
                                tuple(float(v) for v in rng.normal(1.0, 0.1, 3)), valid, ALL_AXES,
                                temp_c if has_temp else None, b"",
                                accel_g=tuple(float(v) for v in rng.normal(0.0, 0.01, 3)), accel_valid=ALL_AXES,
                                accel_present=ALL_AXES))  # fmt: skip
        t_rx_s.append(rx_s)
    return frames, t_rx_s


def _run(daemon: Daemon, frames: list[Frame], t_rx_s: list[float], sizes: list[int]) -> dict:
    """Every output column over the stream, cut into batches of `sizes` (cycled)."""
    out: dict = {"rows": [], "t_s": [], "comp": {}}
    start = index = 0
    while start < len(frames):
        size = sizes[index % len(sizes)]
        batch = daemon.compensate(frames[start : start + size], t_rx_s[start : start + size])
        out["rows"] += [start + row for row in batch.rate_rows]
        out["t_s"] += np.asarray(batch.t_s, dtype=np.float64).tolist()
        channels = batch.channels if batch.channels is not None else {"": batch.comp}
        for name, comp in channels.items():
            columns = out["comp"].setdefault(name, [[], [], [], [], []])
            for column, values in zip(columns, (comp.temp_c, comp.temp_rate_cps, comp.comp_dph, comp.rate_comp_dph,
                                                comp.flags)):  # fmt: skip
                column += np.asarray(values).tolist()
        assert batch.comp.comp_dph is channels[next(iter(channels))].comp_dph or batch.channels is None
        start += size
        index += 1
    out["latest"] = daemon.latest
    out["counters"] = daemon.counters
    return out


@pytest.mark.parametrize("channels", CHANNEL_SETS.values(), ids=CHANNEL_SETS.keys())
@settings(max_examples=15, deadline=None)
@given(sizes=st.lists(st.integers(1, 40), min_size=1, max_size=6), seed=st.integers(0, 2**16))
def test_any_batching_gives_the_one_at_a_time_output(channels, sizes, seed):
    """Rows, times, temperatures, rates, flags, counters bit for bit; the compensation to the tolerance the
    end-to-end tests hold the daemon to against fogd-replay (the kernel's sums run in another order)."""
    frames, t_rx_s = _stream(300, seed)
    one = _run(_daemon(channels), frames, t_rx_s, [1])
    batched = _run(_daemon(channels), frames, t_rx_s, sizes)
    assert len(one["rows"]) == len(frames) - len(range(4, len(frames), 9))
    assert (batched["rows"], repr(batched["t_s"]), batched["counters"]) == (one["rows"], repr(one["t_s"]), one["counters"])
    assert batched["comp"].keys() == one["comp"].keys()
    for name, columns in one["comp"].items():
        got = batched["comp"][name]
        assert repr([got[0], got[1], got[4]]) == repr([columns[0], columns[1], columns[4]]), name  # NaN where NaN
        assert any(columns[4]) and len(set(columns[4])) > 2, "flags of several kinds (warm-up, invalid, stale)"
        for want, have in ((columns[2], got[2]), (columns[3], got[3])):
            np.testing.assert_allclose(have, want, rtol=1e-9, atol=1e-12, equal_nan=True, err_msg=name)
    latest, want = batched["latest"], one["latest"]
    assert (repr(latest.temp_c), latest.flags, repr(latest.rate_dph)) == (repr(want.temp_c), want.flags, repr(want.rate_dph))
    assert (latest.channels is None) == (channels is None)
    assert latest.comp_dph == pytest.approx(want.comp_dph, rel=1e-9, abs=1e-12)


def test_a_drain_takes_every_frame_in_the_ring_through_the_formatter_in_order():
    """`_drain` (the loop after a wake, and at stop after the reader has ended) pops until the ring is empty,
    MAX_BATCH frames at most a batch: more than two batches' worth, pushed as reads of 7 frames, all reach
    the writer in order, each rate frame re-encoded with a good CRC."""
    protocol = KvhProtocol(comp_axes=(2,))
    count = 2 * MAX_BATCH + 300
    raws = [protocol.encode(Frame("kvh-a", "imu", "A", i % 128, None, (1.0, -2.0, 15.0 + 1e-3 * i), ALL_AXES,
                                  ALL_AXES, 20.0 + i // 500)) for i in range(count)]  # fmt: skip
    lexer, ring = Lexer(protocol), Ring(1 << 14)
    for start in range(0, count, 7):
        ring.push(lexer.feed(b"".join(raws[start : start + 7])), 1.0)
    model = modelfile.from_document(DEMO)
    writer = Writer(open_sink(os.devnull, 921600), queue_chunks=64)  # not started: submit queues every chunk
    daemon = Daemon(reader=SimpleNamespace(ring=ring), writer=writer, formatter=Formatter("same", protocol, 2),
                    model=model, rate_hz=1000.0, axis=2, temp_stale_s=2.0, status_interval_s=60.0)  # fmt: skip
    daemon._drain()
    assert len(ring) == 0 and daemon.counters.records_popped == writer.counters.frames_submitted == count
    chunks = [writer._queue.get_nowait() for _ in range(writer._queue.qsize())]
    assert len(chunks) == 3 and all(len(chunk.frame_ends) <= MAX_BATCH for chunk in chunks)
    out = Lexer(KvhProtocol()).feed(b"".join(chunk.data for chunk in chunks))
    assert [frame.seq for frame in out] == [i % 128 for i in range(count)]  # every frame, in order, CRC good
    assert all(frame.rate_dph[2] != pytest.approx(15.0 + 1e-3 * i, abs=1e-4) for i, frame in enumerate(out))
