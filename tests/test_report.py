"""The training report: report.md with tables 3 and 4, and the PNG figures it links to."""

from __future__ import annotations

import errno
import re
from pathlib import Path

import numpy as np
import pytest

from fogd.calibration.models import METHODS, FitOptions
from fogd.calibration.replay import replay, replay_table
from fogd.calibration.report import SUMMARY, write_report
from fogd.calibration.training import TrainConfig, Trained, prepare, train
from fogd.core.inputs import default_inputs
from fogd.core.runio import Run, read_run, write_csv
from fogd.errors import InputError, OutputError

RATE_HZ = 10.0
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def simulated_run(path: Path, start_c: float, end_c: float, seed: int, hours: float = 1.0) -> Run:
    """A chamber ramp with a wobble; error = 0.002*T + 5*dT/dt (deg/h, T in C, dT/dt in C/s) plus noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, hours * 3600.0, 1.0 / RATE_HZ)
    temp = start_c + (end_c - start_c) * t / t[-1] + 2.0 * np.sin(2.0 * np.pi * t / 1500.0)
    truth = 0.002 * temp + 5.0 * np.gradient(temp, t)
    rate = 0.4 + truth + rng.normal(0.0, 0.02, t.size)
    write_csv(str(path), {"t_s": t, "rate_dph": rate, "temp_c": np.round(temp, 3), "true_error_dph": truth}, {})
    return read_run(path)


@pytest.fixture(scope="module")
def trained_runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict[str, Trained], list[Run]]:
    base = tmp_path_factory.mktemp("runs")
    runs = [simulated_run(base / "heat.csv", -10.0, 40.0, 1), simulated_run(base / "cool.csv", 40.0, -10.0, 2)]
    holdout = simulated_run(base / "holdout.csv", 0.0, 30.0, 3)
    # the paper's inputs: a full 5th-order polynomial on fogd-train's default lag bank needs far longer runs
    config = TrainConfig(block_s=60.0, inputs=default_inputs(), fit=FitOptions(particles=6, iterations=4, progress=False))
    prepared = prepare(runs, config)
    trained = {}
    for method in METHODS:
        config.method = method
        trained[method] = train(runs, config, prepared)
    return trained, [holdout]


@pytest.fixture(scope="module")
def report(trained_runs: tuple[dict[str, Trained], list[Run]], tmp_path_factory: pytest.TempPathFactory) -> Path:
    trained, holdouts = trained_runs
    directory = tmp_path_factory.mktemp("out") / "new" / "report"  # created, parents too
    return Path(write_report(str(directory), trained, "pso-svr", holdouts, 60.0, holdout_block_s=60.0))


def test_summary_has_the_tables(report: Path) -> None:
    assert report.name == "report.md" and report.is_file()
    text = report.read_text(encoding="utf-8")
    assert "Table 3" in text and "Table 4: holdout.csv" in text
    for method in METHODS:
        assert re.search(rf"^\| {re.escape(method)} \| \S+ \| \S+ \|$", text, re.M), method  # a row of each table
    assert text.count("| Before compensation |") == 2
    assert "| Best possible (true error removed) |" in text
    assert "heat.csv" in text and "cool.csv" in text


def test_holdout_table_is_on_the_settled_grid_with_shares_of_fallback_and_clamping(
    trained_runs: tuple[dict[str, Trained], list[Run]], report: Path
) -> None:
    trained, (holdout,) = trained_runs
    text = report.read_text(encoding="utf-8")
    table4 = text[text.index("## Table 4: holdout.csv") :]
    assert "50 block means of 60 s" in table4 and "from 600 s after the first row" in table4
    assert "| Method | linear fallback | clamped |" in table4
    for method, t in trained.items():
        table = replay_table(holdout, replay(t.model, holdout), 60.0)
        row = f"| {method} | {100 * table.fallback_share:.1f} % | {100 * table.clamped_share:.1f} % |"
        assert row in table4, row
    before = re.search(r"^\| Before compensation \| (\S+) \|", table4, re.M).group(1)
    assert float(before) == pytest.approx(table.before.rmse_dph, rel=1e-3)


def test_every_linked_figure_is_a_png(report: Path) -> None:
    links = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", report.read_text(encoding="utf-8"))
    # a fit per method, error vs temperature, PSO convergence, one holdout
    assert len(links) == len(METHODS) + 3
    assert any("holdout" in link for link in links) and "pso_convergence.png" in links
    for link in links:
        path = report.parent / link
        data = path.read_bytes()
        assert data[:8] == PNG_MAGIC, link
        assert len(data) > 20_000, link


def test_unwritable_directory_is_an_input_error(
    trained_runs: tuple[dict[str, Trained], list[Run]], tmp_path: Path
) -> None:
    trained, holdouts = trained_runs
    blocker = tmp_path / "a-file"
    blocker.write_text("not a directory")
    with pytest.raises(InputError, match="a-file"):
        write_report(str(blocker / "report"), trained, "pso-svr", holdouts, 60.0)


def test_a_report_that_cannot_be_written_leaves_the_old_one_whole(
    trained_runs: tuple[dict[str, Trained], list[Run]], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Every file is written to a temporary file and renamed: when the disk fills in the middle of a figure,
    the old summary and figures stay byte for byte what they were, and no temporary file is left."""
    from matplotlib.figure import Figure

    trained, holdouts = trained_runs
    directory = tmp_path / "report"
    write_report(str(directory), trained, "pso-svr", holdouts, 60.0)
    before = {path.name: path.read_bytes() for path in directory.iterdir()}
    assert SUMMARY in before and any(name.endswith(".png") for name in before)

    def disk_full(self: Figure, stream, **kwargs: object) -> None:
        stream.write(b"\x89PNG partial")
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Figure, "savefig", disk_full)
    with pytest.raises(OutputError, match="No space left"):  # EX_IOERR (74), issue 35.14
        write_report(str(directory), trained, "pso-svr", holdouts, 60.0)
    assert {path.name: path.read_bytes() for path in directory.iterdir()} == before
