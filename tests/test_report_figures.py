"""The training report's figures checked on the data they draw (read back from the matplotlib Axes), and
report.md's captions checked against the model's real inputs.

The runs are simulated here with a known temperature (so its rate is known without the code under test) and
a different turn-on bias per run (the offset each run's fit removes)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fogd.calibration import report as report_module
from fogd.calibration.models import FitOptions
from fogd.calibration.report import write_report
from fogd.calibration.training import TrainConfig, Trained, prepare, train
from fogd.core.inputs import DEFAULT_INPUTS_TEXT, default_inputs, parse_inputs
from fogd.core.runio import Run, read_run, write_csv

RATE_HZ = 5.0
BLOCK_S = 60.0
PERIOD_S = 1500.0
HOURS = 1.0
BIASES_DPH = {"heat.csv": 0.35, "cool.csv": 0.55}  # per-run turn-on biases


def temperature_c(t_s: np.ndarray, start_c: float, end_c: float) -> np.ndarray:
    return start_c + (end_c - start_c) * t_s / (HOURS * 3600.0) + 2.0 * np.sin(2.0 * np.pi * t_s / PERIOD_S)


def temperature_rate_cps(t_s: np.ndarray, start_c: float, end_c: float) -> np.ndarray:
    """The derivative of `temperature_c`, written out by hand."""
    return (end_c - start_c) / (HOURS * 3600.0) + 2.0 * (2.0 * np.pi / PERIOD_S) * np.cos(2.0 * np.pi * t_s / PERIOD_S)


PROFILES = {"heat.csv": (-10.0, 40.0), "cool.csv": (40.0, -10.0)}


def simulated_run(path: Path, seed: int) -> Run:
    """Error = 0.002*T + 5*dT/dt (deg/h) plus noise, on the run's own turn-on bias."""
    start_c, end_c = PROFILES[path.name]
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, HOURS * 3600.0, 1.0 / RATE_HZ)
    temp = temperature_c(t, start_c, end_c)
    truth = 0.002 * temp + 5.0 * temperature_rate_cps(t, start_c, end_c)
    rate = BIASES_DPH[path.name] + truth + rng.normal(0.0, 0.02, t.size)
    write_csv(str(path), {"t_s": t, "rate_dph": rate, "temp_c": np.round(temp, 4), "true_error_dph": truth}, {})
    return read_run(path)


def _train(runs: list[Run], inputs_text: str | None, method: str) -> Trained:
    inputs = default_inputs() if inputs_text is None else parse_inputs(inputs_text)
    config = TrainConfig(method=method, block_s=BLOCK_S, inputs=inputs,
                         fit=FitOptions(particles=4, iterations=2, progress=False))  # fmt: skip
    return train(runs, config, prepare(runs, config))


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> list[Run]:
    base = tmp_path_factory.mktemp("runs")
    return [simulated_run(base / name, seed) for seed, name in enumerate(PROFILES, start=1)]


@pytest.fixture(scope="module")
def trained(runs: list[Run]) -> dict[str, Trained]:
    """fogd-train's default inputs (a lag bank and a play operator) under two methods, the paper's inputs
    (temperature and its eq. 16 rate), and a model of temperature alone."""
    return {
        "pso-svr": _train(runs, DEFAULT_INPUTS_TEXT, "pso-svr"),
        "linear": _train(runs, DEFAULT_INPUTS_TEXT, "linear"),
        "paper linear": _train(runs, None, "linear"),
        "temp only": _train(runs, "temp", "linear"),
    }


@pytest.fixture(scope="module")
def drawn(trained: dict[str, Trained], tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, str]:
    """Every figure write_report saves, by file name, and the text of report.md."""
    figures: dict = {}
    save = report_module._save

    def keep(figure, out, name):  # noqa: ANN001, ANN202
        figures[name] = figure
        return save(figure, out, name)

    patch = pytest.MonkeyPatch()
    patch.setattr(report_module, "_save", keep)
    try:
        path = write_report(str(tmp_path_factory.mktemp("report")), trained, "pso-svr", [], BLOCK_S)
    finally:
        patch.undo()
    return figures, Path(path).read_text(encoding="utf-8")


def _run_rows(t: Trained) -> list[tuple[str, np.ndarray]]:
    return [(info["name"], t.data.groups == index) for index, info in enumerate(t.data.runs)]


def _offsets_dph(t: Trained) -> np.ndarray:
    """Each block's run offset: the run's mean of measured minus fit."""
    residual = t.error_dph - t.fit_dph
    offsets = np.empty_like(residual)
    for _, rows in _run_rows(t):
        offsets[rows] = residual[rows].mean()
    return offsets


def _axis(figure, method: str):  # noqa: ANN001, ANN202
    matches = [axis for axis in figure.axes if axis.get_title().startswith(f"{method}:")]
    assert len(matches) == 1, [axis.get_title() for axis in figure.axes]
    return matches[0]


def test_the_runs_have_offsets_the_fit_removes(trained: dict[str, Trained]) -> None:
    """The premise of the fit figure's test: offsets far above the residual's noise (of the models that can
    follow the rate-driven error)."""
    for t in (trained["pso-svr"], trained["linear"], trained["paper linear"]):
        offsets = _offsets_dph(t)
        assert np.ptp(offsets) > 10.0 * np.std(t.error_dph - t.fit_dph - offsets)


@pytest.mark.parametrize("method", ["pso-svr", "linear", "paper linear", "temp only"])
def test_error_against_temperature_draws_each_model_along_each_run(
    drawn: tuple[dict, str], trained: dict[str, Trained], method: str
) -> None:
    """For every model, one line per training run: the run's block temperatures and the model's prediction on
    that run's own inputs (not a curve over temperature with the other inputs frozen, which for a lag bank
    leaves the data's range many times over)."""
    t = trained[method]
    axis = _axis(drawn[0]["error_vs_temperature.png"], method)
    lines = [(np.asarray(line.get_xdata(), float), np.asarray(line.get_ydata(), float)) for line in axis.get_lines()]
    measured = t.error_dph - _offsets_dph(t)
    for name, rows in _run_rows(t):
        temp_c = t.data.x[rows, 0]  # every input set here starts with the temperature
        predicted = t.model.predict(t.data.x[rows])[0]
        drawn_here = [x.shape == temp_c.shape and np.allclose(x, temp_c) and np.allclose(y, predicted) for x, y in lines]
        assert any(drawn_here), name
    for x, y in lines:  # no line leaves the measured errors' range by more than a tenth of it
        margin = 0.1 * np.ptp(measured)
        assert measured.min() - margin <= y.min() and y.max() <= measured.max() + margin


@pytest.mark.parametrize("method", ["pso-svr", "temp only"])
def test_error_against_temperature_colours_blocks_by_the_temperature_rate(
    drawn: tuple[dict, str], trained: dict[str, Trained], method: str
) -> None:
    """The dots are the block errors with each run's offset taken off, against the block temperature, their
    colour the temperature rate (here known in closed form: within 10 % of its range of the block
    temperatures' slope, which is all 60 s blocks can tell)."""
    t = trained[method]
    axis = _axis(drawn[0]["error_vs_temperature.png"], method)
    assert len(axis.collections) == 1, "the measured blocks: one scatter coloured by rate"
    dots = axis.collections[0]
    points, colours = np.asarray(dots.get_offsets(), float), np.asarray(dots.get_array(), float)
    assert np.allclose(points[:, 0], t.data.x[:, 0])
    assert np.allclose(points[:, 1], t.error_dph - _offsets_dph(t))
    expected = np.empty_like(colours)
    for name, rows in _run_rows(t):
        expected[rows] = temperature_rate_cps(t.data.block_t_s[rows], *PROFILES[name])
    assert np.abs(colours - expected).max() < 0.1 * np.ptp(expected)
    low, high = dots.get_clim()
    assert low == pytest.approx(-high) and high >= np.abs(colours).max()  # zero rate is the map's middle


@pytest.mark.parametrize("method", ["pso-svr", "linear"])
def test_fit_figure_takes_each_runs_offset_off(
    drawn: tuple[dict, str], trained: dict[str, Trained], method: str
) -> None:
    """Above, the measured blocks with their run's offset taken off and the fit; below, the residual about
    each run's own mean: what table 3 scores."""
    t = trained[method]
    top, bottom = drawn[0][f"fit_{method}.png"].axes[:2]
    residual = t.error_dph - t.fit_dph - _offsets_dph(t)
    measured = t.error_dph - _offsets_dph(t)
    bottom_y = [np.asarray(line.get_ydata(), float) for line in bottom.get_lines()]
    top_y = [np.asarray(line.get_ydata(), float) for line in top.get_lines()]
    for name, rows in _run_rows(t):
        assert any(y.shape == residual[rows].shape and np.allclose(y, residual[rows]) for y in bottom_y), name
        assert any(y.shape == measured[rows].shape and np.allclose(y, measured[rows]) for y in top_y), name
        assert any(y.shape == measured[rows].shape and np.allclose(y, t.fit_dph[rows]) for y in top_y), name


def test_captions_name_the_models_real_inputs(trained: dict[str, Trained], drawn: tuple[dict, str]) -> None:
    text = drawn[1]
    section = text[text.index("## Error against temperature") :]
    caption = section[: section.index("![")]
    assert "the rate input" not in caption
    # the default inputs spelled out, the play with the lag fogd-train chose for it (play@2 or play@2:TAU)
    (play,) = [spec for spec in trained["pso-svr"].model.inputs if spec.width_c is not None]
    assert not play.play_lag_auto and play.width_c == 2.0
    assert f"`temp,lags@10,25.9,66.9,173,448,1160,3000,{play.short}`" in caption
    assert "`temp,rate@50`" in caption and "`temp`" in caption
    assert "temperature alone" in caption  # what a model of temperature alone cannot draw
    fit_caption = text[text.index("![pso-svr: fit and residual]") - 400 : text.index("![pso-svr: fit and residual]")]
    assert "offset" in fit_caption and "heat.csv" in fit_caption and "cool.csv" in fit_caption
