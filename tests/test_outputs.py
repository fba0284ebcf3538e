"""Output formats round-trip through their own readers; sinks open (or fail in one line); the writer never
blocks its caller and counts what a stuck consumer costs."""

import io
import json
import os
import struct
import threading
import time

import numpy as np
import pytest

from fogd.core.columns import ACCEL_CHANNELS, CHANNELS, GYRO_CHANNELS
from fogd.core.compensator import Compensated, Compensator
from fogd.core.estimator import EstimatorSettings
from fogd.core.frozen import FrozenModel, Linear
from fogd.core.inputs import default_inputs
from fogd.errors import DeviceError
from fogd.protocols import get
from fogd.protocols.base import ALL_AXES, Frame
from fogd.protocols.kvh import DPH_PER_RAD_S
from fogd.protocols.lexer import Lexer
from fogd.serving.channels import ChannelPlan
from fogd.serving.outputs import (
    CSV_COLUMNS,
    Chunk,
    Formatter,
    OutputBatch,
    Writer,
    open_sink,
    rate_rows,
)

RATE_HZ = 100.0
Z = 2


def model() -> FrozenModel:
    return FrozenModel(
        method="linear",
        inputs=default_inputs(EstimatorSettings(window_s=0.2, average_s=0.05)),
        x_mean=np.zeros(2),
        x_scale=np.ones(2),
        y_mean=0.0,
        y_scale=1.0,
        domain_min=np.array([-40.0, -1.0]),
        domain_max=np.array([80.0, 1.0]),
        evaluator=Linear(np.array([0.1, 10.0]), 0.25),
    )


def kvh_batch(n: int = 60) -> tuple[OutputBatch, list[Frame]]:
    """n KVH Format A frames (all axes valid, z rate varies, temperature steps) compensated on z."""
    kvh = get("kvh-a", comp_axes=(Z,))
    frames = []
    for i in range(n):
        rates = (1.5 * DPH_PER_RAD_S * 1e-5, -2.0 * DPH_PER_RAD_S * 1e-5, (i % 7) * DPH_PER_RAD_S * 1e-6)
        wire = Frame("kvh-a", "imu", "A", i % 128, None, rates, ALL_AXES, ALL_AXES, 20.0 + i // 20)
        frames.append(kvh.decode(kvh.encode(wire)))
    rows = rate_rows(frames)
    comp = Compensator(model(), RATE_HZ).process(np.array([frames[i].rate_dph[Z] for i in rows]),
                                                 np.array([frames[i].temp_c for i in rows]))  # fmt: skip
    return OutputBatch(frames, rows, np.arange(len(rows)) / RATE_HZ, comp), frames


def test_csv_parses_to_replay_columns():
    batch, frames = kvh_batch()
    formatter = Formatter("csv", get("kvh-a"), Z)
    text = (formatter.header() + formatter.encode(batch).data).decode()
    header, *lines = text.splitlines()
    assert tuple(header.split(",")) == CSV_COLUMNS
    table = np.loadtxt(io.StringIO("\n".join(lines)), delimiter=",")
    assert table.shape == (len(frames), len(CSV_COLUMNS))
    assert np.allclose(table[:, 1], [frame.rate_dph[Z] for frame in frames], rtol=1e-8)
    assert np.allclose(table[:, 2], [frame.temp_c for frame in frames])
    assert np.allclose(table[:, 4], batch.comp.comp_dph, rtol=1e-8)
    assert np.allclose(table[:, 5], batch.comp.rate_comp_dph, rtol=1e-8, atol=1e-12)
    assert list(table[:, 6].astype(int)) == batch.comp.flags.tolist()


def test_jsonl_is_one_object_per_sample():
    batch, frames = kvh_batch()
    chunk = Formatter("jsonl", get("kvh-a"), Z).encode(batch)
    objects = [json.loads(line) for line in chunk.data.decode().splitlines()]
    assert len(objects) == len(frames) == len(chunk.frame_ends)
    assert [obj["rate_comp_dph"] for obj in objects] == batch.comp.rate_comp_dph.tolist()
    assert [obj["flags"] for obj in objects] == batch.comp.flags.tolist()
    assert set(objects[0]) == set(CSV_COLUMNS)


def test_fogd_frames_decode_with_fogds_own_decoder():
    batch, frames = kvh_batch()
    chunk = Formatter("fogd", get("kvh-a"), Z).encode(batch)
    decoded = Lexer(get("fogd")).feed(chunk.data)
    assert len(decoded) == len(frames)
    assert [frame.seq for frame in decoded] == list(range(len(frames)))
    for out, raw, comp, rate_comp, temp in zip(
        decoded, frames, batch.comp.comp_dph, batch.comp.rate_comp_dph, batch.comp.temp_c
    ):
        assert out.kind == "comp"
        assert out.rate_dph == pytest.approx(raw.rate_dph, rel=1e-6)
        assert out.comp_dph[Z] == pytest.approx(comp, rel=1e-6) and out.comp_dph[:2] == (0.0, 0.0)
        assert out.rate_comp_dph[Z] == pytest.approx(rate_comp, rel=1e-6, abs=1e-6)
        assert out.rate_comp_dph[:2] == pytest.approx(raw.rate_dph[:2], rel=1e-6)
        assert out.temp_c == temp


def test_same_reencodes_kvh_with_compensated_z_and_untouched_x_y():
    batch, frames = kvh_batch()
    chunk = Formatter("same", get("kvh-a", comp_axes=(Z,)), Z).encode(batch)
    assert len(chunk.data) == 36 * len(frames)
    lexer = Lexer(get("kvh-a"))
    decoded = lexer.feed(chunk.data)
    assert lexer.counters.bad_crc == 0 and len(decoded) == len(frames)
    for out, raw, rate_comp in zip(decoded, frames, batch.comp.rate_comp_dph):
        assert out.raw[4:12] == raw.raw[4:12]  # x and y gyro words, byte for byte
        assert out.raw[16:32] == raw.raw[16:32]  # accels, status, sequence, temperature
        wire_z = struct.unpack(">f", struct.pack(">f", rate_comp / DPH_PER_RAD_S))[0] * DPH_PER_RAD_S
        assert out.rate_dph[Z] == wire_z
    assert any(out.raw != raw.raw for out, raw in zip(decoded, frames))


@pytest.mark.parametrize(("gyros", "accels"), [((0, 1, 2), (0, 1, 2)), ((0, 2), (1,)), ((1,), ()), ((0, 1, 2), (2,))])
def test_same_reencodes_exactly_the_covered_channels_of_an_imu_frame(gyros, accels):
    """`same` with a multi-channel model: each covered gyro and accelerometer carries its compensated value
    (float32 on the wire), every other field keeps its bytes; the CRC is fresh."""
    covered = tuple(GYRO_CHANNELS[axis] for axis in gyros) + tuple(ACCEL_CHANNELS[axis] for axis in accels)
    sources = tuple((False, axis) for axis in gyros) + tuple((True, axis) for axis in accels)
    plan = ChannelPlan(covered, sources, tuple(c for c in CHANNELS if c not in covered), CHANNELS, single=False)
    kvh = get("kvh-a", comp_axes=gyros, comp_accel_axes=accels)
    frames = []
    for i in range(12):
        wire = Frame("kvh-a", "imu", "A", i, None, (1e-3 * i, -2e-3, 3e-3), ALL_AXES, ALL_AXES, 20.0,
                     accel_g=(0.01, -0.02 * i, 0.99), accel_valid=ALL_AXES, accel_present=ALL_AXES)  # fmt: skip
        frames.append(kvh.decode(kvh.encode(wire)))
    rows = rate_rows(frames)
    values = {name: [100.0 * k + j for j in range(len(rows))] for k, name in enumerate(covered)}
    channels = {name: Compensated([20.0] * len(rows), [0.0] * len(rows), [0.0] * len(rows), column, [0] * len(rows))
                for name, column in values.items()}  # fmt: skip
    batch = OutputBatch(frames, rows, np.zeros(len(rows)), channels[covered[0]], channels)
    decoded = Lexer(get("kvh-a")).feed(Formatter("same", kvh, Z, plan).encode(batch).data)
    assert len(decoded) == len(frames)
    for j, (out, raw) in enumerate(zip(decoded, frames)):
        for name, offset, scale in [(GYRO_CHANNELS[a], 4 + 4 * a, DPH_PER_RAD_S) for a in range(3)] + [
                (ACCEL_CHANNELS[a], 16 + 4 * a, 1.0) for a in range(3)]:  # fmt: skip
            field = out.raw[offset : offset + 4]
            if name in values:
                assert field == struct.pack(">f", values[name][j] / scale), name
            else:
                assert field == raw.raw[offset : offset + 4], name
        assert out.raw[28:32] == raw.raw[28:32]  # status, sequence, temperature


def test_same_passes_frames_without_a_rate_through():
    fogd = get("fogd", comp_axes=(Z,))
    temp = fogd.decode(fogd.encode(Frame("fogd", "temp", "temp", 1, 0.5, temp_c=25.0)))
    rate = fogd.decode(fogd.encode(Frame("fogd", "rate", "rate", 1, 0.5, (0.0, 0.0, 3.0), ALL_AXES, ALL_AXES)))
    rows = rate_rows([temp, rate])
    comp = Compensator(model(), RATE_HZ).process(np.array([3.0]), np.array([25.0]))
    chunk = Formatter("same", fogd, Z).encode(OutputBatch([temp, rate], rows, np.zeros(1), comp))
    out = Lexer(fogd).feed(chunk.data)
    assert out[0].raw == temp.raw
    assert out[1].rate_dph[Z] == pytest.approx(comp.rate_comp_dph[0], rel=1e-6)
    assert len(chunk.frame_ends) == 2


def test_pty_sink_links_a_pty_a_reader_can_open(tmp_path):
    link = tmp_path / "run" / "fog0"
    sink = open_sink(f"pty:{link}", 921600)
    try:
        assert link.is_symlink()
        reader = os.open(link, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
        try:
            assert sink.write(b"hello fog\n", 1.0) == 10
            time.sleep(0.05)
            assert os.read(reader, 100) == b"hello fog\n"
        finally:
            os.close(reader)
    finally:
        sink.close()
    assert not link.exists()


def test_pty_sink_refuses_to_replace_a_real_file(tmp_path):
    target = tmp_path / "fog0"
    target.write_text("keep me")
    with pytest.raises(DeviceError, match="not a symlink"):
        open_sink(f"pty:{target}", 921600)
    assert target.read_text() == "keep me"


@pytest.mark.parametrize("where", ["directory", "missing-parent"])
def test_unopenable_output_is_a_one_line_device_error(tmp_path, where):
    path = tmp_path if where == "directory" else tmp_path / "no" / "such" / "dir" / "out.csv"
    with pytest.raises(DeviceError) as error:
        open_sink(str(path), 921600)
    assert "\n" not in str(error.value) and str(path) in str(error.value)


def test_file_sink_writes_everything(tmp_path):
    path = tmp_path / "out.bin"
    writer = Writer(open_sink(str(path), 921600))
    writer.start(b"head\n")
    for i in range(10):
        writer.submit(Chunk(b"x" * 100, [50, 100]))
    assert writer.close(2.0)
    assert path.read_bytes() == b"head\n" + b"x" * 1000
    assert writer.counters.frames_written == 20


def test_stuck_consumer_is_counted_and_never_blocks_the_caller(tmp_path):
    link = tmp_path / "never-reads"
    sink = open_sink(f"pty:{link}", 921600)
    stuck = os.open(link, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)  # holds the pty open, reads nothing
    writer = Writer(sink, queue_chunks=4, write_timeout_s=0.05)
    writer.start()
    started = time.monotonic()
    for _ in range(200):
        writer.submit(Chunk(b"\x55" * 36_000, list(range(36, 36_001, 36))))
    assert time.monotonic() - started < 200 * writer.write_timeout_s / 2  # blocking, each would wait out a timeout
    writer.close(1.0)
    os.close(stuck)
    counters = writer.counters
    assert counters.frames_dropped_full > 0 and counters.frames_dropped_timeout > 0
    total = (
        counters.frames_written + counters.frames_dropped_full + counters.frames_dropped_timeout
        + counters.frames_dropped_exit + counters.frames_cut + counters.frames_pending
    )
    assert total == counters.frames_submitted == 200 * 1000


def test_direct_and_queued_writes_keep_the_order_and_count_every_frame(tmp_path):
    """An idle writer lets `submit` write at once; what the consumer does not take goes through the queue.
    A slow reader sees every byte in order and every frame is counted written."""
    link = tmp_path / "slow"
    sink = open_sink(f"pty:{link}", 921600)
    reader_fd = os.open(link, os.O_RDONLY | os.O_NOCTTY)
    received = bytearray()
    chunks = [bytes([i % 251]) * (36 * (1 + i % 50)) for i in range(400)]
    expected = b"".join(chunks)

    def read_slowly():
        time.sleep(0.3)  # the pty fills: writes are partial and the rest is queued
        while len(received) < len(expected):
            received.extend(os.read(reader_fd, 4096))
            time.sleep(0.0005)

    thread = threading.Thread(target=read_slowly)
    thread.start()
    writer = Writer(sink, queue_chunks=10_000, write_timeout_s=5.0)
    writer.start()
    for chunk in chunks:
        writer.submit(Chunk(chunk, list(range(36, len(chunk) + 1, 36))))
        time.sleep(0.0002)
    queued = writer._queued
    thread.join(20.0)  # (closing the writer closes the pty, and a pty drops what its reader has not read)
    assert writer.close(1.0)
    os.close(reader_fd)
    assert bytes(received) == expected
    assert writer.counters.frames_written == len(expected) // 36
    assert writer.counters.frames_dropped_full == writer.counters.frames_dropped_timeout == 0
    assert 0 < queued < len(chunks)  # both paths were taken


def numbered_frames(first: int, count: int) -> Chunk:
    """`count` JSON lines of 59 bytes, numbered from `first` (an odd length: a pty's buffer ends mid-frame)."""
    lines = [f'{{"n":"{n:012d}","pad":"{"x" * 29}"}}\n'.encode() for n in range(first, first + count)]
    ends = list(np.cumsum([len(line) for line in lines]))
    return Chunk(b"".join(lines), [int(end) for end in ends])


def test_a_consumer_stalling_mid_frame_never_gets_a_cut_frame(tmp_path):
    """Issue 11.1: a write timeout mid-frame used to leave the frame's head on the wire, glued to the next
    frame. Every line the consumer gets is whole, and every frame submitted is counted exactly once."""
    link = tmp_path / "stalling"
    sink = open_sink(f"pty:{link}", 921600)
    reader_fd = os.open(link, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
    received = bytearray()
    resume = threading.Event()

    def read_after_stall():
        resume.wait(20.0)
        idle_since = time.monotonic()
        while time.monotonic() - idle_since < 1.0:
            try:
                data = os.read(reader_fd, 65536)
            except BlockingIOError:
                time.sleep(0.01)
                continue
            received.extend(data)
            idle_since = time.monotonic()

    thread = threading.Thread(target=read_after_stall)
    thread.start()
    writer = Writer(sink, queue_chunks=8, write_timeout_s=0.02)
    writer.start()
    submitted = 0
    for round_ in range(60):
        writer.submit(numbered_frames(submitted, 50))
        submitted += 50
        time.sleep(0.01)
        if round_ == 40:
            resume.set()  # the consumer comes back; the writer first finishes the frame it was cut in
    thread.join(30.0)
    counters = writer.counters
    assert writer.close(2.0)
    os.close(reader_fd)
    lines = bytes(received).split(b"\n")
    assert lines[-1] == b""
    numbers = [int(json.loads(line)["n"]) for line in lines[:-1]]  # a cut line would not parse
    assert numbers == sorted(numbers) and len(set(numbers)) == len(numbers)
    assert counters.frames_dropped_timeout > 0  # the stall did cost frames
    assert counters.frames_written == len(numbers)
    assert counters.frames_submitted == submitted == (
        counters.frames_written + counters.frames_dropped_full + counters.frames_dropped_timeout
        + counters.frames_dropped_error + counters.frames_dropped_exit + counters.frames_cut + counters.frames_pending
    )


class FullDisk:
    """A sink over a real file that takes `capacity` bytes and then fails like a full disk (ENOSPC)."""

    def __init__(self, path, capacity: int) -> None:
        from fogd.serving.outputs import Sink

        self.fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        self.sink = Sink(str(path), self.fd, blocking=True, on_close=lambda: os.close(self.fd))
        self.capacity = capacity
        real_write = os.write

        def write(fd, data):
            if fd != self.fd:
                return real_write(fd, data)
            room = self.capacity - os.lseek(fd, 0, os.SEEK_CUR)
            if room <= 0:
                raise OSError(28, os.strerror(28))
            return real_write(fd, bytes(data[:room]))

        self.write = write


def test_a_full_disk_leaves_whole_frames_and_counts_them(tmp_path, monkeypatch):
    """Issue 11.2/11.4: on a full disk the file held more frames than were counted, and a cut one. Now the
    file holds whole frames only, exactly as many as counted written."""
    disk = FullDisk(tmp_path / "out.jsonl", capacity=10_000)
    monkeypatch.setattr("fogd.serving.outputs.os.write", disk.write)
    writer = Writer(disk.sink)
    writer.start()
    for first in range(0, 1000, 100):
        writer.submit(numbered_frames(first, 100))
    assert writer.close(2.0)
    data = (tmp_path / "out.jsonl").read_bytes()
    lines = data.split(b"\n")
    assert lines[-1] == b"" and all(json.loads(line) for line in lines[:-1])
    counters = writer.counters
    assert counters.frames_written == len(lines) - 1 == 10_000 // len(lines[0] + b"\n")
    assert counters.frames_written + counters.frames_dropped_error == counters.frames_submitted == 1000
