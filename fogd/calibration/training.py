"""Training: calibration runs in, a validated model document and its frozen model out.

This is where the pieces meet: block rows from `features`, a fit from `models`, the calibrated domain and
the estimator settings written into the model file so that serving cannot disagree with training.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np

from fogd.calibration.features import TrainingSet, training_set
from fogd.calibration.models import FitOptions, Fitted, fit
from fogd.core import domain, modelfile, outside_range
from fogd.core.columns import FIT_BLOCK_S, block_samples
from fogd.core.dequantise import COARSE_RESOLUTION_C, detect_resolution_c
from fogd.core.errorstats import ErrorStats, centred_within_runs
from fogd.core.frozen import FrozenModel
from fogd.core.inputs import (
    DEFAULT_INPUTS_TEXT,
    MAX_RESOLUTION_C,
    TEMP_LAG,
    TEMP_PLAY,
    InputSpec,
    dequantised,
    dequantises,
    dynamic_inputs,
    kernel_columns,
    lag_taus_s,
    parse_inputs,
    shifted_columns,
    static_columns,
    temperature_columns,
    undithered,
    undithers,
    with_play_lag_s,
)
from fogd.core.play import play_batch
from fogd.core.runio import Run
from fogd.core.undither import MAX_NOISE_STEPS, MIN_NOISE_STEPS, MIN_RESOLUTION_C
from fogd.errors import InputError, UsageError

Trial = TypeVar("Trial")  # shortest_within_tolerance's: whatever each residual belongs to


@dataclass
class TrainConfig:
    """Everything `fogd-train` decides besides the runs."""

    method: str = "pso-svr"
    inputs: tuple[InputSpec, ...] = field(default_factory=lambda: parse_inputs(DEFAULT_INPUTS_TEXT))
    block_s: float = FIT_BLOCK_S  # the fit targets' block (fogd.core.columns.FIT_BLOCK_S)
    reference: str | float = "mean"  # 'mean' of all training blocks, or a rate in deg/h
    fit: FitOptions = field(default_factory=FitOptions)
    name: str | None = None
    domain_guard: bool = False  # store a domain guard and its linear fallback (fogd.core.domain), as --domain-guard
    sensor_resolution_c: float | None = None  # None: detected from the runs; a coarse sensor is dequantised
    sensor_noise_c: float | None = None  # a fine sensor's, for its undithered estimate: None chosen on the runs, 0 none
    smoothed_fit: bool = True  # fit a dequantised temperature from its offline estimate (features.training_set)
    unit: str = "deg/h"  # the channel's unit, for what training says (an accelerometer's is g)
    outside: str = outside_range.DEFAULT_POLICY  # beyond the calibrated range (fogd.core.outside_range), as --outside-range


def for_sensor(runs: list[Run], config: TrainConfig) -> TrainConfig:
    """`config` with its inputs computed from the dequantised temperature when the runs' sensor is coarse
    (fogd.core.dequantise: a KVH's whole degrees), from the undithered one when it is fine and the inputs are a
    lag bank (with_undither), from the readings otherwise (inputs already marked are kept), and a
    `play@WIDTH:auto` input's lag chosen on the runs (with_play_lag). What it chose stays in the config it
    returns, so that a second call chooses nothing again."""
    resolution_c = _resolution_c(runs, config)
    if COARSE_RESOLUTION_C <= resolution_c <= MAX_RESOLUTION_C:
        if not dequantises(config.inputs):
            config = dataclasses.replace(config, inputs=dequantised(config.inputs, resolution_c))
    elif MIN_RESOLUTION_C <= resolution_c < COARSE_RESOLUTION_C:
        config = with_undither(runs, config, resolution_c)
    return with_play_lag(runs, config)


def _resolution_c(runs: list[Run], config: TrainConfig) -> float:
    """The sensor's resolution: as given (0: use the readings as they are), else seen in the runs."""
    resolution_c = config.sensor_resolution_c
    if resolution_c is not None and resolution_c > MAX_RESOLUTION_C:
        raise UsageError(f"--sensor-resolution-c {resolution_c:g}: a temperature sensor's steps are at most "
                         f"{MAX_RESOLUTION_C:g} C (0: use the readings as they are)")  # fmt: skip
    if resolution_c is None:
        if dequantises(config.inputs) or undithers(config.inputs):
            return 0.0  # already decided
        return detect_resolution_c([run.temp_c for run in runs])
    return resolution_c


# The undithered estimate's noise candidates, in the sensor's steps, from the gentlest (near the identity) down:
# the coil trend's residual on the calibration blocks has a clear least at the sensor's own noise
# (tools/trend_diagnostic.py --five-run --rate-prior smooth --seed 1 --thermal diffusive --case read/read --case
# und:SIGMA/und:SIGMA for each candidate: a 1/16 C sensor with 0.01 C of noise, residual 0.999 mdeg/h on the
# readings, 0.989 / 0.958 / 0.933 / 0.960 / 1.002 at 0.4 / 0.25 / 0.16 / 0.1 / 0.06 steps; the worst held-out run
# 1.45x the floor on the readings, 1.48 / 1.33 / 1.25 / 1.33 / 1.46x with those). The readings stay the first
# candidate and are kept unless an estimate leaves UNDITHER_TOLERANCE less.
UNDITHER_NOISE_STEPS = (0.4, 0.25, 0.16, 0.1, 0.06)
UNDITHER_TOLERANCE = 0.01


def sensor_noise_c(runs: list[Run], config: TrainConfig) -> float:
    """The noise for_sensor would take for the runs' fine sensor (0: the readings), for the channels of one unit to
    share (fogd.calibration.channels: they share its temperature sensor)."""
    resolution_c = _resolution_c(runs, config)
    if not MIN_RESOLUTION_C <= resolution_c < COARSE_RESOLUTION_C:
        return 0.0
    return with_undither(runs, config, resolution_c).sensor_noise_c or 0.0


def with_undither(runs: list[Run], config: TrainConfig, resolution_c: float) -> TrainConfig:
    """`config` with a fine sensor's lag-bank inputs computed from its undithered estimate (fogd.core.undither)
    of the noise `config.sensor_noise_c`, or if None the noise of UNDITHER_NOISE_STEPS (or the readings) whose
    coil trend leaves the least residual on the runs' blocks (the first within UNDITHER_TOLERANCE of it). The
    config it returns names the noise (0: the readings), so a second call keeps the choice."""
    noise_c = config.sensor_noise_c
    if noise_c == 0.0 or dequantises(config.inputs) or undithers(config.inputs):
        return config
    if noise_c is not None:
        if not MIN_NOISE_STEPS <= noise_c / resolution_c <= MAX_NOISE_STEPS:
            raise UsageError(f"--sensor-noise-c {noise_c:g}: {MIN_NOISE_STEPS:g} to {MAX_NOISE_STEPS:g} of the "
                             f"sensor's {resolution_c:g} C steps (0: the readings as they are)")  # fmt: skip
        return dataclasses.replace(config, inputs=undithered(config.inputs, resolution_c, noise_c))
    if not any(spec.kind == TEMP_LAG for spec in config.inputs) or not _single_steps(runs, resolution_c):
        return dataclasses.replace(config, sensor_noise_c=0.0)  # the paper's inputs (their windows average), or no staircase
    thinned = [_thinned(run, PLAY_CHOICE_MAX_HZ) for run in runs]
    # without the play: it turns with the temperature, hardly with the staircase, and is a Python loop per sample
    # (a one-off check, five-run programme, seeds 1 and 2, both coils: the same choices, residuals within 0.2 %)
    base = tuple(spec for spec in config.inputs if spec.kind != TEMP_PLAY)
    candidates = [0.0] + [steps * resolution_c for steps in UNDITHER_NOISE_STEPS]
    trials = [(_trend_residual_dph(thinned, undithered(base, resolution_c, noise_c or None), config), noise_c)
              for noise_c in candidates]  # fmt: skip
    least = min(residual for residual, _ in trials)
    noise_c = next(noise for residual, noise in trials if residual <= least * (1.0 + UNDITHER_TOLERANCE))
    return dataclasses.replace(config, sensor_noise_c=noise_c,
                               inputs=undithered(config.inputs, resolution_c, noise_c or None))  # fmt: skip


# The play's lag candidates (0: the play of the temperature itself). A gyro's hysteresis follows its coil; how far
# the coil lags the sensor depends on where the sensor sits. tools/trend_diagnostic.py --five-run --rate-prior
# smooth --inputs temp,lags@10..3000/7 --play 2 --play 2@300 --play 2@1000 --play 2@2500 (seeds 1-3, worst held-out
# run, mean over the seeds): the sensor on the housing, lumped coil 1.14x the floor with the play of the reading,
# 1.08x on a 300 s lag; on a baseplate (--physics sensor_on=baseplate) lumped 1.32 -> 1.06x and diffusive 1.60 ->
# 1.21x on a 2500 s lag; housing_tau_s=3000 diffusive 1.25 -> 1.14x on 1000 s. Where the calibration blocks
# hardly tell the lags apart the choice is noise: diffusive coil, three runs, seed 4, the residual 0.865 / 0.864 /
# 0.864 mdeg/h for 0 / 100 / 300 s and the worst held-out run 1.54 / 1.58 / 1.70x. So the shortest lag within
# PLAY_LAG_TOLERANCE of the least residual is taken (the baseplate's 2500 s leaves 2.5 % less than the reading's).
PLAY_LAGS_S = (0.0, 100.0, 300.0, 1000.0, 2500.0)
PLAY_LAG_TOLERANCE = 0.01
PLAY_CHOICE_MAX_HZ = 10.0  # the choice is made on the runs thinned to this rate: a play loop per candidate


def with_play_lag(runs: list[Run], config: TrainConfig) -> TrainConfig:
    """`config` with each `play@WIDTH:auto` input's lag chosen: the coil trend over the inputs with each of
    PLAY_LAGS_S, fitted to the runs' blocks; the shortest lag whose residual about each run's mean is within
    PLAY_LAG_TOLERANCE of the least (the same terms whatever the lag). Unchanged when no input asks."""
    if not any(spec.play_lag_auto for spec in config.inputs):
        return config
    thinned = [_thinned(run, PLAY_CHOICE_MAX_HZ) for run in runs]
    if not turns(thinned, max(spec.width_c for spec in config.inputs if spec.play_lag_auto)):
        return dataclasses.replace(config, inputs=with_play_lag_s(config.inputs, 0.0))
    trials = [(_trend_residual_dph(thinned, specs, config), specs)
              for specs in (with_play_lag_s(config.inputs, lag_s) for lag_s in PLAY_LAGS_S)]  # fmt: skip
    return dataclasses.replace(config, inputs=shortest_within_tolerance(trials))


def _single_steps(runs: list[Run], resolution_c: float) -> bool:
    """Whether the readings climb a staircase: most of their changes one step of `resolution_c`. A sensor whose
    noise spans many of its steps changes by several at a time, and its readings are already dithered."""
    changes = np.concatenate([np.abs(np.diff(run.temp_c[np.isfinite(run.temp_c)])) for run in runs])
    changes = changes[changes > 1e-9 * resolution_c]
    return changes.size > 0 and float(np.mean(np.abs(changes - resolution_c) <= 1e-6 * resolution_c)) >= 0.5


def _trend_residual_dph(runs: list[Run], specs: tuple[InputSpec, ...], config: TrainConfig) -> float:
    """The RMS residual, about each run's mean, of the coil trend over `specs` fitted to the runs' blocks."""
    data = training_set(runs, specs, config.block_s, 0.0, config.smoothed_fit)
    options = dataclasses.replace(options_for_inputs(config.fit, specs), trend="coil", search=False, progress=False)
    error = data.rate_dph - float(np.mean(np.concatenate([run.rate_dph for run in runs])))
    fitted = fit("pso-svr", data.x, error, data.groups, options)
    predicted = fitted.estimator.predict((data.x - fitted.x_mean) / fitted.x_scale) * fitted.y_scale + fitted.y_mean
    return float(np.sqrt(np.mean(centred_within_runs(error - predicted, data.groups) ** 2)))


def turns(runs: list[Run], width_c: float) -> bool:
    """Whether some run turns: its play of `width_c` reaches +1 and -1 (a rise and a fall of twice the width).
    With one offset per run, a run that only heats or only cools holds its play's level in its offset, and a
    lagged play becomes one more slow transient to fit: the quick start's two monotonic runs left 1.6 % less
    residual with a 2500 s lag, and twice the held-out drift (tools/bench_train.py, navigation, 10 Hz: 2.07x
    the floor against 1.02x). Without a turn the lag cannot be told, and the reading's play is kept."""
    return any(np.ptp(play_batch(run.temp_c[np.isfinite(run.temp_c)], width_c)) >= 2.0 - 1e-9 for run in runs if run.rows)


def shortest_within_tolerance(trials: list[tuple[float, Trial]]) -> Trial:
    """Of (residual, trial) in the order of PLAY_LAGS_S, the first trial within PLAY_LAG_TOLERANCE of the least."""
    least = min(residual for residual, _ in trials)
    return next(trial for residual, trial in trials if residual <= least * (1.0 + PLAY_LAG_TOLERANCE))


def _thinned(run: Run, max_hz: float) -> Run:
    """Every k-th row of `run`, k the smallest that brings its rate to `max_hz` or below."""
    step = max(1, int(np.ceil(run.rate_hz / max_hz - 1e-9)))
    if step == 1:
        return run
    return dataclasses.replace(run, t_s=run.t_s[::step], rate_dph=run.rate_dph[::step], temp_c=run.temp_c[::step],
                               rate_hz=run.rate_hz / step, extra={key: values[::step] for key, values in run.extra.items()},
                               channels={key: values[::step] for key, values in run.channels.items()})  # fmt: skip


@dataclass
class Trained:
    """A trained model with what produced it (the fit and the block rows) for tables and figures."""

    document: dict[str, Any]
    model: FrozenModel
    fitted: Fitted
    data: TrainingSet
    reference_dph: float
    error_dph: np.ndarray  # block targets: measured block means minus the reference
    fit_dph: np.ndarray  # the model's prediction for each block

    @property
    def before(self) -> ErrorStats:
        """Table 3's "before": the block errors about each run's mean (turn-on bias is not thermal)."""
        return ErrorStats.about_run_means(self.error_dph, self.data.groups)

    @property
    def after(self) -> ErrorStats:
        return ErrorStats.about_run_means(self.error_dph - self.fit_dph, self.data.groups)


def prepare(runs: list[Run], config: TrainConfig, min_warmup_s: float = 0.0) -> tuple[TrainingSet, float]:
    """Block rows of the runs and the reference rate; shared by every method of a comparison."""
    config = for_sensor(runs, config)
    data = training_set(runs, config.inputs, config.block_s, min_warmup_s, config.smoothed_fit)
    reference = float(np.mean(data.rate_dph)) if config.reference == "mean" else float(config.reference)
    return data, reference


def train(runs: list[Run], config: TrainConfig, prepared: tuple[TrainingSet, float] | None = None) -> Trained:
    """Fit `config.method` to the runs and return the validated model."""
    config = for_sensor(runs, config)
    data, reference = prepared or prepare(runs, config)
    error = data.rate_dph - reference
    options = options_for_inputs(config.fit, config.inputs)
    fitted = fit(config.method, data.x, error, data.groups, options)
    _name_coil_temperature(fitted, config.inputs)
    return _trained(config, data, reference, error, fitted, options, config.method)


def no_compensation(runs: list[Run], config: TrainConfig, prepared: tuple[TrainingSet, float] | None = None) -> Trained:
    """The ladder's rung 0 as a model file holds it: IEEE 952's linear model with every coefficient zero, so the
    daemon and fogd-replay pass the reading through unchanged (flags as for any model: CLAMPED beyond the
    calibrated range, where the held-out estimate was not measured). The constant a model removes is the same
    as every rung's: none with the default `--reference mean`, the runs' mean rate less the reference given
    as a value (a linear fit's intercept is the runs' mean offset)."""
    config = for_sensor(runs, config)
    data, reference = prepared or prepare(runs, config)
    error = data.rate_dph - reference
    x_std = data.x.std(axis=0)
    offset_dph = 0.0 if config.reference == "mean" else float(np.mean(error))
    fitted = Fitted("linear", data.x.mean(axis=0), np.where(x_std > 0, x_std, 1.0), offset_dph, 1.0,
                    {"coef": [0.0] * data.x.shape[1], "intercept": 0.0}, {"compensation": "none"})  # fmt: skip
    options = options_for_inputs(config.fit, config.inputs)
    return _trained(config, data, reference, error, fitted, options, "uncompensated")


def _trained(config: TrainConfig, data: TrainingSet, reference: float, error: np.ndarray, fitted: Fitted,
             options: FitOptions, default_name: str) -> Trained:  # fmt: skip
    """The model document of `fitted` (`default_name`-DATE unless --name), validated by loading it back."""
    created = dt.datetime.now(dt.timezone.utc).replace(microsecond=0).isoformat()
    metrics = {
        "train_before": ErrorStats.about_run_means(error, data.groups).to_dict(),
        "cv_rmse_dph": fitted.cv_rmse_dph,
    }
    document = modelfile.document(
        name=config.name or f"{default_name}-{created[:10]}",
        method=fitted.method,
        inputs=config.inputs,
        x_mean=fitted.x_mean,
        x_scale=fitted.x_scale,
        y_mean=fitted.y_mean,
        y_scale=fitted.y_scale,
        domain_min=data.domain_min,
        domain_max=data.domain_max,
        params=fitted.params,
        reference_dph=reference,
        training={
            "runs": data.runs,
            "rate_hz": float(np.median([run["rate_hz"] for run in data.runs])),
            "block_s": config.block_s,
            "block_samples": [block_samples(config.block_s, run["rate_hz"]) for run in data.runs],
            "reference": config.reference if config.reference == "mean" else "value",
            "fitness": config.fit.fitness if fitted.method == "pso-svr" else None,
            "hyperparameters": _json_ready(fitted.hyperparameters),
            "fitness_history_dph": [float(value) for value in fitted.fitness_history],
            "fit_temperature": "smoothed" if config.smoothed_fit and dequantises(config.inputs) else "as served",
        },
        metrics=metrics,
        created_utc=created,
        domain_guard=domain_guard_document(data, error, fitted, config.fit, config.inputs) if config.domain_guard else None,
        outside_range=outside_document(config.outside, data, error, fitted, options),
    )
    try:
        model = modelfile.from_document(document)
    except modelfile.ModelOutputError as error:  # fitted here, so not hostile: a polynomial that extrapolates
        raise InputError(
            f"the fitted {fitted.method} model reaches {error.value_dph:.3g} {config.unit} within its calibrated input "
            f"range (beyond the {modelfile.MAX_COMP_DPH:g} {config.unit} any sensor could need): a polynomial "
            "extrapolating between inputs; use the default --method pso-svr, or a lower --degree or --poly-terms temp"
        ) from None
    fit_dph, _ = model.predict(data.x)
    metrics["train_after"] = ErrorStats.about_run_means(error - fit_dph, data.groups).to_dict()
    return Trained(document, model, fitted, data, reference, error, fit_dph)


def _name_coil_temperature(fitted: Fitted, specs: tuple[InputSpec, ...]) -> None:
    """Replace the coil trend's mix (weights of the scaled inputs) by what it means in degrees C, e.g.
    '0.86 lag@300 + 0.14 lag@950' (or, signed, '1.52 lag@448 - 0.52 lag@173'), for the fit line, the report and
    the model file's training section."""
    mix = fitted.hyperparameters.pop("coil_mix", None)
    if mix is None:
        return
    raw = np.asarray(mix) / fitted.x_scale
    raw = raw / raw.sum()
    text = " + ".join(f"{weight:.2f} {spec.short}" for weight, spec in zip(raw, specs) if weight != 0)
    fitted.hyperparameters["coil_temperature"] = text.replace("+ -", "- ")  # a signed mix: '1.52 lag@448 - 0.52 lag@173'


def options_for_inputs(options: FitOptions, specs: tuple[InputSpec, ...]) -> FitOptions:
    """`options` with the column roles of these inputs: temperatures, static columns, columns clamped together,
    the inputs a kernel reads."""
    return dataclasses.replace(options, temperature_columns=temperature_columns(specs),
                               static_columns=static_columns(specs), shifted_columns=shifted_columns(specs),
                               kernel_columns=kernel_columns(specs), lag_taus_s=lag_taus_s(specs))  # fmt: skip


def linear_fit(data: TrainingSet, error: np.ndarray, fitted: Fitted, options: FitOptions) -> Fitted:
    """The linear (IEEE 952) fit to the model's blocks and inputs, in the model's own scaling."""
    linear = fitted if fitted.method == "linear" else fit("linear", data.x, error, data.groups, options)
    same = all(np.array_equal(a, b) for a, b in (
        (linear.x_mean, fitted.x_mean), (linear.x_scale, fitted.x_scale),
        (linear.y_mean, fitted.y_mean), (linear.y_scale, fitted.y_scale)))  # fmt: skip
    if not same:
        raise AssertionError("the linear fit must share the model's scaling")
    return linear


def outside_document(policy: str, data: TrainingSet, error: np.ndarray, fitted: Fitted,
                     options: FitOptions) -> dict[str, Any] | None:  # fmt: skip
    """The model file's `outside_range` (fogd.core.outside_range); None for the clamp, as files without the key."""
    if policy == "clamp":
        return None
    if policy not in outside_range.LINEAR_POLICIES:
        return {"policy": policy}
    params = linear_fit(data, error, fitted, options).params
    return {"policy": policy, "coef": params["coef"], "intercept": params["intercept"]}


def domain_guard_document(data: TrainingSet, error: np.ndarray, fitted: Fitted, options: FitOptions,
                          specs: tuple[InputSpec, ...]) -> dict[str, Any]:  # fmt: skip
    """The model file's `domain_guard`: the calibration blocks in the model's scaled units, the threshold and
    the linear fallback (fitted to the same blocks, so it shares the model's scaling exactly). A "range" guard
    for a model with dynamic inputs (a lag bank, a dequantised estimate, a play operator: every new
    temperature history is far from the calibration runs' few trajectories through them), the joint one for
    the others (fogd.core.domain)."""
    linear = linear_fit(data, error, fitted, options)
    points = domain.thin((data.x - fitted.x_mean) / fitted.x_scale)
    samples = None if data.x_samples is None else (data.x_samples - fitted.x_mean) / fitted.x_scale
    fallback = {"method": "linear", "params": linear.params}
    if not dynamic_inputs(specs):
        return {"points": points.tolist(), "threshold": domain.choose_threshold(points, samples), "fallback": fallback}
    low, high = domain.range_box(points, fitted.x_mean, fitted.x_scale, temperature_columns(specs))
    margin = domain.choose_range_margin(low, high, samples)
    return {"kind": "range", "points": points.tolist(), "threshold": margin, "fallback": fallback}


def _json_ready(values: dict[str, Any]) -> dict[str, Any]:
    return {key: value.item() if isinstance(value, np.generic) else value for key, value in values.items()}
