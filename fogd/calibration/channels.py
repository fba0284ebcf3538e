"""Training a model per channel of an IMU, and per unit of a production line, in parallel through joblib.

`fit_channel` is what `fogd-train` does for one channel, as it always has for one axis: `--method auto`'s
selection or `--compare`'s families, the summary, tables 3 and 4, and whether the model's held-out drift is
worse than none. Every channel of every unit is one `ChannelJob`; `fit_channels` runs them through one
`joblib.Parallel`, so whatever backend runs the swarm (`joblib.parallel_config(backend="loky" | "dask" |
"ray")`) runs them too. A job hands back what it would have printed (its `Transcript`) with its fit; the command
prints them in order, checks them and writes one model file per unit (`unit_document`: version 3 for an IMU's
channels, fogd.core.modelfile). The channels of one unit share its runs' temperature inputs, computed once
(`channel_jobs`, fogd.calibration.features.shared_inputs).
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import sys
from contextlib import nullcontext
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from joblib import Parallel, delayed

from fogd.calibration.features import Inputs, run_inputs, shared_inputs
from fogd.calibration.ladder import NONE, climb
from fogd.calibration.models import METHODS
from fogd.calibration.models.folds import MIN_RUNS_LEFT_OUT, drift_rmse
from fogd.calibration.replay import replay, replay_table
from fogd.calibration.selection import select, table_lines
from fogd.calibration.tables import epsilon_key, error_table, unit_named
from fogd.calibration.training import TrainConfig, Trained, for_sensor, prepare, sensor_noise_c, train
from fogd.core import modelfile
from fogd.core.columns import BLOCK_S, SINGLE_CHANNEL, block_samples, channel_unit
from fogd.core.errorstats import block_means
from fogd.core.inputs import TEMP_LAG, InputSpec, describe_inputs
from fogd.core.runio import Run
from fogd.errors import FogdError, InputError


@dataclass
class Settings:
    """How every channel is fitted: fogd-train's options, the same for every channel and every unit."""

    config: TrainConfig
    sets: list[tuple[InputSpec, ...]]  # the input sets: config.inputs, or --method auto's candidates
    auto: bool = False
    compare: bool = False
    log: bool = True  # --method auto's progress lines
    ladder: bool = False  # the default: the model chosen from fogd.calibration.ladder's rungs
    average_s: float = 0.5  # the eq. 16 estimator's, for the ladder's rate inputs
    step_s: float = 0.0


@dataclass
class ChannelJob:
    """One channel of one unit: its calibration and held-out runs as single-channel runs (Run.channel)."""

    unit: str
    channel: str | None  # None: single-axis runs (t_s,rate_dph,temp_c), whose model file stays version 2
    runs: list[Run]
    holdouts: list[Run] = field(default_factory=list)
    inputs: list[Inputs] | None = None  # the runs' temperature inputs, computed once for the unit's channels
    sensor_noise_c: float | None = None  # the unit's fine sensor's noise, chosen once for its channels (0: none)

    @property
    def title(self) -> str:
        return ": ".join(part for part in (self.unit, self.channel) if part)


@dataclass
class Transcript:
    """What a job prints, in order: live (one job in the command's own process) or kept for the command to
    print after a parallel run, where a worker's output would interleave or be lost."""

    live: bool = False
    lines: list[tuple[bool, str]] = field(default_factory=list)  # (to stderr, text)

    def out(self, text: str) -> None:
        self._add(False, text)

    def err(self, text: str) -> None:
        self._add(True, text)

    def _add(self, to_stderr: bool, text: str) -> None:
        if self.live:
            print(text, file=sys.stderr if to_stderr else sys.stdout, flush=to_stderr)
        else:
            self.lines.append((to_stderr, text))

    def replay(self) -> None:
        for to_stderr, text in self.lines:
            print(text, file=sys.stderr if to_stderr else sys.stdout)
        sys.stdout.flush()


@dataclass
class ChannelFit:
    """A job's result: the chosen model and every family fitted, or the one-line error that stopped it."""

    unit: str
    channel: str | None
    transcript: Transcript
    label: str = ""
    trained: dict[str, Trained] = field(default_factory=dict)
    chosen: Trained | None = None
    held_out_dph: float | None = None
    selection: list[str] | None = None  # --method auto's table (markdown) for the report
    worse: str | None = None  # the held-out drift exceeds the uncompensated drift: what to say
    uncompensated: bool = False  # the ladder chose rung 0: the channel's readings pass through unchanged
    error: FogdError | None = None


def channel_jobs(unit: str, runs: list[Run], holdouts: list[Run], channels: list[str] | None,
                 settings: Settings) -> list[ChannelJob]:  # fmt: skip
    """The jobs of one unit: one per channel (`channels`, or every channel all its runs have), or a single
    one for single-axis runs. InputError (one line) when the runs disagree or lack a channel asked for."""
    where = f"unit {unit}: " if unit else ""
    single = [run.path for run in runs + holdouts if tuple(run.channels) == (SINGLE_CHANNEL,)]
    if single:
        if len(single) < len(runs) + len(holdouts):
            raise InputError(f"{where}{single[0]} is a single-axis run (t_s,rate_dph,temp_c) and others are IMU runs; "
                             "train them separately")  # fmt: skip
        if channels:
            raise InputError(f"{where}--channels picks an IMU run's channels; {single[0]} is a single-axis run "
                             "(t_s,rate_dph,temp_c)")  # fmt: skip
        return [ChannelJob(unit, None, runs, holdouts)]
    common = [name for name in runs[0].channels if all(name in run.channels for run in runs)]
    for name in channels or ():
        for run in runs + holdouts:
            if name not in run.channels:
                raise InputError(f"{where}{run.path} has no channel {name}; it has {', '.join(run.channels)}")
    chosen = list(dict.fromkeys(channels)) if channels else common
    if not chosen:
        raise InputError(f"{where}the runs have no channel in common")
    # the channels share the unit's temperature sensor: a fine one's noise (fogd.calibration.training.with_undither)
    # is chosen once, on the channel whose drift stands out most from its noise
    noise_c = settings.config.sensor_noise_c
    lag_sets = [specs for specs in settings.sets if any(spec.kind == TEMP_LAG for spec in specs)]
    if noise_c is None and lag_sets:
        clearest = max(chosen, key=lambda name: drift_to_noise([run.channel(name) for run in runs], settings.config.block_s))
        noise_c = sensor_noise_c([run.channel(clearest) for run in runs], dataclasses.replace(settings.config, inputs=lag_sets[0]))
    config = dataclasses.replace(settings.config, sensor_noise_c=noise_c)
    # the sets as training will compute them (dequantised or undithered), so that every channel finds them
    sets = [for_sensor(runs, dataclasses.replace(config, inputs=specs)).inputs for specs in settings.sets]
    inputs = [run_inputs(run, sets, settings.config.smoothed_fit) for run in runs] if len(chosen) > 1 else None
    return [ChannelJob(unit, name, [run.channel(name) for run in runs], [run.channel(name) for run in holdouts], inputs,
                       noise_c)
            for name in chosen]  # fmt: skip


def drift_to_noise(runs: list[Run], block_s: float) -> float:
    """How far a channel's thermal drift stands out from its noise: the std of its block means about each run's
    mean over the block-to-block noise (the std of successive differences over root 2: drift is smooth)."""
    drift, noise = [], []
    for run in runs:
        means, _ = block_means(run.rate_dph, np.isfinite(run.rate_dph), block_samples(block_s, run.rate_hz))
        means = means[np.isfinite(means)]
        drift.append(means - means.mean() if means.size else means)
        noise.append(np.diff(means) / np.sqrt(2.0))
    drift_all, noise_all = np.concatenate(drift), np.concatenate(noise)
    return float(np.std(drift_all) / np.std(noise_all)) if noise_all.size > 1 and np.std(noise_all) > 0 else 0.0


def fit_channels(jobs: list[ChannelJob], settings: Settings, n_jobs: int = 1) -> list[ChannelFit]:
    """Fit every job, in parallel over `n_jobs` joblib workers (the active joblib backend) when there are
    several: each swarm then runs in its own worker, with no progress bar. One job runs here, printing live,
    its swarm over the `n_jobs` workers as a single-axis fogd-train always has."""
    if len(jobs) == 1:
        return [fit_channel(jobs[0], settings, live=True)]
    fit = dataclasses.replace(settings.config.fit, n_jobs=1, progress=False)
    quiet = dataclasses.replace(settings, config=dataclasses.replace(settings.config, fit=fit))
    return list(Parallel(n_jobs=n_jobs)(delayed(fit_channel)(job, quiet) for job in jobs))


def fit_channel(job: ChannelJob, settings: Settings, *, live: bool = False) -> ChannelFit:
    """Fit one channel as fogd-train fits one axis; errors an operator can act on are returned, not raised."""
    transcript = Transcript(live)
    result = ChannelFit(job.unit, job.channel, transcript)
    sharing = shared_inputs(job.runs, job.inputs) if job.inputs else nullcontext()
    try:
        with sharing:
            _fit(job, settings, result)
    except FogdError as error:
        result.error = error
    return result


def _fit(job: ChannelJob, settings: Settings, result: ChannelFit) -> None:
    say = result.transcript
    config = settings.config
    if job.sensor_noise_c is not None:  # the unit's choice, for all its channels
        config = dataclasses.replace(config, sensor_noise_c=job.sensor_noise_c)
    if job.title and not say.live:  # a parallel run's transcripts, printed one after another
        say.out(f"\n=== {job.title} ===")
    if job.channel is not None and config.name:
        config = dataclasses.replace(config, name=f"{config.name} {job.channel}")
    unit = channel_unit(job.channel)
    config = dataclasses.replace(config, unit=unit)
    runs = job.runs
    nothing_dph = None  # the uncompensated drift on the held-out folds (the ladder's), else the blocks' own
    if settings.ladder:
        ladder = climb(runs, config, log=say.err if settings.log else None, unit=unit,
                       average_s=settings.average_s, step_s=settings.step_s)  # fmt: skip
        result.label = f"ladder: {ladder.chosen.rung.name}"
        result.trained = {result.label: ladder.trained}
        result.chosen = ladder.trained
        result.chosen.document["metrics"]["held_out"] = ladder.held_out()
        result.chosen.document["training"]["ladder"] = {"rule": "one standard error of the per-fold ratios", "folds": ladder.folds,
                                                        "rungs": [s.row() for s in ladder.scored]}  # fmt: skip
        result.selection = ladder.table(unit)
        say.out(f"{job.channel}: {ladder.line(unit)}" if job.channel else ladder.line(unit))
        result.uncompensated = ladder.chosen.rung.method == NONE
        result.held_out_dph = ladder.chosen.drift_rmse_dph
        nothing_dph = ladder.uncompensated_dph
    elif settings.auto:
        best, candidates = select(runs, config, settings.sets, log=say.err if settings.log else None, unit=unit)
        result.label = f"auto: {best.label}"
        result.trained = {result.label: best.trained}
        result.chosen = best.trained
        folds = "leave-one-run-out" if len(runs) >= MIN_RUNS_LEFT_OUT else f"{config.fit.folds} blocked time folds of every run"
        result.chosen.document["training"]["selection"] = {
            "folds": folds,
            "chosen": best.row(),
            "candidates": [candidate.row() for candidate in candidates],
        }
        result.selection = table_lines(candidates, best, markdown=True, unit=unit)
        say.out(f"\nModel selection (--method auto): nested held-out RMSE of each candidate, {folds}")
        say.out("\n".join(table_lines(candidates, best, unit=unit)))
        say.out(f"chosen: {best.label} (nested held-out RMSE {best.held_out_rmse_dph:.3e} {unit})")
        result.held_out_dph = best.held_out_rmse_dph
    else:
        prepared = prepare(runs, config)
        for method in list(METHODS) if settings.compare else [config.method]:
            try:
                result.trained[method] = train(runs, dataclasses.replace(config, method=method), prepared)
            except InputError as error:  # --compare: a family these runs cannot fit is skipped, and said so
                if method == config.method:
                    raise
                say.err(f"fogd-train: --compare: {method} skipped: {error}")
        result.label = config.method
        result.chosen = result.trained[config.method]
        result.held_out_dph = result.chosen.fitted.cv_rmse_dph
    chosen = result.chosen
    for line in summary(chosen, unit):
        say.err(line)
    for method, fitted in ((m, t.fitted) for m, t in result.trained.items()):
        if fitted.unconverged_fits:
            say.err(f"{method}: {fitted.unconverged_fits} of scikit-learn's fits stopped at their iteration limit "
                    "(scored by held-out error like every other fit)")  # fmt: skip
    block_s = config.block_s
    say.out(f"\nTable 3: fit on the training runs ({len(chosen.error_dph)} blocks of {block_s:g} s, about each run's mean)")
    rows = [("Before compensation", chosen.before)] + [(m, t.after) for m, t in result.trained.items()]
    say.out(error_table(rows, unit=unit))
    for holdout in job.holdouts:
        say.out(f"\nTable 4: {holdout.name}, not used for training (block means about the run mean)")
        say.out(error_table(holdout_rows(result.trained, holdout, BLOCK_S), unit=unit))
    result.worse = worse_than_nothing(chosen, result.held_out_dph, unit, nothing_dph)


def uncompensated_drift_dph(trained: Trained) -> float:
    """The calibration blocks' drift with no compensation, about each run's mean (as the held-out figure)."""
    return drift_rmse(trained.error_dph, trained.data.groups)


def worse_than_nothing(trained: Trained, held_out_dph: float | None, unit: str = "deg/h",
                       uncompensated_dph: float | None = None) -> str | None:  # fmt: skip
    """What to say when the model's held-out drift exceeds the drift it is meant to remove (`uncompensated_dph`,
    scored on the same folds, or else the calibration blocks' own drift), else None."""
    if uncompensated_dph is None:
        uncompensated_dph = uncompensated_drift_dph(trained)
    if held_out_dph is None or held_out_dph <= uncompensated_dph:
        return None
    return (f"the model's held-out drift ({held_out_dph:.3e} {unit}) exceeds the uncompensated drift "
            f"({uncompensated_dph:.3e} {unit}): it would make the {'sensor' if unit == 'g' else 'gyro'} worse")  # fmt: skip


def summary(trained: Trained, unit: str = "deg/h") -> list[str]:
    """The chosen fit's hyper-parameters and its held-out drift beside the uncompensated one."""
    if trained.fitted.hyperparameters.get("compensation") == "none":  # the ladder's rung 0 (training.no_compensation)
        return ["no compensation: the readings pass through unchanged (a linear model whose coefficients are zero)"]
    hyper = unit_named(trained.fitted.hyperparameters, unit)
    if epsilon_key(unit) in hyper:  # the tube in the channel's unit says what the scaled epsilon says; one is enough
        hyper.pop("epsilon", None)
    lines = [f"{trained.fitted.method}: " + ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in hyper.items())]
    resolutions = {spec.dequantise_c for spec in trained.model.inputs} - {None}
    if resolutions:
        smoothed = trained.document["training"].get("fit_temperature") == "smoothed"
        lines.append(f"inputs: {describe_inputs(trained.model.inputs)}: the sensor reports steps of "
                     f"{', '.join(f'{value:g}' for value in resolutions)} C (--sensor-resolution-c 0: the readings); "
                     + ("fitted from its offline estimate (--fit-temperature causal: as the daemon computes it)"
                        if smoothed else "fitted as the daemon computes it"))  # fmt: skip
    undithered = {spec.source for spec in trained.model.inputs if spec.undither_c is not None}
    for _, resolution_c, noise_c, tau_s in sorted(undithered):
        lines.append(f"inputs: {describe_inputs(trained.model.inputs)}: the sensor reports steps of {resolution_c:g} C; "
                     f"their flicker read as a {noise_c:.2g} C noise, averaged over {tau_s:g} s "
                     "(--sensor-noise-c 0: the readings)")  # fmt: skip
    if trained.fitted.cv_rmse_dph is not None:
        lines.append(f"held-out (cv) drift RMSE: {trained.fitted.cv_rmse_dph:.3e} {unit} (about each run's mean), "
                     f"uncompensated {uncompensated_drift_dph(trained):.3e} {unit}")
    return lines


def holdout_rows(trained: dict[str, Trained], holdout: Run, block_s: float) -> list:
    """Table 4's rows for a held-out run: before, each fitted family after, and the best possible."""
    tables = {method: replay_table(holdout, replay(t.model, holdout), block_s) for method, t in trained.items()}
    first = next(iter(tables.values()))
    rows = [("Before compensation", first.before)] + [(method, table.after) for method, table in tables.items()]
    if first.best is not None:
        rows.append(("Best possible (true error removed)", first.best))
    return rows


def unit_document(name: str | None, fits: list[ChannelFit]) -> dict[str, Any]:
    """The model document of one unit's fits: the one model of single-axis runs as it always was (version 2),
    or every channel's model in one multi-channel (version 3) document."""
    if len(fits) == 1 and fits[0].channel is None:
        return fits[0].chosen.document
    created = dt.datetime.now(dt.timezone.utc).replace(microsecond=0).isoformat()
    documents = {fit.channel: fit.chosen.document for fit in fits}
    default = f"{fits[0].label.removeprefix('auto: ').split(' ')[0].rstrip(':')}-{created[:10]}"  # ladder-DATE, pso-svr-DATE
    return modelfile.channels_document(name=name or default, documents=documents, created_utc=created)
