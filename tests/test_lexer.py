"""The resynchronising lexer: splits, garbage, false headers, bad CRCs, truncation, sequence counting, memory."""

import math
import random
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fogd.errors import ConfigError
from fogd.protocols import Frame
from fogd.protocols.ascii import AsciiProtocol
from fogd.protocols.fogdbin import FogdProtocol
from fogd.protocols.kvh import KvhProtocol, bit_reply
from fogd.protocols.lexer import Lexer

KVH = KvhProtocol()
FOGD = FogdProtocol()
ALL = (True, True, True)
HEADER_A = b"\xfe\x81\xff\x55"


def kvh_frame(seq: int, message: str = "A", rate_x_dph: float | None = None, valid=ALL, temp_c: float = 21.0) -> bytes:
    rate = (seq * 0.5 if rate_x_dph is None else rate_x_dph, -0.25 * seq, 1.0 + seq)
    return KVH.encode(Frame("kvh-a", "imu", message, seq % 128, seq * 1e-3, rate, valid, ALL, temp_c))


def kvh_stream(count: int, first_seq: int = 0) -> list[bytes]:
    return [kvh_frame(first_seq + i) for i in range(count)]


def fogd_stream(count: int) -> list[bytes]:
    frames = []
    for i in range(count):
        if i % 3 == 2:
            frames.append(FOGD.encode(Frame("fogd", "temp", seq=i // 3, t_s=i * 0.01, temp_c=20.0 + i / 8)))
        else:
            frames.append(FOGD.encode(Frame("fogd", "rate", seq=i - i // 3, t_s=i * 0.01, rate_dph=(0.0, 0.0, i * 1.5),
                                            axis_valid=(False, False, True), axis_present=(False, False, True))))
    return frames


def feed_all(lexer: Lexer, chunks) -> list[bytes]:
    return [frame.raw for chunk in chunks for frame in lexer.feed(chunk)]


def test_clean_stream_gives_every_frame_and_no_drops():
    frames = kvh_stream(50)
    lexer = Lexer(KVH)
    assert feed_all(lexer, [b"".join(frames)]) == frames
    counters = lexer.counters.as_dict()
    assert counters.pop("frames_ok") == 50
    assert counters.pop("frame_bytes") == sum(map(len, frames))
    assert set(counters.values()) == {0}


@settings(max_examples=50)
@given(cuts=st.lists(st.integers(0, 40 * 36), max_size=30), protocol=st.sampled_from(["kvh", "fogd"]))
def test_random_splits_give_exactly_the_frames_in_order(cuts, protocol):
    frames = kvh_stream(40) if protocol == "kvh" else fogd_stream(40)
    stream = b"".join(frames)
    bounds = [0, *sorted(cuts), len(stream)]
    lexer = Lexer(KVH if protocol == "kvh" else FOGD)
    assert feed_all(lexer, [stream[a:b] for a, b in zip(bounds, bounds[1:])]) == frames
    assert lexer.counters.garbage_bytes == 0 and lexer.buffered == 0


def test_one_byte_at_a_time_equals_all_at_once():
    stream = b"xx\xfe\x81" + b"".join(kvh_stream(5)) + b"\xfe\x81\xff\x55\x00" + bit_reply(bytes(6)) + kvh_frame(5, "B")
    whole, bytewise = Lexer(KVH), Lexer(KVH)
    assert feed_all(bytewise, [stream[i : i + 1] for i in range(len(stream))]) == feed_all(whole, [stream])
    assert whole.counters == bytewise.counters
    assert whole.counters.frames_ok == 6 and whole.counters.other_frames == 1


def _damaged(frame: bytes) -> bytes:
    return frame[:20] + bytes([frame[20] ^ 0x10]) + frame[21:]


KVH_READS = st.lists(
    st.sampled_from(["good", "repeat", "invalid", "nan", "bad_crc", "B", "bit", "garbage"]), min_size=1, max_size=40
)


@settings(max_examples=80)
@given(reads=KVH_READS)
def test_reads_of_one_frame_each_equal_the_whole_stream_at_once(reads):
    """The usual read is one whole frame with nothing held back (the lexer's shortcut); any mix of such reads
    with damaged, repeated, invalid and other frames and garbage gives the frames and counters of one read."""
    chunks, seq = [], 0
    for kind in reads:
        seq += kind != "repeat"
        chunks.append({
            "good": lambda: kvh_frame(seq), "repeat": lambda: kvh_frame(seq), "B": lambda: kvh_frame(seq, "B"),
            "invalid": lambda: kvh_frame(seq, valid=(True, False, True)), "nan": lambda: kvh_frame(seq, rate_x_dph=math.nan),
            "bad_crc": lambda: _damaged(kvh_frame(seq)), "bit": lambda: bit_reply(bytes(6)), "garbage": lambda: b"\xfe\x81\x00",
        }[kind]())  # fmt: skip
    whole, each = Lexer(KVH), Lexer(KVH)
    got_whole = [(f.raw, f.flags, f.axis_valid) for f in whole.feed(b"".join(chunks))]
    got_each = [(f.raw, f.flags, f.axis_valid) for chunk in chunks for f in each.feed(chunk)]
    assert got_each == got_whole
    assert each.counters == whole.counters and each.buffered == whole.buffered
    assert whole.counters.frames_ok == sum(kind in ("good", "repeat", "invalid", "nan", "B") for kind in reads)


# Bytes that make false KVH A/B/C headers. BIT headers are left out: their 8-bit checksum lets one false
# BIT header in 256 pass and swallow the start of the next frame, a weakness of the KVH format itself.
KVH_GARBAGE = st.lists(
    st.sampled_from([b"\xfe", b"\x81", b"\xff", b"\x55", b"\x57", b"\x00", b"\x42", HEADER_A, b"\xfe\x81\xff\x56"]),
    max_size=12,
).map(b"".join)


@settings(max_examples=60)
@given(garbage=st.lists(KVH_GARBAGE | st.binary(max_size=40), min_size=21, max_size=21), chunk=st.integers(1, 200))
def test_garbage_between_frames_never_loses_a_frame_and_is_counted(garbage, chunk):
    frames = kvh_stream(20)
    stream = b"".join(g + f for g, f in zip(garbage, frames + [b""]))
    lexer = Lexer(KVH)
    got = feed_all(lexer, [stream[i : i + chunk] for i in range(0, len(stream), chunk)])
    lexer.flush()
    assert got == frames
    assert lexer.counters.garbage_bytes == sum(map(len, garbage))
    assert lexer.counters.frames_missing == 0


@settings(max_examples=60)
@given(index=st.integers(0, 9), byte=st.integers(4, 35), bit=st.integers(0, 7))
def test_a_flipped_bit_drops_only_that_frame(index, byte, bit):
    frames = kvh_stream(10)
    damaged = bytearray(frames[index])
    damaged[byte] ^= 1 << bit
    lexer = Lexer(KVH)
    got = feed_all(lexer, [b"".join(frames[:index]) + bytes(damaged) + b"".join(frames[index + 1 :])])
    assert got == frames[:index] + frames[index + 1 :]
    assert lexer.counters.bad_crc + lexer.counters.truncated >= 1
    assert lexer.counters.frames_missing == (1 if 0 < index < 9 else 0)


def test_a_flipped_payload_bit_counts_as_bad_crc():
    frames = kvh_stream(10)
    damaged = bytearray(frames[4])
    damaged[10] ^= 0x10
    lexer = Lexer(KVH)
    assert feed_all(lexer, [b"".join(frames[:4]) + bytes(damaged) + b"".join(frames[5:])]) == frames[:4] + frames[5:]
    counters = lexer.counters
    assert (counters.bad_crc, counters.truncated, counters.garbage_bytes) == (1, 0, 36)
    assert (counters.seq_gaps, counters.frames_missing) == (1, 1)


def test_false_header_in_garbage_right_before_a_real_frame():
    frames = kvh_stream(3)
    lexer = Lexer(KVH)
    assert feed_all(lexer, [b"\x12" + HEADER_A + b"\x00\x01\x02\x03\x04" + b"".join(frames)]) == frames
    assert (lexer.counters.truncated, lexer.counters.bad_crc, lexer.counters.garbage_bytes) == (1, 0, 10)


def test_truncated_frame_then_a_good_one():
    frames = kvh_stream(3)
    lexer = Lexer(KVH)
    assert feed_all(lexer, [frames[0] + frames[1][:20] + frames[2]]) == [frames[0], frames[2]]
    assert (lexer.counters.truncated, lexer.counters.bad_crc, lexer.counters.garbage_bytes) == (1, 0, 20)


def test_header_pattern_inside_a_valid_payload_does_not_missync():
    (false_rate_x,) = struct.unpack(">f", HEADER_A)
    tricky = kvh_frame(1, rate_x_dph=false_rate_x * KVH.dph_per_unit)
    assert tricky[4:8] == HEADER_A
    frames = [kvh_frame(0), tricky, kvh_frame(2), kvh_frame(3)]
    lexer = Lexer(KVH)
    assert feed_all(lexer, [b"".join(frames)]) == frames
    # Joining mid-frame, just before the inner header: the false candidate fails and the next real frame is found.
    late = Lexer(KVH)
    assert feed_all(late, [tricky[2:] + frames[2] + frames[3]]) == frames[2:]
    assert late.counters.truncated == 1


def test_formats_b_c_and_bit_interleaved_with_a_never_missync():
    frames = [
        kvh_frame(0), kvh_frame(1, "B"), kvh_frame(2), kvh_frame(3, "C"), bit_reply(bytes([0x7F] * 6)), kvh_frame(4, "C"),
        kvh_frame(5), bit_reply(bytes([0x7F] * 8)), kvh_frame(6, "B"), kvh_frame(7, "C"), kvh_frame(8),
    ]
    for chunks in ([b"".join(frames)], [bytes([b]) for b in b"".join(frames)]):
        lexer = Lexer(KVH)
        got = [(frame.message, frame.kind, frame.raw) for chunk in chunks for frame in lexer.feed(chunk)]
        assert [raw for _, _, raw in got] == frames
        assert [message for message, _, _ in got] == ["A", "B", "A", "C", "BIT", "C", "A", "BIT2", "B", "C", "A"]
        assert got[5][1] == "imu" and got[3][1] == "rate"  # C carries temperature when seq % 4 == 0
        assert (lexer.counters.frames_ok, lexer.counters.other_frames, lexer.counters.bad_crc) == (9, 2, 0)


def test_sequence_gaps_wraps_and_repeats():
    seqs = [124, 125, 126, 127, 0, 1, 4, 5, 5, 6, 10]
    lexer = Lexer(KVH)
    lexer.feed(b"".join(kvh_frame(seq) for seq in seqs))
    assert (lexer.counters.seq_gaps, lexer.counters.frames_missing, lexer.counters.seq_repeats) == (2, 5, 1)


def test_fogd_sequences_are_counted_per_frame_type():
    frames = fogd_stream(30)
    lexer = Lexer(FOGD)
    lexer.feed(b"".join(frames[:10] + frames[11:]))  # frame 10 is a rate frame
    assert (lexer.counters.frames_ok, lexer.counters.seq_gaps, lexer.counters.frames_missing) == (29, 1, 1)


def test_invalid_axes_and_temperatures_are_counted():
    frames = [kvh_frame(0, valid=(True, False, True)), kvh_frame(1, rate_x_dph=math.inf)]
    frames.append(FOGD.encode(Frame("fogd", "temp", seq=0, t_s=0.0, temp_c=math.nan)))
    frames.append(FOGD.encode(Frame("fogd", "rate", seq=0, t_s=0.0, rate_dph=(math.nan, math.nan, 1.0),
                                    axis_valid=(False, False, True), axis_present=(False, False, True))))
    lexer = Lexer([KVH, FOGD])
    assert feed_all(lexer, [b"".join(frames)]) == frames
    assert (lexer.counters.invalid_axes, lexer.counters.invalid_temps) == (2, 1)


def test_kvh_and_fogd_frames_share_a_link():
    kvh, fogd = kvh_stream(20), fogd_stream(20)
    frames = [frame for pair in zip(kvh, fogd) for frame in pair]
    stream = b"\x00\xf0" + b"\xfe\x81".join(frames)
    expected_garbage = 2 + 2 * (len(frames) - 1)
    lexer = Lexer([KVH, FOGD])
    assert feed_all(lexer, [stream[i : i + 7] for i in range(0, len(stream), 7)]) == frames
    assert lexer.counters.garbage_bytes == expected_garbage


def test_buffer_stays_bounded_whatever_is_fed():
    class Watched(Lexer):
        largest = 0

        def _scan(self, frames):
            Watched.largest = max(Watched.largest, len(self._buf))
            super()._scan(frames)

    rng = random.Random(5)
    lexer = Watched(KVH)
    blob = bytes(rng.getrandbits(8) for _ in range(100_000)) + (HEADER_A + bytes(20)) * 2000
    lexer.feed(blob + b"".join(kvh_stream(3000)))
    assert Watched.largest <= 17 * lexer.max_frame_len
    assert lexer.buffered < lexer.max_frame_len
    assert lexer.counters.frames_ok == 3000


def test_flush_counts_an_unfinished_frame():
    lexer = Lexer(KVH)
    lexer.feed(kvh_frame(0) + kvh_frame(1)[:30])
    assert lexer.buffered == 30
    lexer.flush()
    assert (lexer.buffered, lexer.counters.truncated, lexer.counters.garbage_bytes) == (0, 1, 30)


def test_ascii_lines_bad_lines_and_blank_lines():
    text = b"R,0.0,1.5\r\nT,0.0,20.0\nnonsense\n\r\n       0.015733   1\r\nR,0.1,xyz\nI,0.2,1.0,20.5\n"
    for chunks in ([text], [bytes([b]) for b in text]):
        lexer = Lexer(AsciiProtocol())
        got = [frame.message for chunk in chunks for frame in lexer.feed(chunk)]
        assert got == ["R", "T", "dsp3000", "I"]
        assert (lexer.counters.bad_line, lexer.counters.frames_ok) == (2, 4)
        assert lexer.counters.garbage_bytes == len(b"nonsense\n\r\nR,0.1,xyz\n")


def test_over_long_ascii_garbage_is_dropped():
    lexer = Lexer(AsciiProtocol())
    assert lexer.feed(b"x" * 10_000 + b"\nR,1.0,2.0\n") != []
    assert lexer.buffered == 0 and lexer.counters.bad_line == 1


def test_lexer_configuration_errors():
    with pytest.raises(ConfigError):
        Lexer([])
    with pytest.raises(ConfigError, match="ascii"):
        Lexer([KVH, AsciiProtocol()])


def fogd_rate(seq: int, t_s: float) -> bytes:
    return FOGD.encode(Frame("fogd", "rate", "rate", seq, t_s, (0.0, 0.0, 1.0 + seq), ALL, ALL))


def test_a_repeated_fogd_frame_is_dropped_and_counted_once():
    """Issue 35 item 4: `seq_repeats` counted the copy, then both went out."""
    lexer = Lexer(FOGD)
    frames = lexer.feed(fogd_rate(1, 0.001) + fogd_rate(2, 0.002) + fogd_rate(2, 0.002) + fogd_rate(3, 0.003))
    assert [frame.seq for frame in frames] == [1, 2, 3]
    counters = lexer.counters
    assert (counters.frames_ok, counters.seq_repeats, counters.frames_repeated, counters.seq_gaps) == (3, 1, 1, 0)


def test_a_repeated_ascii_line_is_dropped_and_counted():
    lexer = Lexer(AsciiProtocol())
    frames = lexer.feed(b"I,0.001,1.5,20.0\nI,0.002,1.6,20.0\nI,0.002,1.6,20.0\nI,0.003,1.7,20.0\n")
    assert [frame.t_s for frame in frames] == [0.001, 0.002, 0.003]
    assert (lexer.counters.frames_ok, lexer.counters.frames_repeated) == (3, 1)


def test_a_kvh_repeat_is_kept_since_its_7_bit_counter_cannot_tell_it_from_128_lost_frames():
    lexer = Lexer(KVH)
    frames = lexer.feed(kvh_frame(5) + kvh_frame(5) + kvh_frame(6))
    assert len(frames) == 3 and lexer.counters.seq_repeats == 1 and lexer.counters.frames_repeated == 0


def test_a_device_time_that_goes_back_is_flagged_and_counted_and_the_frame_kept():
    from fogd.protocols.base import TIME_BACKWARDS

    lexer = Lexer(FOGD)
    frames = lexer.feed(b"".join(fogd_rate(seq, t_s) for seq, t_s in ((1, 1.0), (2, 2.0), (3, 1.5), (4, 2.5))))
    assert [bool(frame.flags & TIME_BACKWARDS) for frame in frames] == [False, False, True, False]
    assert lexer.counters.time_backwards == 1
