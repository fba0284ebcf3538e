"""The training report of `fogd-train --report DIR`: PNG figures and a markdown summary (`report.md`).

Owns the figures of the paper's section 4 for a training: each method's fit and residual over time (figs
4-6) with each run's offset taken off, the error against temperature coloured by the temperature rate with each
model drawn along each training run (hysteresis), PSO convergence, and the compensation of held-out runs (figs
7-9); and the summary with tables 3 and 4, its captions written from each model's inputs. matplotlib is imported here
only, with the Agg backend, when a report is written.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from fogd.calibration.replay import (
    SETTLE_S,
    ReplayTable,
    allan_curves,
    replay,
    replay_table,
)
from fogd.calibration.tables import epsilon_key, error_table, unit_named
from fogd.core.atomic import replaced
from fogd.core.columns import BLOCK_S, TRUE_ERROR_COLUMN
from fogd.core.errorstats import ErrorStats, centred_within_runs
from fogd.core.inputs import TEMP, TEMP_LAG, TEMP_PLAY, TEMP_RATE, InputSpec, describe_inputs
from fogd.core.runio import Run
from fogd.errors import InputError, describe_os_error

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from fogd.calibration.training import Trained

DPI = 120
SUMMARY = "report.md"
MEASURED, TRUTH, BEFORE = "tab:gray", "black", "0.55"


def write_report(
    directory: str,
    trained: dict[str, Trained],
    chosen: str,
    holdouts: list[Run],
    block_s: float,
    *,
    selection: list[str] | None = None,
    allan: bool = False,
    settle_s: float = SETTLE_S,
    unit: str = "deg/h",
    holdout_block_s: float = BLOCK_S,
) -> str:
    """Write the figures and `report.md` into `directory` (created if missing); returns the summary's path.

    `selection`: the `--method auto` table (markdown lines); `allan`: add the Allan deviation of each held-out
    run before and after compensation by the chosen model (table and log-log figure); `settle_s`: the thermal
    settling table 4 skips at the start of each held-out run (`fogd.calibration.replay.block_grid`) and
    `holdout_block_s` its blocks (`block_s`: the fit's, for table 3); `unit`: the
    channel's (g for an accelerometer), in which every figure, table and number of the report is given."""
    import matplotlib

    matplotlib.use("Agg")
    out = Path(directory)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise InputError(f"cannot create report directory {describe_os_error(error)}") from None
    colours = {method: f"C{index}" for index, method in enumerate(trained)}
    first = next(iter(trained.values()))
    lines = _training_summary(trained, chosen, block_s, unit)
    if selection:
        lines += [
            "## Model selection",
            "",
            "Held-out drift of every candidate (`--method auto`'s families, or the default ladder's rungs), each "
            "scored on blocks it was not fitted on, all on the same blocks; the table says which folds.",
            "",
            *selection,
            "",
        ]
    lines += [f"## Table 3: fit on the training runs ({len(first.error_dph)} blocks of {block_s:g} s)", ""]
    rows = [("Before compensation", first.before)] + [(method, t.after) for method, t in trained.items()]
    lines += [error_table(rows, markdown=True, unit=unit), ""]
    for method, t in trained.items():
        name = _save(_fit_figure(method, t, colours[method], block_s, unit), out, f"fit_{_slug(method)}.png")
        lines += [_fit_caption(method, t, unit), "", f"![{method}: fit and residual]({name})", ""]
    name = _save(_hysteresis_figure(trained, colours, unit), out, "error_vs_temperature.png")
    lines += [
        "## Error against temperature",
        "",
        *_hysteresis_caption(trained),
        "",
        f"![error against temperature]({name})",
        "",
    ]
    histories = {method: t for method, t in trained.items() if len(t.fitted.fitness_history)}
    if histories:
        name = _save(_convergence_figure(histories, colours, unit), out, "pso_convergence.png")
        lines += ["## PSO convergence", "", f"![PSO convergence]({name})", ""]
    for index, run in enumerate(holdouts, start=1):
        lines += _holdout_section(index, run, trained, colours, holdout_block_s, settle_s, out, unit)
        if allan:
            lines += _allan_section(index, run, chosen, trained[chosen], out, unit)
    path = out / SUMMARY
    try:
        with replaced(str(path)) as stream:  # a report rewritten over an old one leaves it whole if this fails
            stream.write("\n".join(lines))
    except OSError as error:
        raise InputError(f"cannot write {describe_os_error(error)}") from None
    return str(path)


def _training_summary(trained: dict[str, Trained], chosen: str, block_s: float, unit: str) -> list[str]:
    data = next(iter(trained.values())).data
    reference = next(iter(trained.values())).reference_dph
    lines = [
        "# fogd training report",
        "",
        f"Model written: **{chosen}** ({trained[chosen].model.name}). Targets are {block_s:g} s block means of the "
        f"rate minus the reference {reference:.6g} {unit}; inputs: "
        + ", ".join(f"`{spec.label}`" for spec in trained[chosen].model.inputs)
        + ".",
        "",
        "## Training runs",
        "",
        "| Run | Rows | Rate (Hz) | Blocks |",
        "|---|---:|---:|---:|",
    ]
    lines += [f"| {run['name']} | {run['rows']} | {run['rate_hz']:.6g} | {run['blocks']} |" for run in data.runs]
    lines += ["", "## Methods", "", f"| Method | Hyper-parameters | Held-out (cv) RMSE ({unit}) |", "|---|---|---:|"]
    for method, t in trained.items():
        cv = t.fitted.cv_rmse_dph
        lines.append(f"| {method} | {_hyper(t.fitted.hyperparameters, unit)} | {'-' if cv is None else f'{cv:.3e}'} |")
    return lines + [""]


def _hyper(values: dict[str, Any], unit: str = "deg/h") -> str:
    values = unit_named(values, unit)
    if epsilon_key(unit) in values:  # the tube in the channel's unit, as fogd-train's fit line: not the scaled epsilon too
        values = {k: v for k, v in values.items() if k != "epsilon"}
    return ", ".join(f"{k}={v:.4g}" if isinstance(v, (float, np.floating)) else f"{k}={v}" for k, v in values.items()) or "-"


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text)


def _save(figure: Figure, out: Path, name: str) -> str:
    import matplotlib.pyplot as plt

    figure.tight_layout()
    try:
        with replaced(str(out / name), binary=True) as stream:
            figure.savefig(stream, dpi=DPI, format="png")
    except OSError as error:
        raise InputError(f"cannot write {describe_os_error(error)}") from None
    finally:
        plt.close(figure)
    return name


def _figure(rows: int, cols: int = 1, *, width: float = 10.0, height: float = 3.2, **kw: Any) -> tuple[Figure, Any]:
    import matplotlib.pyplot as plt

    return plt.subplots(rows, cols, figsize=(width, height * rows), squeeze=False, **kw)


def _run_time_h(t: Trained, block_s: float) -> tuple[np.ndarray, list[tuple[float, str]]]:
    """Block times in hours with the runs laid end to end, and each run's (start, name) on that axis."""
    data = t.data
    times = np.empty_like(data.block_t_s)
    spans, offset = [], 0.0
    for index, info in enumerate(data.runs):
        here = data.groups == index
        times[here] = (data.block_t_s[here] + offset) / 3600.0
        end = offset + float(data.block_t_s[here].max()) + block_s / 2
        spans.append((offset / 3600.0, info["name"]))
        offset = end
    return times, spans


def run_offsets(t: Trained) -> np.ndarray:
    """Each block's run offset: its run's mean of the measured error minus the fit. A run's turn-on bias is not
    thermal; table 3 scores the residual about it, and the figures take it off the measured errors."""
    residual = t.error_dph - t.fit_dph
    return residual - centred_within_runs(residual, t.data.groups)


def _fit_caption(method: str, t: Trained, unit: str) -> str:
    offsets = run_offsets(t)
    first = [offsets[t.data.groups == index][0] for index in range(len(t.data.runs))]
    each = ", ".join(f"{info['name']} {offset:+.3g}" for info, offset in zip(t.data.runs, first))
    return (f"{method}: the training runs' block errors (dots) and the fit above, the residual below, each "
            f"run's own offset (its turn-on bias, which the fit removes and table 3 does not score) taken off: "
            f"{each} {unit}. The residual should look like noise about zero, with no shape that follows the "
            "temperature.")  # fmt: skip


def _fit_figure(method: str, t: Trained, colour: str, block_s: float, unit: str) -> Figure:
    """Paper figs 4-6: measured block-mean error with the model's fit, and the residual below, each run's offset
    (`run_offsets`) taken off."""
    figure, axes = _figure(2, height=3.0, sharex=True, gridspec_kw={"height_ratios": [3, 2]})
    top, bottom = axes[0, 0], axes[1, 0]
    hours, spans = _run_time_h(t, block_s)
    measured = t.error_dph - run_offsets(t)
    if t.data.true_error_dph is not None:  # the simulator's truth about the fit in each run (bias is not thermal)
        gap = t.data.true_error_dph - t.fit_dph
        truth = t.data.true_error_dph - (gap - centred_within_runs(gap, t.data.groups))
    for index in range(len(spans)):
        here = t.data.groups == index
        label = "measured, run offset off" if index == 0 else None
        top.plot(hours[here], measured[here], ".", color=MEASURED, ms=4, label=label)
        if t.data.true_error_dph is not None:
            top.plot(hours[here], truth[here], "--", color=TRUTH, lw=1.2,
                     label="true thermal error" if index == 0 else None)  # fmt: skip
        top.plot(hours[here], t.fit_dph[here], "-", color=colour, lw=1.6, label=f"{method} fit" if index == 0 else None)
        bottom.plot(hours[here], measured[here] - t.fit_dph[here], ".-", color=colour, ms=3, lw=0.8,
                    label="residual" if index == 0 else None)  # fmt: skip
    for start, run in spans:
        for axis in (top, bottom):
            if start > 0:
                axis.axvline(start, color="k", lw=0.8, ls=":")
        top.annotate(run, (start, 1.0), xycoords=("data", "axes fraction"), xytext=(3, -3),
                     textcoords="offset points", va="top", fontsize=8, color="0.2",
                     bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": "none", "alpha": 0.8})  # fmt: skip
    before, after = t.before, t.after
    top.set_title(f"{method}: training fit (RMSE {before.rmse_dph:.3g} -> {after.rmse_dph:.3g} {unit}), "
                  "each run's offset taken off")  # fmt: skip
    top.set_ylabel(f"error ({unit})")
    bottom.set_ylabel(f"residual ({unit})")
    bottom.axhline(0.0, color="k", lw=0.6)
    bottom.set_xlabel("time (h, runs end to end)" if len(spans) > 1 else "time (h)")
    for axis in (top, bottom):
        axis.grid(True, alpha=0.4)
        axis.legend(loc="upper right", fontsize=8)
    return figure


def temperature_column(specs: tuple[InputSpec, ...]) -> int:
    """The input drawn as "the temperature": the sensor's, else the fastest lag, else the first input."""
    kinds = [spec.kind for spec in specs]
    if TEMP in kinds:
        return kinds.index(TEMP)
    lags = [index for index, spec in enumerate(specs) if spec.kind == TEMP_LAG]
    return min(lags, key=lambda index: specs[index].tau_s or 0.0) if lags else 0


def block_temperature_rate_cps(t: Trained) -> np.ndarray:
    """Each block's temperature rate (C/s): the slope of its run's block temperatures at the block (central
    differences, one-sided at a run's ends), the same for every model whatever its inputs."""
    temp_c = t.data.x[:, temperature_column(t.model.inputs)]
    rate = np.zeros_like(temp_c)
    for run in np.unique(t.data.groups):
        rows = t.data.groups == run
        if rows.sum() >= 2:
            rate[rows] = np.gradient(temp_c[rows], t.data.block_t_s[rows])
    return rate


def _hysteresis_figure(trained: dict[str, Trained], colours: dict[str, str], unit: str) -> Figure:
    """Block-mean error (each run's offset off) against temperature, coloured by the temperature rate, with each
    model's prediction along each training run: a model of more than the temperature (rates, lags, the play
    operator) has no one curve over temperature, and one drawn with its other inputs frozen leaves the data."""
    cols = min(2, len(trained))
    rows = -(-len(trained) // cols)
    figure, axes = _figure(rows, cols, width=6.0 * cols, height=4.2, sharex=True, sharey=True)
    for axis in axes.flat[len(trained):]:
        axis.set_visible(False)
    styles = ("-", "--", "-.", ":")
    for axis, (method, t) in zip(axes.flat, trained.items()):
        temp_c = t.data.x[:, temperature_column(t.model.inputs)]
        rate = block_temperature_rate_cps(t)
        limit = float(np.max(np.abs(rate))) or 1.0
        dots = axis.scatter(temp_c, t.error_dph - run_offsets(t), c=rate, cmap="coolwarm", vmin=-limit, vmax=limit,
                            s=16, edgecolors="0.4", linewidths=0.3, label="measured, run offset off")  # fmt: skip
        figure.colorbar(dots, ax=axis, label="temperature rate (C/s)")
        for index, info in enumerate(t.data.runs):
            here = t.data.groups == index
            axis.plot(temp_c[here], t.fit_dph[here], styles[index % len(styles)], color=colours[method], lw=1.2,
                      label=f"{method} along {info['name']}", path_effects=_outline())  # fmt: skip
        axis.set_title(f"{method}: error against temperature")
        axis.set_xlabel("temperature (C)")
        axis.set_ylabel(f"error ({unit})")
        axis.grid(True, alpha=0.4)
        axis.legend(fontsize=8, loc="best")
        axis.label_outer()
    empty = len(trained) % cols  # panels above an empty one are the last of their column
    for axis in axes[-2, empty:] if empty else ():
        axis.xaxis.set_tick_params(labelbottom=True)
        axis.set_xlabel("temperature (C)")
    return figure


def _hysteresis_caption(trained: dict[str, Trained]) -> list[str]:
    """What the figure draws, and what each model's real inputs can and cannot draw."""
    lines = [
        "Block means of the training runs against temperature, each run's own offset taken off, coloured by the "
        "temperature rate (C/s, the slope of the block temperatures); each line is a model's prediction along one "
        "training run, from that run's own inputs. Heating and cooling branches apart at the same temperature are "
        "the rate-driven (Shupe) error and hysteresis.",
        "",
    ]
    for method, t in trained.items():
        lines.append(f"- {method} (inputs `{describe_inputs(t.model.inputs)}`): {_what_inputs_carry(t.model.inputs)}")
    return lines


def _what_inputs_carry(specs: tuple[InputSpec, ...]) -> str:
    kinds = {spec.kind for spec in specs}
    named = ((TEMP_RATE, "the eq. 16 temperature rate"), (TEMP_LAG, "lagged temperatures (the coil's)"),
             (TEMP_PLAY, "the play operator (heating or cooling)"))
    carriers = [text for kind, text in named if kind in kinds]
    if not carriers:
        return ("a model of temperature alone: one value per temperature, so its lines lie on one curve and "
                "cannot follow branches apart.")
    return "the branches come from " + " and ".join(carriers) + "."


def _outline() -> list:
    from matplotlib import patheffects

    return [patheffects.withStroke(linewidth=2.4, foreground="k"), patheffects.Normal()]


def _convergence_figure(histories: dict[str, Trained], colours: dict[str, str], unit: str) -> Figure:
    from matplotlib.ticker import MaxNLocator

    figure, axes = _figure(1, width=7.0, height=4.0)
    axis = axes[0, 0]
    for method, t in histories.items():
        history = t.fitted.fitness_history
        fitness = t.document["training"].get("fitness") or "?"
        axis.semilogy(np.arange(1, len(history) + 1), history, "o-", ms=3, color=colours[method],
                      label=f"{method} ({fitness} RMSE)")  # fmt: skip
    axis.set_title("PSO convergence")
    axis.xaxis.set_major_locator(MaxNLocator(integer=True))
    axis.set_xlabel("iteration")
    axis.set_ylabel(f"best fitness ({unit})")
    axis.grid(True, which="both", alpha=0.4)
    axis.legend()
    return figure


def _allan_section(index: int, run: Run, chosen: str, t: Trained, out: Path, unit: str) -> list[str]:
    """Overlapping Allan deviation of a held-out run before and after compensation by the written model."""
    from fogd.calibration.allan import plot, summary_lines

    curves = allan_curves(run, replay(t.model, run))
    name = f"allan_{index}_{_slug(Path(run.name).stem)}.png"
    try:
        plot(str(out / name), curves, f"{run.name}: overlapping Allan deviation ({chosen})", unit)
    except OSError as error:
        raise InputError(f"cannot write {describe_os_error(error)}") from None
    return [
        f"### Allan deviation of {run.name} ({chosen})",
        "",
        "```",
        *summary_lines(curves, unit),
        "```",
        "",
        f"![{run.name}: Allan deviation]({name})",
        "",
    ]


def _holdout_section(
    index: int, run: Run, trained: dict[str, Trained], colours: dict[str, str], block_s: float, settle_s: float,
    out: Path,
    unit: str,
) -> list[str]:
    """Table 4 and paper figs 7-9 for one run not used for training: one replay per method, all on the run's
    one block grid."""
    truth = run.extra.get(TRUE_ERROR_COLUMN)
    figure, axes = _figure(len(trained), height=2.6, sharex=True, sharey=True)
    rows: list[tuple[str, ErrorStats]] = []
    tables: dict[str, ReplayTable] = {}
    for axis, (method, t) in zip(axes[:, 0], trained.items()):
        result = replay(t.model, run)
        table = tables[method] = replay_table(run, result, block_s, settle_s=settle_s)
        if not rows:
            rows.append(("Before compensation", table.before))
        rows.append((method, table.after))
        grid = table.grid
        hours = grid.means(run.t_s - run.t_s[0]) / 3600.0
        before = grid.means(run.rate_dph)
        after = grid.means(result.rate_comp_dph)
        axis.plot(hours, before - before.mean(), ".-", color=BEFORE, lw=0.8, ms=3,
                  label=f"before (RMSE {table.before.rmse_dph:.3g} {unit})")  # fmt: skip
        axis.plot(hours, after - after.mean(), ".-", color=colours[method], lw=1.4, ms=3,
                  label=f"{method} (RMSE {table.after.rmse_dph:.3g} {unit})")  # fmt: skip
        if truth is not None:
            ideal = grid.means(run.rate_dph - truth)
            axis.plot(hours, ideal - ideal.mean(), "--", color=TRUTH, lw=1.0,
                      label=f"best possible (RMSE {table.best.rmse_dph:.3g} {unit})")  # fmt: skip
        axis.set_ylabel(f"{'reading' if unit == 'g' else 'rate'} - mean ({unit})")
        axis.grid(True, alpha=0.4)
        axis.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    axes[0, 0].set_title(f"{run.name}: real-time compensation of a run not used for training ({block_s:g} s block means)")
    axes[-1, 0].set_xlabel("time (h)")
    first = next(iter(tables.values()))
    if first.best is not None:
        rows.append(("Best possible (true error removed)", first.best))
    name = _save(figure, out, f"holdout_{index}_{_slug(Path(run.name).stem)}.png")
    return [
        f"## Table 4: {run.name}, not used for training",
        "",
        f"{first.blocks} block means of {block_s:g} s about the run mean ({run.rows} rows at {run.rate_hz:.6g} Hz), "
        f"{_settling(first, settle_s)}; the same blocks for every row.",
        "",
        error_table(rows, markdown=True, unit=unit),
        "",
        "Share of the table's samples outside the calibrated domain: compensated by the domain guard's linear "
        "fallback (OUT_OF_DOMAIN), or with an input clamped to the calibrated range (CLAMPED).",
        "",
        "| Method | linear fallback | clamped |",
        "|---|---:|---:|",
        *(f"| {method} | {_percent(t.fallback_share)} | {_percent(t.clamped_share)} |" for method, t in tables.items()),
        "",
        f"![{run.name}: compensation]({name})",
        "",
    ]


def _settling(table: ReplayTable, settle_s: float) -> str:
    if table.settle_fallback:
        return f"from the first row (the run is too short for one block after {settle_s:g} s of settling)"
    return f"from {table.settle_s:g} s after the first row (thermal settling skipped)"


def _percent(share: float) -> str:
    return "-" if share != share else f"{100.0 * share:.1f} %"
