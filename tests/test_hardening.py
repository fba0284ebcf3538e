"""Issue 11 (hardening), parsers and loaders: every case found from outside with crafted inputs, each
reproduced here, and bounded fuzz tests of every protocol's lexer and encoders. The cases that need the real
daemon are in test_hardening_e2e.py."""

from __future__ import annotations

import json
import math
import os
import struct
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fogd.cli import replay as replay_cli
from fogd.cli import train as train_cli
from fogd.core import modelfile
from fogd.core.atomic import read_regular, replaced
from fogd.core.compensator import Compensator
from fogd.core.estimator import EstimatorSettings
from fogd.core.inputs import default_inputs
from fogd.core.runio import read_run
from fogd.errors import ConfigError, ModelFileError, OutputError, UsageError
from fogd.protocols import get
from fogd.protocols.ascii import checksum
from fogd.protocols.base import ALL_AXES, Frame
from fogd.protocols.crc import crc16_ccitt_false, crc32_mpeg2
from fogd.protocols.fogdbin import FRAME_LENGTHS as FOGD_LENGTHS
from fogd.protocols.kvh import HEADER_A
from fogd.protocols.lexer import Lexer
from fogd.serving import config
from fogd.serving.outputs import OUT_FORMATS, Formatter, OutputBatch, rate_rows

FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def model_document(**overrides) -> dict:
    doc = modelfile.document(
        name="hard", method="linear", inputs=default_inputs(EstimatorSettings(window_s=0.5, average_s=0.05)),
        x_mean=np.zeros(2), x_scale=np.ones(2), y_mean=0.0, y_scale=1.0,
        domain_min=np.array([-40.0, -5.0]), domain_max=np.array([80.0, 5.0]),
        params={"coef": [0.05, 30.0], "intercept": 0.5}, reference_dph=0.0, training={}, metrics={},
        created_utc="2024-01-01T00:00:00Z",
    )  # fmt: skip
    doc.update(overrides)
    return doc


def write_model(path: Path, doc: dict) -> Path:
    path.write_text(json.dumps(doc))
    return path


# 1-2. Files are sacred -------------------------------------------------------------------------------------------


def write_small_run(path: Path, rows: int = 400) -> Path:
    t = np.arange(rows) / 10.0
    lines = ["t_s,rate_dph,temp_c"] + [f"{a:.1f},{0.01 * np.sin(a)!r},{20 + a / 100:.4f}" for a in t]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize("through_symlink", [False, True])
def test_replay_refuses_to_write_over_its_own_input(tmp_path, capsys, through_symlink):
    """Issue 11.2: `fogd-replay m.json run.csv -o run.csv` replaced its own input (also through a symlink)."""
    run = write_small_run(tmp_path / "run.csv")
    model = write_model(tmp_path / "m.json", model_document())
    before = run.read_bytes()
    output = run
    if through_symlink:
        output = tmp_path / "link.csv"
        output.symlink_to(run)
    status = replay_cli.main([str(model), str(run), "-o", str(output)])
    assert status != 0 and "refusing to overwrite an input" in capsys.readouterr().err
    assert run.read_bytes() == before


def test_train_refuses_to_write_the_model_over_a_calibration_run(tmp_path, capsys):
    run = write_small_run(tmp_path / "run.csv")
    before = run.read_bytes()
    assert train_cli.main([str(run), "-o", str(run)]) != 0
    assert "refusing to overwrite an input" in capsys.readouterr().err
    assert run.read_bytes() == before


def test_a_model_write_that_fails_leaves_the_old_model_whole(tmp_path, monkeypatch):
    """Issue 11.2: on a full disk a model written over an old one left it truncated (4096 bytes)."""
    path = tmp_path / "model.json"
    modelfile.save(path, model_document(name="old"))
    def disk_full(fd: int) -> None:  # a full disk surfaces at fsync at the latest (delayed allocation)
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", disk_full)
    with pytest.raises(OutputError, match=f"cannot write {path}: No space left") as raised:  # 14: 74, with the path
        modelfile.save(path, model_document(name="new", training={"notes": "x" * 100_000}))
    assert raised.value.exit_status == 74
    monkeypatch.undo()
    assert modelfile.load(path).name == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.json"]  # no temporary file left behind


def test_replaced_keeps_the_old_files_permissions_and_replaces_a_symlinks_target(tmp_path):
    target = tmp_path / "real.csv"
    target.write_text("old\n")
    target.chmod(0o640)
    link = tmp_path / "link.csv"
    link.symlink_to(target)
    with replaced(str(link)) as stream:
        stream.write("new\n")
    assert link.is_symlink() and target.read_text() == "new\n"
    assert target.stat().st_mode & 0o777 == 0o640


# 3. ASCII checksum and plausibility ---------------------------------------------------------------------------------


def test_fogd_ascii_lines_carry_a_checksum_that_catches_every_single_bit_flip():
    """Issue 11.3: with bit flips, -0.0744 read as -4.0744 deg/h with no flag. Every single-bit flip of a
    checksummed line is now rejected (bad_crc, or bad_line when it stops being a line), including a '*' flipped
    into a newline, which leaves a line without its checksum: once a sender sends them, one is required."""
    ascii_ = get("ascii")
    line = ascii_.encode(Frame("ascii", "imu", "I", None, 5.024, (np.nan, np.nan, -0.0744), (False, False, True),
                               (False, False, True), 21.5))  # fmt: skip
    assert b"*" + checksum(line[: line.index(b"*")]) in line
    for position in range(len(line) - 1):  # not the newline: a flipped newline is another framing
        for bit in range(8):
            flipped = bytearray(line)
            flipped[position] ^= 1 << bit
            lexer = Lexer(get("ascii"))
            frames = lexer.feed(line + bytes(flipped)) + lexer.flush()  # the sender's lines carry checksums
            assert [f.raw for f in frames if f.kind == "imu"] == [line], (position, bit, bytes(flipped))
            assert lexer.counters.bad_crc + lexer.counters.bad_line >= 1


def test_a_line_without_a_checksum_is_still_read():
    frame = get("ascii").decode(b"R,1.0,-0.0744\n")
    assert frame.rate_dph[2] == -0.0744 and frame.axis_valid[2]


def test_plausibility_check_flags_a_spike_and_follows_a_real_step():
    """Issue 11.3: DSP-3000 lines have no checksum; a jump beyond max_jump_dph from both the previous and the
    last accepted rate is flagged (axis invalid, counted), a real step costs one sample."""
    lexer = Lexer(get("ascii", max_jump_dph=1.0))
    rates_dps = [0.0001, 0.0002, 0.0011 + 1.0, 0.0001, 0.0002, 0.5, 0.5001, 0.5002]  # a spike, then a step
    lines = b"".join(f"{rate:15.6f}   1\r\n".encode() for rate in rates_dps)
    frames = lexer.feed(lines)
    valid = [frame.axis_valid[2] for frame in frames]
    assert valid == [True, True, False, True, True, False, True, True]
    assert lexer.counters.implausible == 2
    unchecked = Lexer(get("ascii")).feed(lines)
    assert all(frame.axis_valid[2] for frame in unchecked)  # off by default: nothing flagged


# 4. The lexer's counters add up ---------------------------------------------------------------------------------


def fogd_frame(frame_type: int, seq: int, time_us: int, payload: bytes) -> bytes:
    body = struct.pack(">2sBBHQ", b"\xf0\x0d", frame_type, 14 + len(payload) + 2, seq, time_us) + payload
    return body + struct.pack(">H", crc16_ccitt_false(body))


def rate_frame(seq: int, time_us: int = 1000, rate: float = 1.0) -> bytes:
    return fogd_frame(1, seq, time_us, struct.pack(">3fB", 0.0, 0.0, rate, 0x74))


def test_garbage_bytes_count_what_is_held_at_stop():
    """Issue 11.4: the lexer's garbage_bytes missed the last held byte at stop."""
    lexer = Lexer(get("fogd"))
    data = rate_frame(0) + rate_frame(1) + b"\xf0"
    lexer.feed(data)
    lexer.flush()
    counters = lexer.counters
    assert counters.frame_bytes + counters.garbage_bytes == len(data) and lexer.buffered == 0


def test_sequence_tracking_restarts_after_a_lost_port():
    """Issue 11.4: a KVH unplug that lost 511 frames (4 x 128 - 1) counted seq_repeats and no loss: a gap of
    unknown length is no repeat."""
    kvh = get("kvh-a")

    def frame(seq: int) -> bytes:
        return kvh.encode(Frame("kvh-a", "imu", "A", seq, None, (0.0, 0.0, 1.0), ALL_AXES, ALL_AXES, 20.0))

    lexer = Lexer(kvh)
    lexer.feed(frame(5) + frame(6))
    lexer.flush()  # the reader lost the port
    lexer.feed(frame(6 + 512 % 128) + frame(7 + 512 % 128))  # seq 6 again: 511 frames later
    counters = lexer.counters
    assert (counters.seq_repeats, counters.seq_gaps, counters.seq_resets) == (0, 0, 1)


@FUZZ
@given(st.lists(st.one_of(st.binary(max_size=40), st.integers(0, 2**16 - 1).map(rate_frame)), max_size=30),
       st.integers(1, 64))  # fmt: skip
def test_fuzz_bytes_in_equal_frame_bytes_garbage_and_buffered(pieces, read_size):
    data = b"".join(pieces)
    for name in ("fogd", "kvh-a", "ascii"):
        lexer = Lexer(get(name))
        for start in range(0, len(data), read_size):
            lexer.feed(data[start : start + read_size])
        counters = lexer.counters
        assert counters.frame_bytes + counters.garbage_bytes + lexer.buffered == len(data)
        lexer.flush()
        assert counters.frame_bytes + counters.garbage_bytes == len(data)


# 5. Any value a decoder accepts is encodable in every output format ----------------------------------------------


def test_crafted_frames_that_killed_the_daemon_are_refused_and_counted():
    """Issue 11.5: ASCII R,inf,2.0 (OverflowError), R,0.002,1e300 (struct error), a fogd rate frame with a
    valid CRC and t_us = 2^64-1."""
    lexer = Lexer(get("ascii"))
    assert lexer.feed(b"R,inf,2.0\nR,0.002,1e300\nR,nan,1.0\nR,0.003,1.0\n")[-1].t_s == 0.003
    assert lexer.counters.bad_line == 3
    lexer = Lexer(get("fogd"))
    frames = lexer.feed(rate_frame(0, time_us=2**64 - 1) + rate_frame(1, time_us=2000))
    assert [frame.seq for frame in frames] == [1] and lexer.counters.bad_value == 1


def compensate_and_encode(frames: list[Frame], protocol_name: str) -> None:
    """Every decoded frame through the compensator and every output format, as the daemon does."""
    rows = rate_rows(frames)
    model = modelfile.from_document(model_document())
    temps = [math.nan if frames[i].temp_c is None else frames[i].temp_c for i in rows]
    comp = Compensator(model, 1000.0).process(np.array([frames[i].rate_dph[2] for i in rows]), np.array(temps))
    batch = OutputBatch(frames, rows, np.arange(len(rows)) / 1000.0, comp)
    for out_format in OUT_FORMATS:
        Formatter(out_format, get(protocol_name), 2).encode(batch)


float32_bits = st.integers(0, 2**32 - 1).map(lambda bits: struct.unpack(">f", struct.pack(">I", bits))[0])


@FUZZ
@given(st.lists(st.tuples(st.tuples(float32_bits, float32_bits, float32_bits), st.integers(0, 255),
                          st.integers(0, 127), st.integers(-32768, 32767)), min_size=1, max_size=8),
       st.binary(max_size=20))  # fmt: skip
def test_fuzz_kvh_any_frame_with_a_good_crc_is_compensated_and_encoded(fields, garbage):
    raw = b""
    for gyro, status, seq, temp in fields:
        body = HEADER_A + struct.pack(">3f3fBBh", *gyro, 0.0, 0.0, 0.0, status, seq, temp)
        raw += garbage + body + struct.pack(">I", crc32_mpeg2(body))
    lexer = Lexer(get("kvh-a"))
    frames = lexer.feed(raw) + lexer.flush()
    assert len([f for f in frames if f.kind == "imu"]) >= len(fields) - (1 if garbage else 0)  # garbage may hide one
    compensate_and_encode(frames, "kvh-a")


@FUZZ
@given(st.lists(st.tuples(st.sampled_from([1, 2, 3, 7]), st.integers(0, 2**16 - 1), st.integers(0, 2**64 - 1),
                          st.binary(min_size=37, max_size=37)), min_size=1, max_size=8))  # fmt: skip
def test_fuzz_fogd_any_frame_with_a_good_crc_is_compensated_and_encoded(fields):
    raw = b""
    for frame_type, seq, time_us, payload in fields:
        size = FOGD_LENGTHS.get(frame_type, 14 + 10 + 2) - 16
        raw += fogd_frame(frame_type, seq, time_us, payload[:size])
    lexer = Lexer(get("fogd"))
    frames = lexer.feed(raw) + lexer.flush()
    compensate_and_encode(frames, "fogd")


number_texts = st.one_of(
    st.floats().map(repr), st.sampled_from(["inf", "-inf", "nan", "1e300", "-1e309", "0", "-0.0", "1" * 400, ""]),
    st.integers(-(10**30), 10**30).map(str),
)


@FUZZ
@given(st.lists(st.one_of(
    st.tuples(st.sampled_from(["R", "T", "I"]), number_texts, number_texts, number_texts).map(
        lambda f: ",".join(f if f[0] == "I" else f[:3])),
    st.tuples(number_texts, st.sampled_from(["0", "1"])).map(lambda f: f"{f[0]:>15}   {f[1]}"),
    st.text(max_size=30),
), min_size=1, max_size=10), st.floats(0.1, 1e6) | st.none())  # fmt: skip
def test_fuzz_ascii_any_line_is_decoded_or_counted_and_what_decodes_is_encoded(lines, jump):
    data = "".join(line + "\n" for line in lines).encode("utf-8", "replace")
    lexer = Lexer(get("ascii", max_jump_dph=jump))
    frames = lexer.feed(data) + lexer.flush()
    counters = lexer.counters
    assert counters.frame_bytes + counters.garbage_bytes == len(data)
    compensate_and_encode(frames, "ascii")


@FUZZ
@given(st.sampled_from(["fogd", "kvh-a", "ascii"]), st.tuples(st.floats(), st.floats(), st.floats()),
       st.floats(), st.floats(0, 1e9), st.integers(0, 1000))  # fmt: skip
def test_fuzz_encoders_give_frames_their_own_lexer_reads_or_a_value_error(name, rates, temp_c, t_s, seq):
    protocol = get(name)
    kind = "imu" if name != "fogd" else "rate"
    frame = Frame(name, kind, "", seq, t_s, rates, ALL_AXES, ALL_AXES if name != "ascii" else (False, False, True), temp_c)
    try:
        raw = protocol.encode(frame)
    except (ValueError, OverflowError):  # e.g. KVH Format A needs a finite whole-degree temperature
        return
    lexer = Lexer(protocol)
    decoded = lexer.feed(raw) + lexer.flush()
    counters = lexer.counters
    assert len(decoded) + counters.bad_line + counters.bad_value == 1


# 6. Models that pass validation must be usable --------------------------------------------------------------------


@pytest.mark.parametrize("change, message", [
    ({"params": {"coef": [1e300, 1e300], "intercept": 0.5}}, "inside its own domain"),
    ({"method": "rbf-nn", "params": {"centres": [[0.0, 0.0]], "width": 1e-300, "coef": [1.0], "intercept": 0.0}},
     "params.width"),
    ({"input_scaling": {"mean": [0.0, 0.0], "scale": [1e-300, 1.0]}}, "input_scaling.scale"),
])  # fmt: skip
def test_models_whose_output_overflows_are_refused_at_load(tmp_path, change, message):
    """Issue 11.6: coefficients of 1e300 overflowed the KVH re-encode, width 1e-300 divided by zero."""
    with pytest.raises(ModelFileError, match=message):
        modelfile.load(write_model(tmp_path / "m.json", model_document(**change)))


def test_an_estimator_window_too_large_for_the_rate_is_refused():
    """Issue 11.6: a window of 86,400 s at 100 kHz asked for 129 GiB."""
    doc = model_document(inputs=[{"kind": "temp_c"}, {"kind": "temp_rate_cps", "window_s": 86400.0,
                                                       "average_s": 1.0, "step_s": 86400.0}])  # fmt: skip
    model = modelfile.from_document(doc)
    with pytest.raises(ModelFileError, match="MiB at 100000 Hz"):
        modelfile.check_rate(model, 100_000.0)
    modelfile.check_rate(model, 1.0)  # the same model at 1 Hz fits


# 7, 11. Loaders: YAML and JSON bounded, duplicate keys refused --------------------------------------------------

ALIAS_BOMB = "\n".join(
    ["a: &a [x, x, x, x, x, x, x, x, x, x]"]
    + [f"{chr(98 + i)}: &{chr(98 + i)} [{', '.join(['*' + chr(97 + i)] * 10)}]" for i in range(8)]
    + ["port: *i"]
)


@pytest.mark.parametrize("text, message", [
    (ALIAS_BOMB, "aliases"),
    ("baud: " + "9" * 5000, "longer than"),
    ("baud: 9600\nbaud: 19200\n", "appears twice"),
    ("port: \"/dev/tty\\nWATCHDOG=1\"\n", "control character"),
])  # fmt: skip
def test_hostile_configs_are_one_line_config_errors(tmp_path, text, message):
    """Issue 11.7/11.10/11.11: an alias bomb hung start-up, a 5000-digit integer gave a traceback, duplicate
    keys took the last value, a newline in a string forged log lines."""
    path = tmp_path / "fogd.yaml"
    path.write_text(text)
    started = time.monotonic()
    with pytest.raises(ConfigError, match=message) as error:
        config.load(str(path))
    assert time.monotonic() - started < 5.0
    assert "\n" not in str(error.value) and len(str(error.value)) < 400


def test_duplicate_json_keys_are_refused_in_a_model(tmp_path):
    path = tmp_path / "m.json"
    text = json.dumps(model_document())
    path.write_text(text[:-1] + ', "name": "other"}')
    with pytest.raises(ModelFileError, match="appears twice"):
        modelfile.load(path)


def test_control_characters_in_a_models_strings_are_refused(tmp_path):
    """Issue 11.10: a model named "m\\nWATCHDOG=1" put WATCHDOG=1 in every STATUS= datagram."""
    for doc in (model_document(name="m\nWATCHDOG=1"), model_document(training={"runs": ["a\x1b[2Jb.csv"]})):
        with pytest.raises(ModelFileError, match="control character"):
            modelfile.load(write_model(tmp_path / "m.json", doc))


# 8. A FIFO is no model or config ------------------------------------------------------------------------------------


def test_a_fifo_as_model_or_config_is_refused_without_blocking(tmp_path):
    """Issue 11.8: a FIFO as the model file blocked start-up forever."""
    fifo = tmp_path / "model.json"
    os.mkfifo(fifo)
    outcome: list[BaseException] = []

    def load() -> None:
        for loader in (modelfile.load, config.load):
            try:
                loader(str(fifo))
            except (ModelFileError, ConfigError) as error:
                outcome.append(error)

    thread = threading.Thread(target=load, daemon=True)
    thread.start()
    thread.join(20.0)
    if thread.is_alive():  # unblock the test's thread before failing
        os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
        pytest.fail("loading a FIFO blocked")
    assert len(outcome) == 2 and all("not a regular file" in str(error) for error in outcome)
    with pytest.raises(OSError):
        read_regular(tmp_path, 10)


# 11. Run CSVs that asked for terabytes ------------------------------------------------------------------------------


@pytest.mark.parametrize("rows, message", [
    ("0,1,20\n1e-9,1,20\n2e-9,1,20\n", "outside 0.001..100000 Hz"),
    ("1e300,1,20\n2e300,1,20\n3e300,1,20\n", "outside 0.001..100000 Hz"),
    ("-1.7e308,1,20\n1.7e308,1,20\n", "outside 0.001..100000 Hz"),
    ("0,1,20\n1," + "1" * 100_000 + ",20\n", "longer than 2048 bytes"),
])  # fmt: skip
def test_runs_that_asked_for_terabytes_are_refused_in_one_line(tmp_path, rows, message):
    """Issue 11.11: nanosecond steps tried to allocate 3.64 TiB, times near 1e300 gave a ValueError, a 1 GB
    line took 6.3 GB."""
    path = tmp_path / "run.csv"
    path.write_text("t_s,rate_dph,temp_c\n" + rows)
    with pytest.raises(Exception, match=message) as error:
        read_run(path)
    assert error.type.__name__ == "InputError"


# 12. A false header holds frames; CRC-16 lets 1 in 65536 through ------------------------------------------------


def test_flush_rescans_frames_held_behind_a_false_header_of_unknown_type():
    """Issue 11.12: a false fogd header of an unknown type held the frames behind it until 255 bytes came,
    and flush dropped them."""
    false_header = b"\xf0\x0d\x09\xff"  # type 9 claims 255 bytes
    real = [rate_frame(seq) for seq in range(5)]
    lexer = Lexer(get("fogd"))
    assert lexer.feed(false_header + b"".join(real)) == []  # held: the candidate is not complete
    recovered = lexer.flush()
    assert [frame.raw for frame in recovered] == real
    assert lexer.counters.frame_bytes + lexer.counters.garbage_bytes == len(false_header) + sum(map(len, real))


def test_frames_of_unknown_type_whose_sequence_does_not_follow_are_suspect():
    lexer = Lexer(get("fogd"))
    other = [fogd_frame(7, seq, 0, b"\x00" * 4) for seq in (10, 11, 12, 500)]
    frames = lexer.feed(b"".join(other))
    assert [frame.kind for frame in frames] == ["other"] * 4
    assert lexer.counters.suspect_frames == 2  # the first of its type, and the jump to 500
