"""Every benchmark in tools/ still runs, in its tiny --quick mode. No timing is asserted: the numbers of a
quick run on a shared machine mean nothing; the benchmarks themselves are what show speed."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from fogd.simulation.profiles import Profile
from fogd.simulation.simulator import params_for, simulate

TOOLS = Path(__file__).resolve().parent.parent / "tools"
sys.path.insert(0, str(TOOLS))
import quantisation_bound  # noqa: E402


@pytest.mark.parametrize(
    "script, table",
    [
        ("bench_replay.py", "2a. Replay compensation"),
        ("bench_daemon.py", "3b-d. Latency"),
        ("bench_train.py", "4. Training wall time"),
    ],
)
def test_benchmark_runs_in_quick_mode(script, table):
    done = subprocess.run(
        [sys.executable, "-W", "ignore", str(TOOLS / script), "--quick"], capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert table in done.stdout
    assert "Traceback" not in done.stderr


def test_the_design_comparison_runs_its_single_thread_prototype():
    """bench_daemon.py --design runs tools/bench_loop_prototype.py, which builds fogd's Daemon itself: it broke
    unnoticed once when the Daemon's constructor changed."""
    done = subprocess.run([sys.executable, "-W", "ignore", str(TOOLS / "bench_daemon.py"), "--design", "1", "--quick"],
                          capture_output=True, text=True, timeout=600)  # fmt: skip
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert "single-thread prototype" in done.stdout and "Traceback" not in done.stderr


def test_bench_runs_the_sections_it_is_given():
    """tools/bench.py runs the sections it is given, each in its own quick mode: here bench_point.py's (which
    no other test runs)."""
    done = subprocess.run(
        [sys.executable, str(TOOLS / "bench.py"), "--quick", "--only", "point"], capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert "1. Per-point compensation cost" in done.stdout and "== point: ok" in done.stdout


def test_paper_tables_reproduce_the_papers_table_3_headline():
    """tools/paper_tables.py (the paper's recipe on a navigation-grade gyro, one heating run): PSO-SVR is the
    best of the three in-sample and removes at least 95 % of the error (table 3); the tool prints table 4."""
    done = subprocess.run(
        [sys.executable, "-W", "ignore", str(TOOLS / "paper_tables.py"), "--quick", "--rate-hz", "1"],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    table3 = done.stdout.split("Table 4")[0]
    removed = {line.split("|")[1].strip(): float(line.split("|")[4].strip(" %")) for line in table3.splitlines()
               if line.startswith("| ") and line.rstrip().endswith("% |")}  # fmt: skip
    assert set(removed) == {"5th-order LS", "RBF-NN (L1)", "PSO-SVR"}
    assert removed["PSO-SVR"] >= 95.0 and removed["PSO-SVR"] == max(removed.values())
    assert "Table 4" in done.stdout and "Best possible" in done.stdout


def _bounds(*args: str) -> dict[str, float]:
    done = subprocess.run([sys.executable, str(TOOLS / "quantisation_bound.py"), "--rate-hz", "2", *args],
                          capture_output=True, text=True, timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    return {line.split()[0]: float(line.split("worst ")[1].rstrip(")")) for line in done.stdout.splitlines() if "(worst" in line}


def test_quantisation_bound_is_blind_only_with_a_coarse_sensor():
    """A fine sensor changes its reading within seconds of a ramp's start, so its bound is the floor itself; a
    whole-degree one stays blind for minutes while the error moves, and the whole move stays in (the minimax
    guess between a ramp up, a ramp down and the soak held is "no move"), so its worst run is over 2x the floor
    (the tool that kept half of it said 1.72 for the lumped coil)."""
    fine = _bounds("--resolution-c", "0.0625", "--sensor-hz", "4")
    whole = _bounds()
    assert set(fine) == set(whole) == {"lumped", "diffusive"}
    assert all(value < 1.02 for value in fine.values())
    assert all(value > 2.0 for value in whole.values())


def test_accuracy_table_runs_only_the_schemes_it_is_given():
    """--schemes linear: one coil, one sensor, only the linear row (and the uncompensated one) in the table."""
    done = subprocess.run(
        [sys.executable, "-W", "ignore", str(TOOLS / "accuracy_table.py"), "--rate-hz", "1", "--thermal", "lumped",
         "--sensor", "fine", "--schemes", "linear", "--jobs", "1"],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    rows = [line.split("|")[1].strip() for line in done.stdout.splitlines() if line.startswith("| ")]
    assert rows == ["Scheme", "Before compensation", "linear (IEEE 952: temp, rate@50)", "Noise floor, deg/h"]


@pytest.mark.parametrize("option, value", [("--schemes", "default,bogus"), ("--default-inputs", "lags@5..1")])
def test_accuracy_table_refuses_bad_options_in_one_line(option, value):
    done = subprocess.run([sys.executable, str(TOOLS / "accuracy_table.py"), option, value],
                          capture_output=True, text=True, timeout=60)  # fmt: skip
    assert done.returncode == 2
    assert "Traceback" not in done.stderr
    error = done.stderr.strip().splitlines()[-1]
    assert "error:" in error and value.split(",")[-1] in error


def _drift(values_dph: np.ndarray, rate_hz: float) -> float:
    """The accuracy table's metric, written out: 100 s block means after the first 600 s, rms about their mean."""
    block = int(100 * rate_hz)
    kept = values_dph[int(600 * rate_hz):]
    means = kept[: kept.size // block * block].reshape(-1, block).mean(axis=1)
    return float(np.sqrt(np.mean((means - means.mean()) ** 2)))


def test_quantisation_bound_keeps_the_whole_move_when_the_ramp_could_go_either_way():
    """After a soak a whole-degree reading stays still for minutes; the same ramp going down reads the same
    meanwhile and moves the error the other way (a linear static curve, no play, no sensor noise: exactly), so
    the minimax guess is "no move" and the bound keeps the whole move of the error in the blind window. (The tool
    once hedged between "soak" and "up" only and kept half.)"""
    params = params_for("navigation", "lumped", sensor_resolution_c=1.0, sensor_rate_hz=1.0, sensor_noise_c=0.0,
                        hysteresis_dph=0.0, static_dph=(0.06, 0.0, 0.0))  # fmt: skip
    profile = Profile("soak-then-ramp", ((900.0, 10.0), (1800.0, 40.0)))
    rate_hz, seed = 1.0, 7
    run = simulate(profile, rate_hz, seed, params)
    start = 900
    stop = start + int(np.flatnonzero(run.temp_c[start:] != run.temp_c[start])[0])
    assert stop - start > 300  # blind for minutes
    moved = np.zeros(run.t_s.size)
    moved[start:stop] = run.true_error_dph[start:stop] - run.true_error_dph[start]
    noise = run.rate_dph - run.true_error_dph
    whole, half = (_drift(noise + share * moved, rate_hz) / _drift(noise, rate_hz) for share in (1.0, 0.5))
    assert whole > half + 0.3  # the case tells the two apart
    assert quantisation_bound.profile_bound(profile, rate_hz, seed, params) == pytest.approx(whole, rel=1e-6)


def _table(stdout: str, title: str) -> list[dict[str, str]]:
    """The rows of the markdown table printed under the line starting with `title`, as header: cell."""
    lines = stdout.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(title)) + 1
    end = next((i for i in range(start, len(lines)) if not lines[i].startswith("|")), len(lines))
    header, _rule, *body = ([cell.strip() for cell in line.strip("|").split("|")] for line in lines[start:end])
    return [dict(zip(header, row)) for row in body]


def test_the_dedicated_box_mode_measures_each_process_alone_without_loss():
    """bench_daemon.py --dedicated (issue 37): fogd and the relay each alone, paced frames at a low rate; every
    figure of the summary is there, a number, and nothing was lost. No timing is asserted."""
    done = subprocess.run([sys.executable, "-W", "ignore", str(TOOLS / "bench_daemon.py"), "--dedicated", "--quick",
                           "--rates", "200"], capture_output=True, text=True, timeout=600)  # fmt: skip
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert "condition: dedicated" in done.stdout and "Traceback" not in done.stderr
    rows = {row["process"]: row for row in _table(done.stdout, "3k. Dedicated box")}
    assert set(rows) == {"fogd", "relay"}
    for row in rows.values():
        assert row["frames/s"] == "200"
        lost, written = (int(part) for part in row["lost"].split("/"))
        assert lost == 0 and written == 140  # 0.2 s of lead-in and 0.5 s measured at 200/s
        assert float(row["CPU"].rstrip("%")) > 0.0
        for name in ("us/frame", "wakes/frame", "p50 us", "p99 us"):
            assert float(row[name]) > 0.0, name
    ratios = _table(done.stdout, "3l. Dedicated box")
    assert [row["process"] for row in ratios] == ["fogd"] and ratios[0]["CPU"].endswith("x")
    assert any(line.startswith("**On a dedicated box**") for line in done.stdout.splitlines())


def test_the_results_page_opens_with_what_a_dedicated_box_should_see():
    """bench.py --markdown: the dedicated benchmark's EXPECT line is repeated under the page's intro, above every
    section, and stays in its own section too."""
    sys.path.insert(0, str(TOOLS))
    import bench

    expect = f"{bench.EXPECT} expect fogd to take about 12.0 % at 1,000 frames/s\n"
    kept = ["\n## daemon: `python tools/bench_daemon.py`\n\n", "| a |\n", "\n## dedicated: `...`\n\n", "| b |\n",
            expect, "\ndedicated: ok in 1 s\n"]  # fmt: skip
    page = bench.page_body(kept)
    assert page.startswith(bench.PAGE_INTRO)
    assert page.index(expect) < page.index("## daemon") and page.count(expect) == 2


@pytest.mark.parametrize("restored", [True, False])
def test_the_dedicated_box_restored_condition_starts_fogd_on_its_state_file(tmp_path, restored):
    """bench_dedicated's restored-state process (what a box running all day sees) is the real daemon restoring the
    state file the harness wrote for its port: no WARMING bound runs; fogd started without one starts cold."""
    import bench_daemon
    import bench_dedicated

    command = (bench_dedicated.restored_command(str(bench_daemon.DEMO_MODEL), tmp_path) if restored
               else bench_daemon.fogd_command(str(bench_daemon.DEMO_MODEL)))  # fmt: skip
    harness = bench_daemon.Harness("fogd", command)
    try:
        harness.warm_up()
        step = harness.run(bench_daemon.Step(200.0, 0.3))
    finally:
        log = harness.stop()
    assert step.loss == 0 and step.read > 0
    assert ("thermal state: restored" in log) == restored and ("cold start" in log) != restored, log


def test_the_floor_process_does_fogds_job_byte_for_byte(tmp_path):
    """bench_dedicated.py's `floor: least Python` (bench_loop_prototype.py --upto floor) is the least Python doing
    fogd's job: over real ptys, frame by frame, its output is the bytes fogd's own daemon path makes of the same
    frames (the demo model, no thermal state), so the floor it sets is a floor of the same work."""
    import os
    import pty
    import select
    import tty

    from bench_daemon import DEMO_MODEL, frame_cycle

    from fogd.core import modelfile
    from fogd.protocols.kvh import KvhProtocol
    from fogd.protocols.lexer import Lexer
    from fogd.serving.daemon import Daemon
    from fogd.serving.outputs import Formatter, Sink, Writer
    from fogd.serving.reader import Reader
    from fogd.serving.ring import Ring

    cycle = frame_cycle()
    frames = [cycle[i : i + 36] for i in range(0, len(cycle), 36)] * 2
    ends = [pty.openpty() for _ in range(2)]
    for master, slave in ends:
        tty.setraw(master)
        tty.setraw(slave)
    (in_master, in_slave), (out_master, out_slave) = ends
    process = subprocess.Popen([sys.executable, str(TOOLS / "bench_loop_prototype.py"), "--upto", "floor", str(DEMO_MODEL),
                                os.ttyname(in_slave), os.ttyname(out_slave)])  # fmt: skip
    floor = []
    try:
        # its ports are set raw (which flushes what waits on them) before it first polls: frames from then on
        wchan = Path(f"/proc/{process.pid}/wchan")
        for _ in range(1200):  # (the kernel names the wait it sleeps in: a minute for its imports at most)
            if "poll" in wchan.read_text():
                break
            assert process.poll() is None, "the floor process ended"
            time.sleep(0.05)
        else:
            pytest.fail(f"the floor process never waited in poll(): {wchan.read_text()!r}")
        for frame in frames:  # one frame a read, as the floor's stream is; each waited for
            os.write(in_master, frame)
            got = b""
            while len(got) < 36:
                assert select.select([out_master], [], [], 30.0)[0], "the floor process wrote nothing within 30 s"
                got += os.read(out_master, 36 - len(got))
            floor.append(got)
    finally:
        process.terminate()
        process.wait(10)
        for fd in (in_master, in_slave, out_master, out_slave):
            os.close(fd)

    out_r, out_w = os.pipe()
    protocol = KvhProtocol(comp_axes=(2,))
    writer = Writer(Sink("pipe", out_w, blocking=False, on_close=lambda: os.close(out_w)))
    reader = Reader(lambda: None, Lexer(protocol), Ring(1 << 12))
    daemon = Daemon(reader=reader, writer=writer, formatter=Formatter("same", protocol, 2),
                    model=modelfile.load(str(DEMO_MODEL)), rate_hz=1000.0, axis=2, temp_stale_s=2.0,
                    status_interval_s=3600.0)  # fmt: skip
    writer.start(b"")
    reader.inline = daemon.take_inline
    for frame in frames:
        reader._push(reader.lexer.feed(frame), 0.0)
    assert writer.close(5.0)
    fogd = os.read(out_r, 1 << 16)
    os.close(out_r)
    assert b"".join(floor) == fogd
    assert fogd != b"".join(frames)  # (the model compensated them)
