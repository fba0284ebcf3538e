"""The reader-to-compensator ring: order, wrap-around, overruns, and any interleaving of pushes and pops."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from fogd.protocols import get
from fogd.protocols.base import ALL_AXES, Frame
from fogd.ring import KIND_IMU, KIND_OTHER, KIND_TEMP, SAMPLE_DTYPE, Ring, pack_frames, raw_bytes, to_frames

COUNTER = np.dtype([("value", np.int64)])


def numbered(start: int, count: int) -> np.ndarray:
    batch = np.zeros(count, dtype=COUNTER)
    batch["value"] = np.arange(start, start + count)
    return batch


def test_pop_returns_pushed_records_in_order():
    ring = Ring(8, COUNTER)
    assert ring.push(numbered(0, 5)) == 5
    assert list(ring.pop(3)["value"]) == [0, 1, 2]
    assert list(ring.pop()["value"]) == [3, 4]
    assert len(ring.pop()) == 0


def test_wrap_around_keeps_order():
    ring = Ring(5, COUNTER)
    ring.push(numbered(0, 4))
    ring.pop(3)
    assert ring.push(numbered(4, 4)) == 4  # slots 4, 0, 1, 2
    assert list(ring.pop()["value"]) == [3, 4, 5, 6, 7]


def test_full_ring_drops_the_newest_and_counts_overruns():
    ring = Ring(4, COUNTER)
    assert ring.push(numbered(0, 6)) == 4
    assert ring.overruns == 2
    assert ring.push(numbered(6, 1)) == 0
    assert ring.overruns == 3
    assert list(ring.pop()["value"]) == [0, 1, 2, 3]


def test_popped_batch_is_a_copy_the_producer_cannot_overwrite():
    ring = Ring(2, COUNTER)
    ring.push(numbered(0, 2))
    out = ring.pop()
    ring.push(numbered(10, 2))
    assert list(out["value"]) == [0, 1]


@settings(max_examples=200, deadline=None)
@given(st.integers(1, 16), st.lists(st.tuples(st.booleans(), st.integers(0, 20)), max_size=40))
def test_any_interleaving_loses_nothing_while_not_full(capacity, steps):
    ring = Ring(capacity, COUNTER)
    pushed, popped, next_value = [], [], 0
    for is_push, count in steps:
        if is_push:
            stored = ring.push(numbered(next_value, count))
            assert stored == min(count, capacity - (len(pushed) - len(popped)))
            pushed.extend(range(next_value, next_value + stored))
            next_value += count
        else:
            popped.extend(ring.pop(count)["value"].tolist())
    popped.extend(ring.pop()["value"].tolist())
    assert popped == pushed
    assert ring.overruns == next_value - len(pushed)


def test_pack_frames_keeps_fields_and_raw_bytes():
    kvh = get("kvh-a")
    imu = kvh.decode(kvh.encode(Frame("kvh-a", "imu", "A", 5, None, (1.0, -2.0, 3.0), ALL_AXES, ALL_AXES, 31.0)))
    temp = Frame("fogd", "temp", "temp", 7, 2.5, temp_c=30.5, raw=b"\xf0\x0d\x00")
    other = Frame("kvh-a", "other", "BIT", raw=b"\xfe\x81\x00\xaa")
    batch = pack_frames([imu, temp, other], t_rx_s=12.0)
    assert batch.dtype == SAMPLE_DTYPE
    assert list(batch["kind"]) == [KIND_IMU, KIND_TEMP, KIND_OTHER]
    assert list(batch["seq"]) == [5, 7, -1]
    assert np.isnan(batch["t_dev_s"][0]) and batch["t_dev_s"][1] == 2.5
    assert np.allclose(batch["rate_dph"][0], imu.rate_dph)
    assert batch["axis_valid"][0] == 7 and batch["axis_present"][1] == 0
    assert list(batch["has_temp"]) == [True, True, False]
    assert batch["temp_c"][1] == 30.5
    assert all(batch["t_rx_s"] == 12.0)
    assert [raw_bytes(record) for record in batch] == [imu.raw, temp.raw, other.raw]


def test_to_frames_gives_back_what_reencoding_needs():
    kvh = get("kvh-a")
    frame = kvh.decode(kvh.encode(Frame("kvh-a", "imu", "A", 9, None, (1.0, 2.0, 3.0), ALL_AXES, ALL_AXES, 20.0)))
    (back,) = to_frames(pack_frames([frame], 0.0), "kvh-a")
    assert back == frame
