"""A read's one frame on a one-gyro model takes `Daemon._hand_on_one`, the daemon's usual path at real rates: it
must give the same bytes, flags, counters and state as `_hand_on`'s batch path, whatever the frames carry
(Formats A, B with a device clock that can go back, C with its temperature every fourth frame, BIT replies,
invalid and NaN rates, NaN, missing and out-of-range temperatures, stale temperatures), in every output format
and warming mode, cold start or none. Two real daemons, one with the one-row path switched off, are fed the
same reads through the real lexer and reader; their output is a real pipe."""

from __future__ import annotations

import math
import os
import time
from dataclasses import asdict, replace
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st

import fogd
from fogd.core import modelfile
from fogd.protocols.base import ALL_AXES, NO_AXES, Frame
from fogd.protocols.kvh import KvhProtocol, bit_reply
from fogd.protocols.lexer import Lexer
from fogd.serving.daemon import Daemon
from fogd.serving.outputs import Formatter, Sink, Writer
from fogd.serving.reader import Reader
from fogd.serving.ring import Ring
from fogd.serving import thermalstate
from fogd.serving.thermalstate import Thermal

MODEL = modelfile.load(str(Path(fogd.__file__).parent / "data" / "demo-model.json"))
ENCODER = KvhProtocol()


class Rig:
    """A daemon fed one read at a time on the test's thread (the reader's part), writing to a pipe."""

    def __init__(self, out_format: str, warming: str | None, one_row: bool) -> None:
        self.out_r, out_w = os.pipe()
        os.set_blocking(out_w, False)
        protocol = KvhProtocol(comp_axes=(2,))
        self.writer = Writer(Sink("pipe", out_w, blocking=False, on_close=lambda: os.close(out_w)))
        self.reader = Reader(lambda: None, Lexer(protocol), Ring(1 << 12))
        thermal = None if warming is None else Thermal([MODEL], 1000.0, path=None, device="test", warming=warming)
        self.daemon = Daemon(reader=self.reader, writer=self.writer, formatter=Formatter(out_format, protocol, 2),
                             model=MODEL, rate_hz=1000.0, axis=2, temp_stale_s=0.01, status_interval_s=3600.0,
                             thermal=thermal)  # fmt: skip
        assert self.daemon._one_row
        self.daemon._one_row = one_row
        self.daemon.temperature.rx_s = 0.0  # the receive clock is the test's
        self.writer.start(self.daemon.formatter.header())
        self.reader.inline = self.daemon.take_inline

    def read(self, data: bytes, t_rx_s: float, z_absent: bool = False) -> None:
        frames = self.reader.lexer.feed(data)
        if z_absent:  # a stream without the model's axis (no KVH format lacks one: the decoded frame is changed)
            frames = [replace(frame, axis_present=(True, True, False), axis_valid=(True, True, False)) for frame in frames]
        if frames:
            self.reader._push(frames, t_rx_s)

    def finish(self) -> tuple[bytes, dict]:
        assert self.writer.close(5.0)
        chunks = []
        while chunk := os.read(self.out_r, 1 << 16):
            chunks.append(chunk)
        os.close(self.out_r)
        daemon, thermal = self.daemon, self.daemon.thermal
        state = {
            "loop": asdict(daemon.counters),
            "lexer": asdict(self.reader.lexer.counters),
            "writer": asdict(self.writer.counters),
            "latest": repr(daemon.latest),  # (repr: NaN equals NaN)
            "seen": (daemon.channels_seen.seen, daemon.channels_seen.first_s),
            "clock": daemon.clock.count,
            "held": (repr(daemon.temperature.temp_c), daemon.temperature.rx_s),
            "thermal": None if thermal is None else (thermal.history.points(), asdict(thermal.counters), thermal.started,
                                                     thermal.clock, thermal.offset_s),
        }
        return b"".join(chunks), state


TEMPS = st.one_of(st.floats(-60.0, 100.0), st.sampled_from([math.nan, 200.0, -100.0]))
RATES = st.one_of(st.floats(-500.0, 500.0), st.sampled_from([math.nan, math.inf, 1e40]))
FRAME = st.tuples(
    st.sampled_from(["A", "A", "A", "B", "C", "BIT"]),
    RATES,
    st.booleans(),  # the z axis valid
    TEMPS,
    st.floats(0.0, 0.02),  # receive gap (s): past temp_stale_s sometimes
    st.floats(-0.002, 0.003),  # device time step (Format B): back sometimes
    st.sampled_from([False, False, False, True]),  # the frame lacks the z axis
)


def _reads(specs: list[tuple]) -> list[tuple[bytes, float, bool]]:
    reads, t_rx_s, t_s = [], 0.0, 1.0
    for seq, (message, rate, valid, temp, gap_s, step_s, z_absent) in enumerate(specs):
        t_rx_s += gap_s
        t_s += step_s
        if message == "BIT":
            reads.append((bit_reply(b"\xff" * 6), t_rx_s, False))
            continue
        z_valid = (True, True, valid)
        frame = Frame("kvh-a", "imu", message, seq, max(t_s, 0.0), (1.0, -2.0, rate), z_valid, ALL_AXES,
                      temp if message == "C" else round(temp) if math.isfinite(temp) else 0)  # fmt: skip
        reads.append((ENCODER.encode(frame), t_rx_s, z_absent))
    return reads


@settings(max_examples=60, deadline=None)
@given(specs=st.lists(FRAME, min_size=1, max_size=40), out_format=st.sampled_from(["same", "fogd", "csv", "jsonl"]),
       warming=st.sampled_from([None, "compensate", "pass", "fallback"]))  # fmt: skip
def test_one_row_path_equals_the_batch_path(specs, out_format, warming):
    reads = _reads(specs)
    results = []
    thermalstate.time = _WallClock()  # the wall clock's offset at a cold start is the same for both daemons
    try:
        for one_row in (True, False):
            rig = Rig(out_format, warming, one_row)
            for data, t_rx_s, z_absent in reads:
                rig.read(data, t_rx_s, z_absent)
            results.append(rig.finish())
    finally:
        thermalstate.time = time
    (fast_bytes, fast_state), (batch_bytes, batch_state) = results
    assert fast_bytes == batch_bytes
    assert fast_state == batch_state
    assert fast_state["loop"]["records_popped"] == len(specs)  # every frame read, BIT replies too


class _WallClock:
    """`time` for fogd.serving.thermalstate with its Unix time fixed."""

    def __getattr__(self, name: str):
        return getattr(time, name)

    @staticmethod
    def time() -> float:
        return 1.8e9


def test_a_frame_that_cannot_be_encoded_is_counted_and_the_next_goes_on():
    """A rate beyond float32 after compensation is re-encoded as infinity (kvh's rule), never a crash; a Format
    A frame with no rate at all (a decoder that accepted it) costs that frame, counted."""
    rig = Rig("same", None, True)
    good = ENCODER.encode(Frame("kvh-a", "imu", "A", 1, None, (0.0, 0.0, 3e38 * 206264.8), ALL_AXES, ALL_AXES, 20))
    rig.read(good, 0.001)
    rig.daemon.take_inline([Frame("kvh-a", "imu", "A", 2, None, None, NO_AXES, NO_AXES, 20.0, b"")], 0.002)
    rig.read(ENCODER.encode(Frame("kvh-a", "imu", "A", 3, None, (0.0, 0.0, 1.0), ALL_AXES, ALL_AXES, 20)), 0.003)
    data, state = rig.finish()
    assert len(data) == 2 * 36
    assert state["loop"]["frames_unencodable"] == 1
    assert state["writer"]["frames_written"] == 2
