"""Every figure of an accelerometer channel in its own unit (g), never deg/h: fogd-train's --method auto table and
fit lines, tables 3 and 4, the report and its figures, the Allan summaries of fogd-train and fogd-replay; a gyro
channel keeps deg/h."""

from __future__ import annotations

import re
from pathlib import Path

import matplotlib
import pytest

from fogd.cli import replay as replay_cli
from fogd.cli import train as train_cli

matplotlib.use("Agg")
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.text import Text  # noqa: E402

SMALL_SWARM = ["--particles", "4", "--iterations", "2"]


@pytest.fixture(scope="module")
def runs(imu_runs) -> dict[str, Path]:
    return imu_runs  # tests/conftest.py's, written once per session


@pytest.fixture
def figure_texts(monkeypatch) -> list[str]:
    """Every text (titles, axis labels, legends, ticks) of every figure saved while the test runs."""
    texts: list[str] = []
    save = Figure.savefig

    def recording(self, *args, **kwargs):
        texts.extend(text.get_text() for text in self.findobj(Text) if text.get_text())
        return save(self, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", recording)
    return texts


def train(runs, tmp_path, capsys, channel: str, method: str = "auto") -> tuple[str, Path]:
    """fogd-train on one channel with a report; everything it printed, and the report's directory."""
    report = tmp_path / "report"
    args = [runs["heat"], runs["cool"], "-o", tmp_path / "m.json", "--channels", channel, "--method", method,
            *SMALL_SWARM, "--holdout", runs["check"], "--report", report]  # fmt: skip
    assert train_cli.main([str(arg) for arg in args]) == 0
    captured = capsys.readouterr()
    return captured.out + captured.err, report / channel


def test_an_accelerometer_channel_is_in_g_everywhere(runs, tmp_path, capsys, figure_texts):
    printed, report = train(runs, tmp_path, capsys, "accel_z_g")
    summary = (report / "report.md").read_text()
    assert figure_texts, "no figure was saved"
    for where, text in (("fogd-train's output", printed), ("report.md", summary), ("the figures", "\n".join(figure_texts))):
        assert "deg/h" not in text and "dph" not in text and "deg/sqrt" not in text, (where, text)
    assert "held-out RMSE (g)" in printed and "RMSE (g)" in printed and re.search(r"epsilon_g=\d", printed), printed
    assert "Held-out RMSE (g)" in summary and "Held-out (cv) RMSE (g)" in summary and "bias instab. (g)" in summary
    assert "noise (g/sqrt Hz)" in summary and "epsilon_g=" in summary
    assert {"error (g)", "residual (g)", "reading - mean (g)", "Allan deviation (g)"} <= set(figure_texts)
    replayed = tmp_path / "out.csv"
    capsys.readouterr()
    assert replay_cli.main([str(tmp_path / "m.json"), str(runs["check"]), "-o", str(replayed),
                            "--allan-plot", str(tmp_path / "allan.png")]) == 0  # fmt: skip
    captured = capsys.readouterr()
    assert "deg/h" not in captured.out and "bias instab. (g)" in captured.out and "noise (g/sqrt Hz)" in captured.out
    assert figure_texts.count("Allan deviation (g)") == 2  # the report's and fogd-replay's --allan-plot


def test_a_gyro_channel_keeps_deg_per_hour(runs, tmp_path, capsys, figure_texts):
    printed, report = train(runs, tmp_path, capsys, "rate_x_dph", "pso-svr")
    summary = (report / "report.md").read_text()
    assert "RMSE (deg/h)" in printed and re.search(r"epsilon_dph=\d", printed) and "(g)" not in printed
    assert "Held-out (cv) RMSE (deg/h)" in summary and "ARW (deg/sqrt h)" in summary and "(g)" not in summary
    assert {"error (deg/h)", "Allan deviation (deg/h)", "rate - mean (deg/h)", "best fitness (deg/h)"} <= set(figure_texts)
    assert not any("(g)" in text for text in figure_texts)


def test_an_accelerometers_swarm_convergence_is_in_g(runs, tmp_path, capsys, figure_texts):
    """pso-svr alone (auto's candidates keep no swarm history): the report's convergence figure."""
    printed, _ = train(runs, tmp_path, capsys, "accel_z_g", "pso-svr")
    assert "best fitness (g)" in figure_texts and "deg/h" not in printed
    assert not any("deg/h" in text for text in figure_texts)
