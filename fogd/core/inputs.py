"""The model's inputs (temperature, temperature rates, lagged temperatures) and how they are computed,
streaming and in batch.

An `InputSpec` is what a model file stores about one input, so that serving computes exactly what training
computed. `InputBank` is the streaming form (O(1) per sample whatever the window lengths and time constants,
any chunk size) and `inputs_batch` the batch form; both give the same floats bit for bit (the rate estimator
works in exact integer sums, the lag filter runs one recurrence in both forms).

Kinds: `temp_c` (the held temperature), `temp_rate_cps` (eq. 16 with its window settings; several windows
may be used at once), `temp_lag_c` (a first-order lag of the temperature with time constant `tau_s`,
fogd.core.lag) and `temp_play` (the play operator of the temperature with width `width_c`, fogd.core.play:
+1 after heating, -1 after cooling; of a `play_lag_s` lag of the temperature when given). `parse_inputs` reads
the `fogd-train --inputs` syntax, e.g. `temp,rate@50,rate@300,lag@600,play@2` or `play@2:300`; `play@2:auto`
leaves the play's lag to fogd-train (fogd.calibration.training.with_play_lag), and a model file never holds it.
Any of them may be computed from the dequantised temperature of a coarse sensor instead of its readings
(`dequantise_c`, the sensor's resolution; fogd.core.dequantise), one dequantiser shared by all the inputs;
`dequantise_pace` names how that estimate runs between crossings (None: "linear", what model files written
before it existed were trained with). Or from a fine sensor's undithered estimate (`undither_c`, its
resolution, with `undither_noise_c` and `undither_tau_s`; fogd.core.undither). Each input's `source` names
what it is computed from: None (the readings), ("dequantise", resolution, pace) or ("undither", resolution,
noise, lag); inputs with the same source share one estimate.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from fogd.core.dequantise import DEFAULT_PACE, PACES, Dequantiser, dequantise_batch, smoothed_batch
from fogd.core.estimator import EstimatorSettings, TempRateEstimator, temp_rate_batch
from fogd.core.lag import MAX_TAU_S, LagFilter, update_lags_one
from fogd.core.play import MAX_WIDTH_C, LaggedPlay, PlayFilter
from fogd.core.undither import (
    DEFAULT_TAU_S,
    MAX_NOISE_STEPS,
    MIN_NOISE_STEPS,
    MIN_RESOLUTION_C,
    Undither,
    undither_batch,
)

TEMP = "temp_c"
TEMP_RATE = "temp_rate_cps"
TEMP_LAG = "temp_lag_c"
TEMP_PLAY = "temp_play"
KINDS = (TEMP, TEMP_RATE, TEMP_LAG, TEMP_PLAY)
INPUTS_SYNTAX = (
    "comma-separated inputs: 'temp' (temperature, C), 'rate@W' (eq. 16 temperature rate over a W s window, "
    "with --average-s and --step-s), 'lag@TAU' (temperature through a first-order lag of time constant TAU s, a "
    "stand-in for the coil temperature), 'lags@TAU,TAU,...' or 'lags@FIRST..LAST/COUNT' (a bank of such lags, "
    "the range log-spaced), 'play@WIDTH' (the temperature's play operator of WIDTH C: +1 after heating, -1 after "
    "cooling, for a gyro's hysteresis), 'play@WIDTH:TAU' (the same of a TAU s lag of the temperature) or "
    "'play@WIDTH:auto' (TAU chosen on the runs); e.g. temp,rate@50,rate@300,lag@600 or lags@30..3000/5,play@2"
)
MAX_INPUTS = 16
MAX_RESOLUTION_C = 10.0
DEQUANTISE = "dequantise"
UNDITHER = "undither"
Source = tuple | None  # an input's `source`: None, (DEQUANTISE, resolution, pace) or (UNDITHER, resolution, noise, lag)


@dataclass(frozen=True)
class InputSpec:
    """One model input: `temp_c`, `temp_rate_cps` with its eq. 16 estimator settings, `temp_lag_c` with
    its time constant `tau_s`, or `temp_play` with its width `width_c` (and its lag `play_lag_s`, or
    `play_lag_auto` until fogd-train chooses it); of the readings, of their dequantised estimate
    (`dequantise_c`) or of their undithered estimate (`undither_c`, `undither_noise_c`, `undither_tau_s`)."""

    kind: str
    estimator: EstimatorSettings | None = None
    tau_s: float | None = None
    dequantise_c: float | None = None  # the sensor's resolution when computed from fogd.dequantise's estimate
    dequantise_pace: str | None = None  # fogd.dequantise's pace (PACES) when not "linear"
    width_c: float | None = None
    play_lag_s: float | None = None  # the play of this lag of the temperature (None: of the temperature)
    play_lag_auto: bool = False  # `play@WIDTH:auto`: play_lag_s still to be chosen (never in a model file)
    undither_c: float | None = None  # a fine sensor's resolution when computed from fogd.core.undither's estimate
    undither_noise_c: float | None = None  # the sensor noise that estimate assumes
    undither_tau_s: float | None = None  # the lag that averages the readings before its inverse

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"unknown input {self.kind!r}; known inputs: {', '.join(KINDS)}")
        if (self.kind == TEMP_RATE) != (self.estimator is not None):
            raise ValueError(f"input {self.kind!r}: estimator settings go with {TEMP_RATE} only")
        if (self.kind == TEMP_LAG) != (self.tau_s is not None):
            raise ValueError(f"input {self.kind!r}: a time constant tau_s goes with {TEMP_LAG} only")
        if (self.kind == TEMP_PLAY) != (self.width_c is not None):
            raise ValueError(f"input {self.kind!r}: a width width_c goes with {TEMP_PLAY} only")
        if (self.play_lag_s is not None or self.play_lag_auto) and self.kind != TEMP_PLAY:
            raise ValueError(f"input {self.kind!r}: a play's lag goes with {TEMP_PLAY} only")
        if self.play_lag_s is not None and (self.play_lag_auto or not 0 < self.play_lag_s <= MAX_TAU_S):
            raise ValueError(f"a play's lag time constant must be in (0, {MAX_TAU_S:g}] s, got {self.play_lag_s}")
        if self.width_c is not None and not 0 < self.width_c <= MAX_WIDTH_C:
            raise ValueError(f"play width must be in (0, {MAX_WIDTH_C:g}] C, got {self.width_c}")
        if self.tau_s is not None and not 0 < self.tau_s <= MAX_TAU_S:
            raise ValueError(f"lag time constant must be in (0, {MAX_TAU_S:g}] s, got {self.tau_s}")
        if self.dequantise_c is not None and not 0 < self.dequantise_c <= MAX_RESOLUTION_C:
            raise ValueError(f"sensor resolution must be in (0, {MAX_RESOLUTION_C:g}] C, got {self.dequantise_c}")
        if self.dequantise_pace is not None and (self.dequantise_c is None or self.dequantise_pace not in PACES[1:]):
            raise ValueError(f"dequantiser pace {self.dequantise_pace!r}: one of {', '.join(PACES[1:])}, "
                             "for a dequantised input only")
        undither = (self.undither_c, self.undither_noise_c, self.undither_tau_s)
        if any(value is not None for value in undither):
            if any(value is None for value in undither) or self.dequantise_c is not None:
                raise ValueError("an undithered input needs its resolution, noise and lag, and is not dequantised")
            resolution_c, noise_c, tau_s = undither
            if not MIN_RESOLUTION_C <= resolution_c <= MAX_RESOLUTION_C:
                raise ValueError(f"sensor resolution must be {MIN_RESOLUTION_C:g} to {MAX_RESOLUTION_C:g} C, "
                                 f"got {resolution_c}")  # fmt: skip
            if not MIN_NOISE_STEPS <= noise_c / resolution_c <= MAX_NOISE_STEPS:
                raise ValueError(f"sensor noise must be {MIN_NOISE_STEPS:g} to {MAX_NOISE_STEPS:g} of its resolution "
                                 f"({resolution_c:g} C), got {noise_c} C")  # fmt: skip
            if not 0 < tau_s <= MAX_TAU_S:
                raise ValueError(f"the undither lag must be in (0, {MAX_TAU_S:g}] s, got {tau_s}")

    @property
    def source(self) -> Source:
        """What the input is computed from: None (the readings), the dequantiser's (DEQUANTISE, resolution, pace)
        or the undither's (UNDITHER, resolution, noise, lag)."""
        if self.undither_c is not None:
            return (UNDITHER, self.undither_c, self.undither_noise_c, self.undither_tau_s)
        return None if self.dequantise_c is None else (DEQUANTISE, self.dequantise_c, self.dequantise_pace or PACES[0])

    @property
    def label(self) -> str:
        """A short unique name, e.g. 'temp_rate_cps@50s' or 'temp_lag_c@600s'."""
        if self.estimator is not None:
            return f"{self.kind}@{self.estimator.window_s:g}s"
        if self.tau_s is not None:
            return f"{self.kind}@{self.tau_s:g}s"
        if self.width_c is not None:
            return f"{self.kind}@{self.width_c:g}C" + self._play_lag_text("@lag", "s")
        return self.kind

    @property
    def short(self) -> str:
        """The `--inputs` spelling: temp, rate@50, lag@600."""
        if self.estimator is not None:
            return f"rate@{self.estimator.window_s:g}"
        if self.tau_s is not None:
            return f"lag@{self.tau_s:g}"
        if self.width_c is not None:
            return f"play@{self.width_c:g}" + self._play_lag_text(":")
        return "temp"

    def _play_lag_text(self, prefix: str, unit: str = "") -> str:
        if self.play_lag_auto:
            return f"{prefix}auto"
        return "" if self.play_lag_s is None else f"{prefix}{self.play_lag_s:g}{unit}"

    def to_dict(self) -> dict:
        extra = {} if self.dequantise_c is None else {"dequantise_c": float(self.dequantise_c)}
        if self.dequantise_pace is not None:
            extra["dequantise_pace"] = self.dequantise_pace
        if self.undither_c is not None:
            extra |= {"undither_c": float(self.undither_c), "undither_noise_c": float(self.undither_noise_c),
                      "undither_tau_s": float(self.undither_tau_s)}  # fmt: skip
        if self.estimator is not None:
            return {"kind": self.kind, **self.estimator.to_dict(), **extra}
        if self.tau_s is not None:
            return {"kind": self.kind, "tau_s": float(self.tau_s), **extra}
        if self.play_lag_auto:
            raise ValueError(f"{self.short}: the play's lag is chosen by fogd-train before a model file is written")
        if self.play_lag_s is not None:
            extra["lag_s"] = float(self.play_lag_s)
        if self.width_c is not None:
            return {"kind": self.kind, "width_c": float(self.width_c), **extra}
        return {"kind": self.kind, **extra}


def parse_inputs(text: str, average_s: float = 0.5, step_s: float = 0.0) -> tuple[InputSpec, ...]:
    """Inputs from the `--inputs` syntax (INPUTS_SYNTAX); raises ValueError naming the bad item.

    A lag bank (`lags@...`) is the same as its lags given one by one: each is an ordinary `temp_lag_c` input,
    so the model file and the streaming code need nothing new; a bank's later time constants are the bare
    numbers that follow it (`lags@300,1000,3000`)."""
    specs: list[InputSpec] = []
    in_bank = False
    for item in (part.strip() for part in text.split(",")):
        name, _, value = item.partition("@")
        bank_tau_s = _float_or_none(name) if in_bank and not value else None
        try:
            if bank_tau_s is not None:
                new = [InputSpec(TEMP_LAG, tau_s=bank_tau_s)]
            elif name == "lags" and value:
                new = [InputSpec(TEMP_LAG, tau_s=tau_s) for tau_s in _bank_taus(value)]
            else:
                new = [_single(name, value, average_s, step_s)]
        except ValueError as error:
            raise ValueError(f"--inputs item {item!r}: {error}") from None
        in_bank = name == "lags" or bank_tau_s is not None
        for spec in new:
            if spec in specs:
                raise ValueError(f"--inputs item {item!r} gives {spec.short} twice")
            specs.append(spec)
    if not 1 <= len(specs) <= MAX_INPUTS:
        raise ValueError(f"--inputs needs 1 to {MAX_INPUTS} inputs (a lag bank counts each of its lags)")
    return tuple(specs)


def _single(name: str, value: str, average_s: float, step_s: float) -> InputSpec:
    if name == "temp" and not value:
        return InputSpec(TEMP)
    if name == "rate" and value:
        spec = InputSpec(TEMP_RATE, EstimatorSettings(float(value), average_s, step_s))
        if not 2 * average_s <= spec.estimator.window_s <= 86400:
            raise ValueError(f"window must be from 2 * average_s ({2 * average_s:g} s) to 86400 s")
        return spec
    if name == "lag" and value:
        return InputSpec(TEMP_LAG, tau_s=float(value))
    if name == "play" and value:
        width, _, lag = value.partition(":")
        if lag == "auto":
            return InputSpec(TEMP_PLAY, width_c=float(width), play_lag_auto=True)
        return InputSpec(TEMP_PLAY, width_c=float(width), play_lag_s=float(lag) if lag else None)
    raise ValueError("expected temp, rate@SECONDS, lag@SECONDS, lags@SECONDS,SECONDS,... / lags@FIRST..LAST/COUNT, "
                     "play@WIDTH_C, play@WIDTH_C:TAU_S or play@WIDTH_C:auto")


def _bank_taus(value: str) -> list[float]:
    """`FIRST..LAST/COUNT` as COUNT log-spaced time constants (rounded to 3 significant digits), or one."""
    if ".." not in value:
        return [float(value)]
    bounds, _, count_text = value.partition("/")
    first_text, _, last_text = bounds.partition("..")
    first, last = float(first_text), float(last_text)
    count = int(count_text) if count_text else 0
    if not (0 < first < last) or count < 2:
        raise ValueError("a lag range is FIRST..LAST/COUNT with 0 < FIRST < LAST and COUNT >= 2, e.g. 30..3000/5")
    return [float(f"{tau_s:.3g}") for tau_s in np.geomspace(first, last, count)]


def _float_or_none(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None


def describe_inputs(specs: tuple[InputSpec, ...]) -> str:
    """The `--inputs` spelling of a whole input set (two or more lags in a row as one `lags@` bank), followed
    by the resolution it dequantises, or the resolution and noise it undithers, if any."""
    resolutions = sorted({spec.dequantise_c for spec in specs if spec.dequantise_c is not None})
    suffix = "".join(f" (dequantised {resolution_c:g} C)" for resolution_c in resolutions)
    undithers = sorted({spec.source[1:3] for spec in specs if spec.undither_c is not None})
    suffix += "".join(f" (undithered {resolution_c:g} C, noise {noise_c:.2g} C)" for resolution_c, noise_c in undithers)
    return _describe_plain(specs) + suffix


def dequantised(specs: tuple[InputSpec, ...], resolution_c: float | None,
                pace: str = DEFAULT_PACE) -> tuple[InputSpec, ...]:  # fmt: skip
    """The same inputs computed from the dequantised temperature of a sensor of `resolution_c` (None: from
    the readings), the estimate running at `pace` between crossings."""
    stored = None if resolution_c is None or pace == PACES[0] else pace
    return tuple(dataclasses.replace(spec, dequantise_c=resolution_c, dequantise_pace=stored) for spec in specs)


def undithered(specs: tuple[InputSpec, ...], resolution_c: float | None, noise_c: float | None = None,
               tau_s: float = DEFAULT_TAU_S) -> tuple[InputSpec, ...]:  # fmt: skip
    """The same inputs computed from the undithered estimate of a fine sensor of `resolution_c` with noise
    `noise_c` (None: from the readings)."""
    if resolution_c is None or noise_c is None:
        return tuple(dataclasses.replace(spec, undither_c=None, undither_noise_c=None, undither_tau_s=None)
                     for spec in specs)  # fmt: skip
    return tuple(dataclasses.replace(spec, undither_c=resolution_c, undither_noise_c=noise_c, undither_tau_s=tau_s)
                 for spec in specs)  # fmt: skip


def _describe_plain(specs: tuple[InputSpec, ...]) -> str:
    parts: list[str] = []
    index = 0
    while index < len(specs):
        end = index
        while end < len(specs) and specs[end].kind == TEMP_LAG:
            end += 1
        if end - index >= 2:
            parts.append("lags@" + ",".join(f"{spec.tau_s:g}" for spec in specs[index:end]))
            index = end
        else:
            parts.append(specs[index].short)
            index += 1
    return ",".join(parts)


def default_inputs(estimator: EstimatorSettings | None = None) -> tuple[InputSpec, ...]:
    """The paper's inputs: temperature and its eq. 16 rate."""
    return (InputSpec(TEMP), InputSpec(TEMP_RATE, estimator or EstimatorSettings()))


def temperature_columns(specs: tuple[InputSpec, ...]) -> tuple[int, ...]:
    """The inputs that are temperatures (the sensor's, or lagged), as opposed to temperature rates."""
    return tuple(i for i, spec in enumerate(specs) if spec.kind in (TEMP, TEMP_LAG))


def lag_taus_s(specs: tuple[InputSpec, ...]) -> tuple[float, ...]:
    """Each input's lag time constant in s, 0 for the inputs that are not lagged temperatures."""
    return tuple(float(spec.tau_s) if spec.kind == TEMP_LAG else 0.0 for spec in specs)


def with_play_lag_s(specs: tuple[InputSpec, ...], lag_s: float) -> tuple[InputSpec, ...]:
    """`specs` with each `play@WIDTH:auto` input's lag chosen as `lag_s` (0: the play of the temperature itself)."""
    return tuple(dataclasses.replace(spec, play_lag_s=lag_s or None, play_lag_auto=False) if spec.play_lag_auto else spec
                 for spec in specs)  # fmt: skip


def dequantises(specs: tuple[InputSpec, ...]) -> bool:
    """Whether some input is computed from a coarse sensor's dequantised estimate."""
    return any(spec.dequantise_c is not None for spec in specs)


def undithers(specs: tuple[InputSpec, ...]) -> bool:
    """Whether some input is computed from a fine sensor's undithered estimate."""
    return any(spec.undither_c is not None for spec in specs)


def dynamic_inputs(specs: tuple[InputSpec, ...]) -> bool:
    """Whether the inputs carry a thermal state (a lag bank, a play operator, a dequantised or undithered
    estimate) beyond the paper's temperature and eq. 16 rates."""
    return dequantises(specs) or undithers(specs) or any(spec.kind not in (TEMP, TEMP_RATE) for spec in specs)


def kernel_columns(specs: tuple[InputSpec, ...]) -> tuple[int, ...] | None:
    """The inputs an SVR kernel over a trend reads: with dynamic inputs, the sensor's temperature (else the
    fastest lag), where the static curve the trend leaves lives; None (every input) for the paper's inputs.

    Over a lag bank a kernel of every input is fitted to the calibration runs' few trajectories through nine
    dimensions, and a faster history reaches it off them: on tools/accuracy_table.py's held-out runs (--quick,
    seeds 1-5, both coils, fine sensor) it left the worst run at 1.21-2.55x the noise floor, a kernel of the
    temperature alone 1.11-1.66x (docs/how-it-works.md); the swarm's leave-one-run-out score could not tell
    them apart. Over the temperature the kernel still follows a static curve that the trend's cubic cannot."""
    if not dynamic_inputs(specs):
        return None
    temps = [i for i, spec in enumerate(specs) if spec.kind == TEMP]
    if temps:
        return tuple(temps)
    lags = [i for i, spec in enumerate(specs) if spec.kind == TEMP_LAG]
    return (min(lags, key=lambda i: specs[i].tau_s),) if lags else None


STATIC_MAX_TAU_S = 1000.0  # temperatures that follow the coil: the sensor's and lags up to this time constant
# fogd-train's default: the sensor's temperature and a bank of lags from half a minute to the housing's hour.
# A bank reaching 10,000 s was as good with three calibration runs and far worse with two: the slowest lags
# hardly move within a run and, with one offset per run, are nearly free (an exploratory least-squares check,
# not in tools/: held-out drift 1.6-3.9x the noise floor against 1.2-1.8x with paper-train and cooling as the
# only calibration runs). The sensor's own temperature carries what no lag has: the housing's latest move,
# which the coil's rate and gradient follow at once (tools/accuracy_table.py --quick, diffusive coil, fine
# sensor, fast-ramp: 3.10x the floor with the previous default, lags only under the poly trend; 1.37x now).
# A fine sensor's default is denser and down to 10 s, and has the play operator (fogd.core.play): the gyro's
# heating/cooling hysteresis is what no lag can hold, and without it the denser bank bent its fast lags to
# stand in for it (tools/trend_diagnostic.py --inputs temp,lags@10..3000/7 --case true/true --play '' --play 2:
# the coil trend alone on the true sensor temperature, seed 1, worst held-out run 1.38x lumped and 1.47x
# diffusive without it, 1.12x and 1.17x with play@2). tools/accuracy_table.py --quick --sensor fine --schemes default, worst run, seeds 1 / 2:
# lumped 1.52 / 1.92 before, 1.18 / 1.22 with it; diffusive 1.48 / 1.45 before, 1.37 / 1.39 with it.
# A coarse sensor (dequantised) has the same default: fitted from the offline estimate (fogd.core.dequantise.
# smoothed_batch), the denser bank halves the whole-degree runs' worst drift (tools/accuracy_table.py --quick
# --sensor whole --schemes default, seed 1, worst run: lumped 13.55 with temp,lags@30..3000/5 fitted causally,
# 9.92 with this bank fitted causally, 6.48 fitted from the offline estimate; diffusive 19.87, 14.32, 9.72).
DEFAULT_INPUTS_TEXT = "temp,lags@10..3000/7,play@2:auto"
# The ladder's "long lag bank" (fogd.calibration.ladder), offered with three calibration runs or more, where each
# is held out whole: the bank reaching 10,000 s, for a coil whose slowest path outlasts the housing's hour.
LONG_INPUTS_TEXT = "temp,lags@10..10000/8,play@2:auto"


def static_columns(specs: tuple[InputSpec, ...], max_tau_s: float = STATIC_MAX_TAU_S) -> tuple[int, ...]:
    """The temperature inputs close enough to the coil's temperature to carry its static nonlinearity: the
    sensor's own and lags up to `max_tau_s` (slower lags stand for the long memory of the housing); if there
    is none, the fastest lag."""
    columns = tuple(i for i, spec in enumerate(specs)
                    if spec.kind == TEMP or (spec.kind == TEMP_LAG and spec.tau_s <= max_tau_s))  # fmt: skip
    if columns:
        return columns
    lags = [i for i, spec in enumerate(specs) if spec.kind == TEMP_LAG]
    return (min(lags, key=lambda i: specs[i].tau_s),) if lags else ()


def shifted_columns(specs: tuple[InputSpec, ...]) -> tuple[int, ...]:
    """The temperature inputs that the calibrated-domain clamp moves together (the fastest first), for models
    with lagged temperatures; () for the others, whose inputs are clamped one by one.

    A lag bank's slow lags cover a narrower range in calibration than the sensor does (a 3-hour lag never
    reaches the end of a 45-minute soak), so clamping each lag to its own range would bend the differences
    between lags, which carry the coil's thermal state, wherever a slow lag steps outside. Moving them all by
    the fastest temperature's clamp keeps the state and stops only the static extrapolation."""
    if not any(spec.kind == TEMP_LAG for spec in specs):
        return ()
    columns = temperature_columns(specs)
    speed = lambda i: 0.0 if specs[i].kind == TEMP else specs[i].tau_s  # noqa: E731
    return tuple(sorted(columns, key=speed))


def clamp_rows(x: np.ndarray, low: np.ndarray, high: np.ndarray, shifted: tuple[int, ...]) -> np.ndarray:
    """Input rows clamped to the calibrated domain [low, high]: rates column by column, and the `shifted`
    temperature columns moved together by the first one's clamp (`shifted_columns`)."""
    out = np.clip(x, low, high)
    if shifted:
        first = shifted[0]
        shift = out[:, first] - x[:, first]
        out[:, shifted] = x[:, shifted] + shift[:, None]
    return out


def warmup_samples(specs: tuple[InputSpec, ...], rate_hz: float) -> int:
    """Samples before every input is real (the longest estimator window; a lag starts in steady state at the
    first temperature and has no warm-up)."""
    windows = [spec.estimator.samples(rate_hz)[0] for spec in specs if spec.estimator is not None]
    return max(windows, default=1) - 1


def inputs_batch(temp_c: np.ndarray, specs: tuple[InputSpec, ...], rate_hz: float, smoothed: bool = False) -> np.ndarray:
    """All inputs for a whole run of finite temperatures: an (n, len(specs)) array. `smoothed` (fitting only)
    computes the dequantised inputs from the offline estimate (fogd.core.dequantise.smoothed_batch)."""
    temp_c = np.asarray(temp_c, dtype=np.float64)
    sources = {key: source_batch(temp_c, key, rate_hz, smoothed) for key in _sources(specs)}
    columns = [_column_batch(sources[spec.source], spec, rate_hz) for spec in specs]
    return np.column_stack(columns) if columns else np.empty((temp_c.size, 0))


def _column_batch(temp_c: np.ndarray, spec: InputSpec, rate_hz: float) -> np.ndarray:
    if spec.estimator is not None:
        return temp_rate_batch(temp_c, spec.estimator, rate_hz)
    if spec.tau_s is not None:
        return LagFilter(spec.tau_s, rate_hz).update(temp_c)
    if spec.width_c is not None:
        return _play(spec, rate_hz).update(temp_c)
    return temp_c


def source_batch(temp_c: np.ndarray, key: Source, rate_hz: float, smoothed: bool = False) -> np.ndarray:
    """The temperature `key` (an input's `source`) over a whole run of readings; `smoothed` (fitting only) takes
    a dequantiser's offline estimate (fogd.core.dequantise.smoothed_batch)."""
    if key is None:
        return temp_c
    if key[0] == DEQUANTISE:
        return (smoothed_batch if smoothed else dequantise_batch)(temp_c, key[1], rate_hz, key[2])
    return undither_batch(temp_c, key[1], key[2], key[3], rate_hz)


def source_filter(key: Source, rate_hz: float) -> Dequantiser | Undither | None:
    """The streaming estimate `key` names (None: the readings themselves)."""
    if key is None:
        return None
    if key[0] == DEQUANTISE:
        return Dequantiser(key[1], rate_hz, key[2])
    return Undither(key[1], key[2], key[3], rate_hz)


def _sources(specs: tuple[InputSpec, ...]) -> list[Source]:
    """The temperature sources the inputs need, each once: None (the readings) and each estimate's key."""
    return list(dict.fromkeys(spec.source for spec in specs))


def _play(spec: InputSpec, rate_hz: float) -> PlayFilter | LaggedPlay:
    if spec.play_lag_auto:
        raise ValueError(f"{spec.short}: the play's lag must be chosen (fogd.calibration.training.with_play_lag) first")
    return PlayFilter(spec.width_c) if spec.play_lag_s is None else LaggedPlay(spec.width_c, spec.play_lag_s, rate_hz)


def _streaming(spec: InputSpec, rate_hz: float) -> TempRateEstimator | LagFilter | PlayFilter | LaggedPlay | None:
    if spec.estimator is not None:
        return TempRateEstimator(spec.estimator, rate_hz)
    if spec.tau_s is not None:
        return LagFilter(spec.tau_s, rate_hz)
    if spec.width_c is not None:
        return _play(spec, rate_hz)
    return None


class InputBank:
    """All inputs, streaming: feed finite temperatures in chunks, get the (k, d) input rows back."""

    def __init__(self, specs: tuple[InputSpec, ...], rate_hz: float) -> None:
        self.specs = specs
        self.rate_hz = float(rate_hz)
        self._estimators = [_streaming(spec, rate_hz) for spec in specs]
        self._sources = [spec.source for spec in specs]
        keys = _sources(specs)
        self._filters = {key: source_filter(key, rate_hz) for key in keys if key is not None}
        self.warmup = warmup_samples(specs, rate_hz)
        self.count = 0
        # update_one's row, when every input has the same source (fogd-train's models): that source's estimate
        # once, the lags (a run of columns: fogd-train's default bank) in one update_lags_one call, the inputs
        # before and after them one call each
        self._shared = self._filters.get(keys[0]) if len(keys) == 1 else None
        lags = [column for column, estimator in enumerate(self._estimators) if isinstance(estimator, LagFilter)]
        run = len(keys) == 1 and len(lags) > 1 and lags == list(range(lags[0], lags[-1] + 1))
        self._lag_run = (self._estimators[: lags[0]], self._estimators[lags[0] : lags[-1] + 1],
                         self._estimators[lags[-1] + 1 :]) if run else None  # fmt: skip

    @property
    def warm(self) -> bool:
        return self.count > self.warmup

    @property
    def parts(self) -> list[TempRateEstimator | LagFilter | PlayFilter | LaggedPlay | None]:
        """Each input's streaming state (None: the temperature itself), for fogd.core.history to prime."""
        return self._estimators

    @property
    def sources(self) -> dict[tuple, Dequantiser | Undither]:
        """Each estimate the inputs are computed from (a dequantiser, an undither), by its key."""
        return self._filters

    def reset(self) -> None:
        for estimator in self._estimators:
            if estimator is not None:
                estimator.reset()
        for source in self._filters.values():
            source.reset()
        self.count = 0

    def update(self, temp_c: np.ndarray) -> np.ndarray:
        temp_c = np.atleast_1d(np.asarray(temp_c, dtype=np.float64))
        out = np.empty((temp_c.size, len(self.specs)))
        sources = {None: temp_c} | {key: source.update(temp_c) for key, source in self._filters.items()}
        for column, (key, estimator) in enumerate(zip(self._sources, self._estimators)):
            source = sources[key]
            out[:, column] = source if estimator is None else estimator.update(source)
        self.count += temp_c.size
        return out

    def update_one(self, temp_c: float) -> tuple[float, ...]:
        """Feed one finite temperature; its input row as Python floats, the same floats `update` gives."""
        self.count += 1
        if self._lag_run is not None:
            if self._shared is not None:
                temp_c = self._shared.update_one(temp_c)
            before, lags, after = self._lag_run
            row = []
            for estimator in before:
                row.append(temp_c if estimator is None else estimator.update_one(temp_c))
            row += update_lags_one(lags, temp_c)
            for estimator in after:
                row.append(temp_c if estimator is None else estimator.update_one(temp_c))
            return tuple(row)
        if not self._filters:
            return tuple([temp_c if estimator is None else estimator.update_one(temp_c) for estimator in self._estimators])
        sources = {None: temp_c} | {key: source.update_one(temp_c) for key, source in self._filters.items()}
        return tuple([sources[key] if estimator is None else estimator.update_one(sources[key])
                      for key, estimator in zip(self._sources, self._estimators)])  # fmt: skip
