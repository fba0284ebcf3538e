"""--protocol auto's detector (fogd.protocols.detect): each protocol recognised from its own valid frames
behind any garbage and split anywhere, every frame still there for the lexer afterwards, the rate measured,
and random bytes or another protocol's text never taken for one of fogd's."""

import math
import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fogd.protocols import Frame, get, names
from fogd.protocols.detect import BURST_FRAMES, FRAMES_NEEDED, MAX_BYTES, Detector, describe
from fogd.protocols.lexer import Lexer

NAN = math.nan
ALL = (True, True, True)
Z = (False, False, True)
NMEA = b"$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47\r\n$GPVTG,054.7,T,034.4,M,005.5,N,010.2,K*48\r\n"


def candidates():
    return [get(name) for name in names()]


def frames_of(protocol: str, rates_dph: list[float], temp_c: float, rate_hz: float) -> list[bytes]:
    """Valid frames of `protocol` carrying `rates_dph`, one sample every 1/rate_hz s of device time (fogd
    also sends a temperature frame after every fourth sample)."""
    encoder = get(protocol)
    frames = []
    for i, rate in enumerate(rates_dph):
        t_s = i / rate_hz
        if protocol == "kvh-a":
            frames.append(encoder.encode(Frame("kvh-a", "imu", "A", i % 128, None, (rate, -rate, rate), ALL, ALL, temp_c)))
        elif protocol == "fogd":
            frames.append(encoder.encode(Frame("fogd", "rate", seq=i % 65536, t_s=t_s, rate_dph=(NAN, NAN, rate),
                                               axis_valid=Z, axis_present=Z)))  # fmt: skip
            if i % 4 == 3:
                frames.append(encoder.encode(Frame("fogd", "temp", seq=i // 4, t_s=t_s, temp_c=temp_c)))
        else:
            frames.append(encoder.encode(Frame("ascii", "imu", "I", t_s=t_s, rate_dph=(NAN, NAN, rate), axis_valid=Z,
                                               axis_present=Z, temp_c=temp_c)))  # fmt: skip
    return frames


def feed_in_pieces(detector: Detector, data: bytes, cuts: list[int], arrival_s: list[float] | None = None):
    """Feed `data` cut at `cuts`; the verdict and the piece it came with (settle() after the last)."""
    bounds = sorted({0, len(data), *(cut % (len(data) + 1) for cut in cuts)})
    for index, (start, stop) in enumerate(zip(bounds, bounds[1:])):
        found = detector.feed(data[start:stop], arrival_s[index] if arrival_s else 0.0)
        if found is not None:
            return found, index
    return detector.settle(), None


rates = st.lists(st.floats(-500.0, 500.0, allow_nan=False), min_size=FRAMES_NEEDED + 1, max_size=60)


@settings(max_examples=60, deadline=None)
@given(protocol=st.sampled_from(names()), rates_dph=rates, temp_c=st.floats(-40.0, 85.0),
       garbage=st.binary(max_size=300), cuts=st.lists(st.integers(0, 10_000), max_size=20))  # fmt: skip
def test_each_protocol_is_recognised_behind_garbage_and_every_frame_reaches_the_lexer(protocol, rates_dph, temp_c, garbage, cuts):
    if protocol == "ascii":
        garbage = garbage.replace(b"\n", b"")  # a line format's frames start after a newline
    frames = frames_of(protocol, rates_dph, temp_c, 100.0)
    detector = Detector(candidates())
    found, _ = feed_in_pieces(detector, garbage + b"\n" + b"".join(frames), cuts)
    assert found is not None and found.name == protocol
    framed = Lexer(get(protocol)).feed(detector.held)
    assert [frame.raw for frame in framed][-len(frames) :] == frames  # what detection read is all still there


@settings(max_examples=60, deadline=None)
@given(protocol=st.sampled_from(names()), rate_hz=st.floats(1.0, 5000.0), count=st.integers(FRAMES_NEEDED, 40))
def test_the_rate_is_measured_by_the_device_clock_where_frames_carry_one(protocol, rate_hz, count):
    frames = frames_of(protocol, [1.0] * count, 20.0, rate_hz)
    detector = Detector(candidates())
    found = detector.feed(b"".join(frames), 0.0) or detector.settle()  # the burst, or the pause after it
    assert found is not None and found.name == protocol and found.frames == len(frames)
    if protocol == "kvh-a":  # Format A has no time, and the frames came at once
        assert found.rate_hz is None and found.rate_from == "arrival"
    else:
        assert found.rate_from == "device time" and found.rate_hz == pytest.approx(rate_hz, rel=1e-3)
        assert found.span_s == pytest.approx((count - 1) / rate_hz, rel=1e-3)


@settings(max_examples=30, deadline=None)
@given(rate_hz=st.floats(50.0, 2000.0), per_read=st.integers(1, 8))
def test_a_unit_without_time_is_measured_as_its_frames_arrive_and_decided_after_measure_s(rate_hz, per_read):
    frames = frames_of("kvh-a", [0.5] * 2000, 20.0, rate_hz)
    detector = Detector(candidates(), burst_frames=10_000)
    for index in range(0, len(frames), per_read):
        found = detector.feed(b"".join(frames[index : index + per_read]), (index + per_read - 1) / rate_hz)
        if found is not None:
            break
    assert found is not None and found.name == "kvh-a" and found.rate_from == "arrival"
    assert found.rate_hz == pytest.approx(rate_hz, rel=0.01)
    assert 0.5 <= found.span_s < 0.5 + (per_read + 1) / rate_hz  # decided as soon as half a second is measured


def test_a_backlog_is_decided_at_once_without_a_rate():
    frames = frames_of("kvh-a", [0.5] * BURST_FRAMES, 20.0, 1000.0)
    found = Detector(candidates()).feed(b"".join(frames), 7.0)
    assert found is not None and found.name == "kvh-a" and found.frames == BURST_FRAMES and found.rate_hz is None


@settings(max_examples=60, deadline=None)
@given(data=st.binary(min_size=1, max_size=20_000), cuts=st.lists(st.integers(0, 20_000), max_size=10))
def test_random_bytes_are_never_taken_for_a_protocol(data, cuts):
    detector = Detector(candidates())
    found, _ = feed_in_pieces(detector, data, cuts)
    assert found is None
    assert len(detector.held) + detector.dropped_bytes == len(data) == detector.bytes_seen


def test_a_long_unrecognised_stream_is_bounded_and_a_protocol_starting_late_is_still_found():
    rng = random.Random(7)
    noise = bytes(rng.getrandbits(8) for _ in range(3 * MAX_BYTES))
    detector = Detector(candidates())
    for index in range(0, len(noise), 4096):
        assert detector.feed(noise[index : index + 4096], 0.0) is None
        assert len(detector.held) <= MAX_BYTES + 4096
    assert detector.dropped_bytes > 0
    frames = frames_of("fogd", [2.0] * 200, 25.0, 200.0)
    found = detector.feed(b"".join(frames), 0.0)
    assert found is not None and found.name == "fogd"
    assert [frame.raw for frame in Lexer(get("fogd")).feed(detector.held)][-len(frames) :] == frames


def test_another_protocols_text_is_not_recognised_and_is_described_as_text():
    detector = Detector(candidates())
    for _ in range(200):
        assert detector.feed(NMEA, 0.0) is None
    assert detector.settle() is None
    text = detector.describe()
    assert text.startswith("printable text, e.g. '$GP") and "400 ascii" in text  # every line rejected by ascii


@pytest.mark.parametrize(
    "data, start",
    [
        (b"", "no bytes"),
        (bytes(5000), "all zero bytes"),
        (b"\xff" * 300, "one byte repeated (0xff)"),
        (b"hello\r\nworld, again\r\n", "printable text, e.g. 'world, again'"),
        (bytes(range(256)) * 4, "binary with no known header (e.g. 00 01 02"),
    ],
)
def test_describe_names_what_the_bytes_look_like(data, start):
    assert describe(data).startswith(start)


def test_kvh_headers_failing_their_crc_are_named():
    frames = frames_of("kvh-a", [1.0] * 20, 20.0, 1000.0)
    broken = b"".join(frame[:-1] + bytes([frame[-1] ^ 0x55]) for frame in frames)
    detector = Detector(candidates())
    assert detector.feed(broken, 0.0) is None and detector.settle() is None
    assert "20 kvh-a" in detector.describe() and "ascii" not in detector.describe()
