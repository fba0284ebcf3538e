"""Run CSVs: write_csv/read_run round trips, and every unusable file is one InputError naming file and line."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fogd.core.columns import CHANNELS, GYRO_CHANNELS, SINGLE_CHANNEL, TRUE_ERROR_COLUMN, truth_column
from fogd.core.runio import read_run, write_csv
from fogd.errors import InputError

HEADER = "t_s,rate_dph,temp_c"


def write_text(tmp_path: Path, text: str, name: str = "run.csv") -> Path:
    path = tmp_path / name
    path.write_bytes(text.encode("utf-8"))
    return path


def rows(n: int, rate_hz: float = 10.0, start_s: float = 0.0) -> list[str]:
    """n well-formed data lines at rate_hz."""
    return [f"{start_s + i / rate_hz:.6f},{0.1 * i:.3f},{20 + 0.01 * i:.3f}" for i in range(n)]


def input_error(path: Path) -> str:
    """read_run's InputError message, checked to be one line starting with the file, which becomes '<file>'."""
    with pytest.raises(InputError) as caught:
        read_run(path)
    message = str(caught.value)
    assert "\n" not in message and "\r" not in message, message
    assert message.startswith(str(path)), message
    return "<file>" + message[len(str(path)) :]  # tmp_path holds the test's name: keep it out of word checks


def line_number(path: Path, message: str) -> int:
    """The line number in '<file>:N: ...'."""
    match = re.match(r"<file>:(\d+):", message)
    assert match, f"no line number in {message!r}"
    return int(match.group(1))


# --- good files -------------------------------------------------------------------------------------------


def test_round_trip_keeps_columns_rate_and_extras(tmp_path):
    t = np.arange(0.0, 30.0, 0.04)  # 25 Hz
    rate = np.sin(t) * 3.0 + 0.25
    temp = 20.0 + 0.1 * t
    truth = 0.002 * temp
    path = tmp_path / "sub" / "run.csv"
    path.parent.mkdir()  # write_csv creates no directories (issue 35.1)
    write_csv(str(path), {"t_s": t, "rate_dph": rate, "temp_c": temp, "true_error_dph": truth}, {})

    run = read_run(path)

    assert run.path == str(path) and run.name == "run.csv"
    assert run.rows == t.size
    np.testing.assert_allclose(run.t_s, t, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(run.rate_dph, rate, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(run.temp_c, temp, rtol=1e-8)
    assert list(run.extra) == ["true_error_dph"]
    np.testing.assert_allclose(run.extra["true_error_dph"], truth, rtol=1e-8)
    assert run.rate_hz == pytest.approx(25.0, rel=1e-6)
    assert run.nan_rows == 0
    for array in (run.t_s, run.rate_dph, run.temp_c, run.extra["true_error_dph"]):
        assert array.dtype == np.float64 and array.flags.c_contiguous


def test_columns_in_any_order_with_formats(tmp_path):
    path = tmp_path / "run.csv"
    t = np.arange(10) * 0.5
    write_csv(str(path), {"temp_c": np.full(10, 21.5), "t_s": t, "rate_dph": np.arange(10.0)}, {"t_s": "%.3f"})
    assert path.read_text().splitlines()[1].split(",")[1] == "0.000"
    run = read_run(path)
    np.testing.assert_array_equal(run.t_s, t)
    np.testing.assert_array_equal(run.temp_c, np.full(10, 21.5))
    np.testing.assert_array_equal(run.rate_dph, np.arange(10.0))
    assert run.extra == {}
    assert run.rate_hz == pytest.approx(2.0)


def test_comment_lines_before_header_are_skipped(tmp_path):
    path = tmp_path / "run.csv"
    t = np.arange(5) * 0.1
    write_csv(str(path), {"t_s": t, "rate_dph": t * 2, "temp_c": t + 20}, {}, comments=["chamber A", "seed 3"])
    lines = path.read_text().splitlines()
    assert lines[:3] == ["# chamber A", "# seed 3", HEADER]
    run = read_run(path)
    np.testing.assert_allclose(run.t_s, t)
    np.testing.assert_allclose(run.rate_dph, t * 2)
    assert run.rate_hz == pytest.approx(10.0)


def test_hand_written_comments_blank_lines_and_crlf(tmp_path):
    text = "# recorded 2024\n\n#another\n" + HEADER + "\n" + "\n".join(rows(4, rate_hz=5.0)) + "\n"
    run = read_run(write_text(tmp_path, text.replace("\n", "\r\n")))
    np.testing.assert_allclose(run.t_s, [0.0, 0.2, 0.4, 0.6])
    np.testing.assert_allclose(run.temp_c, [20.0, 20.01, 20.02, 20.03])
    assert run.rate_hz == pytest.approx(5.0)


def test_sha256_is_of_the_file_bytes(tmp_path):
    import hashlib

    path = write_text(tmp_path, HEADER + "\n" + "\n".join(rows(3)) + "\n")
    assert read_run(path).sha256 == hashlib.sha256(path.read_bytes()).hexdigest()


def test_nan_and_inf_rows_are_kept_and_counted(tmp_path):
    lines = rows(8)
    lines[2] = "0.2,nan,20.02"
    lines[4] = "0.4,0.4,inf"
    lines[5] = "0.5,-inf,nan"
    path = write_text(tmp_path, HEADER + "\n" + "\n".join(lines) + "\n")
    run = read_run(path)
    assert run.rows == 8
    assert run.nan_rows == 3
    assert np.isnan(run.rate_dph[2]) and np.isposinf(run.temp_c[4]) and np.isneginf(run.rate_dph[5])
    assert run.temp_c[3] == pytest.approx(20.03)


def test_nan_rows_written_by_write_csv_read_back(tmp_path):
    path = tmp_path / "run.csv"
    rate = np.array([1.0, np.nan, 2.0, np.inf, 3.0])
    write_csv(str(path), {"t_s": np.arange(5.0), "rate_dph": rate, "temp_c": np.full(5, 20.0)}, {})
    run = read_run(path)
    assert run.nan_rows == 2
    np.testing.assert_array_equal(run.rate_dph, rate)


# --- bad files: one-line InputError naming the file (and line) --------------------------------------------


def test_missing_file(tmp_path):
    message = input_error(tmp_path / "nope.csv")
    assert "No such file" in message


def test_empty_file(tmp_path):
    message = input_error(write_text(tmp_path, ""))
    assert "empty" in message


def test_whitespace_only_file(tmp_path):
    assert "empty" in input_error(write_text(tmp_path, "\n  \n\n"))


def test_comments_only(tmp_path):
    assert "header" in input_error(write_text(tmp_path, "# just a note\n# and another\n"))


@pytest.mark.filterwarnings("ignore:loadtxt")  # numpy warns of no data; read_run raises the error
def test_header_only(tmp_path):
    message = input_error(write_text(tmp_path, "# note\n" + HEADER + "\n"))
    assert "no data" in message


def test_missing_column(tmp_path):
    path = write_text(tmp_path, "# c\nt_s,rate_dph\n" + "\n".join(r.rsplit(",", 1)[0] for r in rows(3)) + "\n")
    message = input_error(path)
    assert line_number(path, message) == 2
    assert "temp_c" in message and "missing" in message


def test_misnamed_column_suggests_close_name(tmp_path):
    path = write_text(tmp_path, "t_s,rate_dph,temp\n" + "\n".join(rows(3)) + "\n")
    message = input_error(path)
    assert line_number(path, message) == 1
    assert "temp_c" in message and "'temp'" in message


def test_duplicate_column(tmp_path):
    path = write_text(tmp_path, "#x\nt_s,rate_dph,temp_c,rate_dph\n" + "\n".join(r + ",1" for r in rows(3)) + "\n")
    message = input_error(path)
    assert line_number(path, message) == 2
    assert "rate_dph" in message and "more than once" in message


def test_data_where_header_should_be(tmp_path):
    path = write_text(tmp_path, "# c\n\n" + "\n".join(rows(3)) + "\n")
    message = input_error(path)
    assert line_number(path, message) == 3
    assert "header" in message


def test_non_numeric_cell_names_line_and_column(tmp_path):
    lines = rows(6)
    lines[3] = "0.3,0.3,hot"
    path = write_text(tmp_path, "# c\n" + HEADER + "\n" + "\n".join(lines) + "\n")
    message = input_error(path)
    assert line_number(path, message) == 6  # comment, header, then data line 4
    assert "column 3" in message and "hot" in message


@pytest.mark.parametrize("cell", ["1_000", "\u0661\u0662", "0x1p3", "1.5d3"])
def test_cells_python_reads_but_numpy_does_not_are_named(tmp_path, cell):
    lines = rows(6)
    lines[2] = f"0.2,{cell},20.0"
    path = write_text(tmp_path, HEADER + "\n" + "\n".join(lines) + "\n")
    message = input_error(path)
    assert line_number(path, message) == 4
    assert "column 2" in message


def test_empty_cell(tmp_path):
    lines = rows(6)
    lines[1] = "0.1,,20.0"
    path = write_text(tmp_path, HEADER + "\n" + "\n".join(lines) + "\n")
    message = input_error(path)
    assert line_number(path, message) == 3
    assert "column 2" in message


def test_row_with_too_few_cells(tmp_path):
    lines = rows(6)
    lines[4] = "0.4,0.4"
    path = write_text(tmp_path, HEADER + "\n" + "\n".join(lines) + "\n")
    message = input_error(path)
    assert line_number(path, message) == 6
    assert "2 cells" in message and "3" in message


def test_row_with_too_many_cells(tmp_path):
    lines = rows(6)
    lines[0] += ",7"
    path = write_text(tmp_path, HEADER + "\n" + "\n".join(lines) + "\n")
    assert line_number(path, input_error(path)) == 2


def test_line_of_spaces_inside_data_is_named(tmp_path):
    lines = rows(6)
    lines.insert(3, "   ")
    path = write_text(tmp_path, HEADER + "\n" + "\n".join(lines) + "\n")
    assert line_number(path, input_error(path)) == 5


def test_time_not_increasing_names_the_line(tmp_path):
    lines = rows(10)
    lines[6] = lines[5]  # repeated time stamp on data row 7
    path = write_text(tmp_path, "# a\n# b\n" + HEADER + "\n" + "\n".join(lines) + "\n")
    message = input_error(path)
    assert line_number(path, message) == 3 + 7
    assert "increase" in message


def test_time_going_backwards_names_the_line(tmp_path):
    lines = rows(10)
    lines[8] = "0.1,0,20"
    path = write_text(tmp_path, HEADER + "\n" + "\n".join(lines) + "\n")
    assert line_number(path, input_error(path)) == 1 + 9


def test_time_gap_names_the_line(tmp_path):
    lines = rows(5) + rows(5, start_s=10.0)  # 10 Hz, then a 9.6 s gap
    path = write_text(tmp_path, HEADER + "\n" + "\n".join(lines) + "\n")
    message = input_error(path)
    assert line_number(path, message) == 1 + 6
    assert "gap" in message


def test_small_jitter_is_not_a_gap(tmp_path):
    t = np.arange(50) * 0.1 + np.where(np.arange(50) % 2, 0.01, -0.01)
    path = tmp_path / "run.csv"
    write_csv(str(path), {"t_s": t, "rate_dph": np.zeros(50), "temp_c": np.full(50, 20.0)}, {})
    assert read_run(path).rows == 50


def test_blank_lines_inside_data_do_not_shift_line_numbers(tmp_path):
    lines = rows(10)
    lines[7] = lines[6]
    lines.insert(3, "")
    lines.insert(1, "")
    path = write_text(tmp_path, HEADER + "\n" + "\n".join(lines) + "\n")
    message = input_error(path)
    text_lines = path.read_text().splitlines()
    number = line_number(path, message)
    assert text_lines[number - 1] == text_lines[number - 2] == rows(10)[6], message


def test_fewer_than_two_rows(tmp_path):
    path = write_text(tmp_path, HEADER + "\n" + rows(1)[0] + "\n")
    message = input_error(path)
    assert "two" in message


def test_non_utf8_bytes_are_reported_not_crashed(tmp_path):
    path = tmp_path / "run.csv"
    path.write_bytes((HEADER + "\n0,0,20\n0.1,\xff\xfe,20\n").encode("latin-1"))
    assert line_number(path, input_error(path)) == 3


# --- property ---------------------------------------------------------------------------------------------

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


@st.composite
def tables(draw):
    n = draw(st.integers(2, 40))
    start_s = draw(st.floats(-1e4, 1e4))
    step_s = draw(st.floats(1e-3, 100.0))
    jitter = draw(st.lists(st.floats(-0.2, 0.2), min_size=n, max_size=n))
    t_s = start_s + step_s * (np.arange(n) + np.array(jitter))
    extras = draw(st.lists(st.sampled_from(["aux", "true_error_dph", "x1"]), unique=True, max_size=2))
    columns = {"t_s": t_s}
    for name in ["rate_dph", "temp_c", *extras]:
        columns[name] = np.array(draw(st.lists(finite, min_size=n, max_size=n)), dtype=np.float64)
    order = draw(st.permutations(list(columns)))
    return {name: columns[name] for name in order}


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(table=tables())
def test_any_finite_table_round_trips(tmp_path, table):
    path = tmp_path / "prop.csv"
    write_csv(str(path), table, {})
    run = read_run(path)
    got = {"t_s": run.t_s, "rate_dph": run.rate_dph, "temp_c": run.temp_c, **run.extra}
    assert set(got) == set(table)
    for name, values in table.items():
        # %.9g keeps 9 significant digits: relative error below 5e-9
        np.testing.assert_allclose(got[name], values, rtol=6e-9, atol=0, err_msg=name)
    assert run.nan_rows == 0
    step = np.median(np.diff(table["t_s"]))
    printed = 1e-8 * np.max(np.abs(table["t_s"]))  # worst change of a step by printing both ends
    assert run.rate_hz == pytest.approx(1.0 / step, rel=2 * printed / step + 1e-12)


@given(present=st.lists(st.sampled_from(CHANNELS), min_size=1, max_size=6, unique=True), seed=st.integers(0, 2**16))
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_a_multi_channel_run_reads_every_channel_and_views_each_as_a_single_channel_run(tmp_path, present, seed):
    rng = np.random.default_rng(seed)
    values = {name: rng.normal(size=20).round(6) for name in present}
    truth = {truth_column(name): rng.normal(size=20).round(6) for name in present[:1]}
    columns = {"t_s": np.arange(20) / 10.0, **values, "temp_c": np.linspace(20.0, 21.0, 20), **truth}
    path = tmp_path / f"imu-{seed}.csv"
    write_csv(str(path), columns, {})
    run = read_run(path)
    assert list(run.channels) == present
    expected_primary = "rate_z_dph" if "rate_z_dph" in present else next((n for n in GYRO_CHANNELS if n in present), present[0])
    assert np.array_equal(run.rate_dph, values[expected_primary])
    for name in present:
        view = run.channel(name)
        assert np.array_equal(view.rate_dph, values[name]) and list(view.channels) == [name]
        assert np.array_equal(view.t_s, run.t_s) and np.array_equal(view.temp_c, run.temp_c)
        if name == present[0]:
            assert np.array_equal(view.extra[TRUE_ERROR_COLUMN], truth[truth_column(name)])
        else:
            assert TRUE_ERROR_COLUMN not in view.extra


def test_a_single_axis_run_is_its_own_one_channel(tmp_path):
    run = read_run(write_text(tmp_path, "\n".join([HEADER, *rows(5)]) + "\n"))
    assert list(run.channels) == [SINGLE_CHANNEL] and run.channel(SINGLE_CHANNEL).rate_dph is run.rate_dph
    with pytest.raises(InputError, match="no channel 'rate_x_dph'; it has rate_dph"):
        run.channel("rate_x_dph")


def test_an_imu_run_without_temperature_names_what_a_run_needs(tmp_path):
    message = input_error(write_text(tmp_path, "t_s,rate_x_dph,accel_z_g\n0,1,1\n0.1,1,1\n"))
    assert "missing column(s) temp_c" in message and "accel_z_g" in message
