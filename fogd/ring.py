"""The ring buffer between the reader thread and the compensation loop: decoded samples in a preallocated
numpy structured array, one producer and one consumer, batches in and batches out.

Each slot holds one decoded frame (`SAMPLE_DTYPE`): what kind it is, its sequence number, device and receive
times, the three rates with their valid/present bits, the temperature, and the raw frame bytes so the
output can re-encode the very frame that came in. The producer never waits: samples that do not fit in a
full ring are dropped and counted as overruns. With one producer and one consumer each index has a single
writer, and the slots are written before the index that publishes them, so no lock is needed.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from fogd.protocols.base import Frame

RAW_SLOT_BYTES = 256  # the longest frame any protocol produces (an ASCII line; fogd frames are <= 255)

KIND_IMU = 1  # rate and temperature in one frame
KIND_RATE = 2
KIND_TEMP = 3
KIND_OTHER = 4  # recognised frames carrying nothing fogd uses (passed through by output format 'same')
KIND_CODES = {"imu": KIND_IMU, "rate": KIND_RATE, "temp": KIND_TEMP}
KIND_NAMES = {KIND_IMU: "imu", KIND_RATE: "rate", KIND_TEMP: "temp", KIND_OTHER: "other"}

SAMPLE_DTYPE = np.dtype(
    [
        ("kind", np.uint8),
        ("message", "S8"),  # the wire message ('A', 'rate', 'dsp3000', ...), for re-encoding
        ("seq", np.int32),  # -1 when the format has no counter
        ("t_dev_s", np.float64),  # device time; NaN when the format has none
        ("t_rx_s", np.float64),  # time.monotonic() when the read that completed the frame returned
        ("rate_dph", np.float64, (3,)),  # NaN for frames without a rate
        ("axis_valid", np.uint8),  # bit i: axis i valid
        ("axis_present", np.uint8),  # bit i: axis i present
        ("temp_c", np.float64),  # NaN when the frame has no temperature (or an invalid one)
        ("has_temp", np.bool_),
        ("raw_len", np.uint16),
        ("raw", np.uint8, (RAW_SLOT_BYTES,)),
    ]
)

_NAN3 = (math.nan, math.nan, math.nan)


def _bits(mask: Sequence[bool]) -> int:
    return (1 if mask[0] else 0) | (2 if mask[1] else 0) | (4 if mask[2] else 0)


def pack_frames(frames: Sequence[Frame], t_rx_s: float) -> np.ndarray:
    """The ring records for one read's frames ('comp' frames are kept as kind 'other': fogd does not
    re-compensate its own output)."""
    n = len(frames)
    batch = np.zeros(n, dtype=SAMPLE_DTYPE)
    if n == 0:
        return batch
    raw = bytearray(n * RAW_SLOT_BYTES)
    kinds, messages, seqs, times, rates, valid, present, temps, has_temp, lengths = ([] for _ in range(10))
    for i, frame in enumerate(frames):
        kinds.append(KIND_CODES.get(frame.kind, KIND_OTHER))
        messages.append(frame.message.encode("ascii", "replace"))
        seqs.append(-1 if frame.seq is None else frame.seq)
        times.append(math.nan if frame.t_s is None else frame.t_s)
        rates.append(frame.rate_dph or _NAN3)
        valid.append(_bits(frame.axis_valid))
        present.append(_bits(frame.axis_present))
        temp = frame.temp_c
        has_temp.append(temp is not None and frame.kind in ("imu", "temp"))
        temps.append(math.nan if temp is None else temp)
        data = frame.raw[:RAW_SLOT_BYTES]
        lengths.append(len(data))
        raw[i * RAW_SLOT_BYTES : i * RAW_SLOT_BYTES + len(data)] = data
    batch["kind"] = kinds
    batch["message"] = messages
    batch["seq"] = seqs
    batch["t_dev_s"] = times
    batch["t_rx_s"] = t_rx_s
    batch["rate_dph"] = rates
    batch["axis_valid"] = valid
    batch["axis_present"] = present
    batch["temp_c"] = temps
    batch["has_temp"] = has_temp
    batch["raw_len"] = lengths
    batch["raw"] = np.frombuffer(raw, dtype=np.uint8).reshape(n, RAW_SLOT_BYTES)
    return batch


def raw_bytes(record: np.void) -> bytes:
    """The frame bytes stored in one ring record."""
    return record["raw"][: record["raw_len"]].tobytes()


def mask(bits: int) -> tuple[bool, bool, bool]:
    """An axis bit mask as the (x, y, z) booleans `Frame` uses."""
    return (bool(bits & 1), bool(bits & 2), bool(bits & 4))


def to_frames(batch: np.ndarray, protocol: str) -> list[Frame]:
    """The `Frame`s ring records came from (enough of each to re-encode it; no compensated fields)."""
    columns = zip(
        batch["kind"].tolist(),
        batch["message"].tolist(),
        batch["seq"].tolist(),
        batch["t_dev_s"].tolist(),
        batch["rate_dph"].tolist(),
        batch["axis_valid"].tolist(),
        batch["axis_present"].tolist(),
        batch["temp_c"].tolist(),
        batch["has_temp"].tolist(),
        batch["raw_len"].tolist(),
    )
    raw = batch["raw"].tobytes()
    frames = []
    for i, (kind, message, seq, t_s, rates, valid, present, temp, has_temp, length) in enumerate(columns):
        name = KIND_NAMES[kind]
        frames.append(
            Frame(
                protocol,
                name,
                message.decode("ascii"),
                None if seq < 0 else seq,
                None if t_s != t_s else t_s,  # NaN: no device time
                tuple(rates) if name in ("imu", "rate") else None,
                mask(valid),
                mask(present),
                temp if has_temp else None,
                raw[i * RAW_SLOT_BYTES : i * RAW_SLOT_BYTES + length],
            )
        )
    return frames


class Ring:
    """Single-producer, single-consumer ring of `dtype` records with a fixed capacity."""

    def __init__(self, capacity: int, dtype: np.dtype = SAMPLE_DTYPE) -> None:
        if capacity < 1:
            raise ValueError(f"ring capacity must be at least 1, not {capacity}")
        self.capacity = capacity
        self._slots = np.zeros(capacity, dtype=dtype)
        self._head = 0  # records ever pushed (written by the producer only)
        self._tail = 0  # records ever popped (written by the consumer only)
        self.overruns = 0  # records dropped because the ring was full (producer only)

    def __len__(self) -> int:
        return self._head - self._tail

    def push(self, batch: np.ndarray) -> int:
        """Append as much of `batch` as fits; the rest is dropped and counted. Returns the number stored."""
        free = self.capacity - (self._head - self._tail)
        count = min(len(batch), free)
        if count < len(batch):
            self.overruns += len(batch) - count
        if count == 0:
            return 0
        start = self._head % self.capacity
        first = min(count, self.capacity - start)
        self._slots[start : start + first] = batch[:first]
        if count > first:  # wrapped
            self._slots[: count - first] = batch[first:count]
        self._head += count  # publish only after the slots are written
        return count

    def pop(self, max_count: int | None = None) -> np.ndarray:
        """Remove and return (a copy of) up to `max_count` of the oldest records, oldest first."""
        count = self._head - self._tail
        if max_count is not None:
            count = min(count, max_count)
        start = self._tail % self.capacity
        first = min(count, self.capacity - start)
        # a copy by slicing, not np.concatenate: promoting a structured dtype costs more than the copy itself
        if count == first:
            out = self._slots[start : start + count].copy()
        else:  # wrapped
            out = np.empty(count, dtype=self._slots.dtype)
            out[:first] = self._slots[start:]
            out[first:] = self._slots[: count - first]
        self._tail += count
        return out
