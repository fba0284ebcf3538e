"""The ASCII line protocol: KVH DSP-3000 lines and fogd's R/T/I/C lines."""

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fogd.errors import ConfigError
from fogd.protocols import Frame, FrameError, get
from fogd.protocols.ascii import MAX_RATE_DPH, AsciiProtocol
from fogd.protocols.base import MAX_T_S

ASCII = AsciiProtocol()
DSP3000_LINE = b"       0.015733   1\r\n"  # a KVH DSP-3000 line: deg/s, then the validity flag


def test_dsp3000_line_decodes_to_deg_per_hour_on_z():
    frame = ASCII.decode(DSP3000_LINE)
    assert (frame.kind, frame.message, frame.seq, frame.t_s, frame.temp_c) == ("rate", "dsp3000", None, None, None)
    assert frame.rate_dph[2] == pytest.approx(0.015733 * 3600.0)
    assert math.isnan(frame.rate_dph[0]) and math.isnan(frame.rate_dph[1])
    assert frame.axis_present == (False, False, True)
    assert frame.axis_valid == (False, False, True)


def test_dsp3000_invalid_flag_and_delta_mode():
    assert ASCII.decode(b"      -0.000120   0\r\n").axis_valid == (False, False, False)
    delta = AsciiProtocol(rotfmt="delta", rate_hz=100.0).decode(DSP3000_LINE)
    assert delta.rate_dph[2] == pytest.approx(0.015733 * 100.0 * 3600.0)
    with pytest.raises(ConfigError):
        get("ascii", rotfmt="delta")


def test_fogd_lines_decode():
    rate = ASCII.decode(b"R,12.5,-3.25\n")
    assert (rate.kind, rate.t_s, rate.rate_dph[2], rate.axis_valid[2]) == ("rate", 12.5, -3.25, True)
    temp = ASCII.decode(b"T,12.75,31.0625\r\n")
    assert (temp.kind, temp.t_s, temp.temp_c, temp.rate_dph) == ("temp", 12.75, 31.0625, None)
    both = ASCII.decode(b"I,,1.5,20.0\n")
    assert (both.kind, both.t_s, both.rate_dph[2], both.temp_c) == ("imu", None, 1.5, 20.0)
    comp = ASCII.decode(b"C,1.0,10.0,25.0,0.01,0.5,9.5,1\n")
    assert (comp.kind, comp.temp_rate_cps, comp.comp_dph[2], comp.rate_comp_dph[2], comp.flags) == (
        "comp", 0.01, 0.5, 9.5, 1,
    )
    assert ASCII.decode(b"R,1.0,nan\n").axis_valid == (False, False, False)


@pytest.mark.parametrize(
    "line",
    [b"R,1.0,abc\n", b"X,1.0,2.0\n", b"R,1.0\n", b"hello\n", b"0.1 2\n", b"0.1\n", b"R,1,\xff\n", b"C,1,1,1,1,1,1,-1\n"],
)
def test_bad_lines_raise_bad_line(line):
    with pytest.raises(FrameError) as error:
        ASCII.decode(line)
    assert error.value.counter == "bad_line"


def test_reencode_dsp3000_keeps_the_field_width_and_flag():
    frame = ASCII.decode(DSP3000_LINE)
    assert ASCII.reencode(frame, (0.0, 0.0, 0.016 * 3600.0)) == b"       0.016000   1\r\n"
    invalid = ASCII.decode(b"       0.015733   0\r\n")
    assert ASCII.reencode(invalid, (0.0, 0.0, 1.0)) == invalid.raw


def test_reencode_fogd_lines_replaces_only_the_rate_field():
    frame = ASCII.decode(b"I,1.000,5.0,20.50\r\n")
    assert ASCII.reencode(frame, (0.0, 0.0, 4.75)) == b"I,1.000,4.75,20.50\r\n"
    temp = ASCII.decode(b"T,1.0,20.0\n")
    assert ASCII.reencode(temp, (0.0, 0.0, 4.75)) == temp.raw


def test_frame_length_finds_lines_and_skips_blank_ones():
    assert ASCII.frame_length(b"R,1,2\nT", 0) == 6
    assert ASCII.frame_length(b"R,1,2", 0) == 0
    assert ASCII.frame_length(b"  \r\nR", 0) == -4
    assert ASCII.frame_length(b"x" * 300, 0) == -300


finite = st.floats(allow_nan=False, allow_infinity=False)
rates = st.floats(min_value=-MAX_RATE_DPH, max_value=MAX_RATE_DPH)
times = st.none() | st.floats(min_value=-MAX_T_S, max_value=MAX_T_S)  # beyond, a line is refused (issue 11.5)


@given(t_s=times, rate=rates, temp_c=finite, kind=st.sampled_from(["rate", "temp", "imu"]))
def test_fogd_line_round_trip(t_s, rate, temp_c, kind):
    record = Frame("ascii", kind, "", None, t_s, (math.nan, math.nan, rate), (False, False, True), (False, False, True), temp_c)
    frame = ASCII.decode(ASCII.encode(record))
    assert (frame.kind, frame.t_s) == (kind, t_s)
    if kind != "temp":
        assert frame.rate_dph[2] == rate and frame.axis_valid == (False, False, True)
    if kind != "rate":
        assert frame.temp_c == temp_c


@given(t_s=st.floats(min_value=-MAX_T_S, max_value=MAX_T_S), values=st.tuples(rates, *[finite] * 4), flags=st.integers(0, 63))
def test_comp_line_round_trip(t_s, values, flags):
    rate, temp_c, temp_rate_cps, comp, rate_comp = values
    z_only = (False, False, True)
    record = Frame("ascii", "comp", "C", None, t_s, (0.0, 0.0, rate), z_only, z_only, temp_c, b"", temp_rate_cps,
                   (0.0, 0.0, comp), (0.0, 0.0, rate_comp), flags)
    frame = ASCII.decode(ASCII.encode(record))
    assert (frame.t_s, frame.rate_dph[2], frame.temp_c, frame.temp_rate_cps) == (t_s, rate, temp_c, temp_rate_cps)
    assert (frame.comp_dph[2], frame.rate_comp_dph[2], frame.flags) == (comp, rate_comp, flags)


@given(rate_dps=st.floats(min_value=-1000, max_value=1000), valid=st.booleans())
def test_dsp3000_round_trip_to_six_decimals(rate_dps, valid):
    record = Frame("ascii", "rate", "dsp3000", rate_dph=(0.0, 0.0, rate_dps * 3600.0), axis_valid=(False, False, valid),
                   axis_present=(False, False, True))
    line = ASCII.encode(record)
    assert line.endswith(b"\r\n") and len(line) >= 21
    frame = ASCII.decode(line)
    assert frame.rate_dph[2] == pytest.approx(rate_dps * 3600.0, abs=0.5e-6 * 3600.0 * 1.01)
    assert frame.axis_valid[2] == valid


def test_reencode_dsp3000_writes_the_digits_a_small_compensation_needs():
    """Issue 35 item 5: 0.02340 deg/h removed must not come out as 0.02520 (six decimals of deg/s)."""
    frame = ASCII.decode(DSP3000_LINE)
    line = ASCII.reencode(frame, (0.0, 0.0, frame.rate_dph[2] - 0.0234))
    assert ASCII.decode(line).rate_dph[2] - frame.rate_dph[2] == pytest.approx(-0.0234, abs=1e-9)
    assert line.endswith(b"   1\r\n")


@given(st.integers(-100_000_000, 100_000_000), st.floats(-100.0, 100.0), st.sampled_from(["rate", "delta"]))
def test_reencoded_dsp3000_minus_raw_is_the_compensation(micro_units, comp_dph, rotfmt):
    protocol = AsciiProtocol(rotfmt=rotfmt, rate_hz=100.0)
    units = micro_units / 1e6 if rotfmt == "rate" else micro_units / 1e8  # up to 100 deg/s either way
    frame = protocol.decode(f"{units:15.6f}   1\r\n".encode())
    line = protocol.reencode(frame, (0.0, 0.0, frame.rate_dph[2] - comp_dph))
    assert protocol.decode(line).rate_dph[2] - frame.rate_dph[2] == pytest.approx(-comp_dph, abs=1e-9)
