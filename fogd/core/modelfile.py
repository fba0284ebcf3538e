"""The model file: plain JSON written by training, validated field by field before anything is evaluated.

A model file is data from outside. Loading reads at most `MAX_MODEL_BYTES`, refuses pickles and other binary
files by their first bytes, parses strict JSON (no NaN; deep nesting refused), accepts exactly the keys below and
checks every array's shape and finiteness; anything else is a `ModelFileError` with a one-line message.

Version 2 adds an optional `trend_powers` to pso-svr's params (the monomials of a polynomial trend under the
SVR; without it the trend is linear, as in version 1). pso-svr's params may also carry `kernel_columns` (the
inputs the kernel reads, in increasing order; its support vectors have those columns only; without it, every
input): a fogd from before the key refuses such a file by name rather than evaluate the kernel on the wrong
inputs. They may carry `trend_mix` too (one weight per input: the trend's monomials then read one more input
after the model's own, the coil temperature q = trend_mix . x, so the default trend is stored as the eleven
terms it is fitted as rather than their 165-monomial expansion); an older fogd refuses it by name. Version-1
files still load. Version 1 had grown
compatibly (files written before still load; older fogd refuses the new parts by name):
inputs may be `temp_lag_c` (with `tau_s`) and several `temp_rate_cps` windows, and an optional top-level
`domain_guard` holds the joint-space guard of fogd.core.domain: `points` (calibration block rows in scaled units),
`threshold` (scaled distance) and `fallback` (`{"method": "linear", "params": {"coef", "intercept"}}`, in the
model's own input and output scaling). A guard may carry `kind` ("joint", as without it, or "range": `threshold` is
then a margin beyond the points' range per input, the temperatures sharing one; fogd.core.domain); a fogd from
before the key refuses it by name rather than guard the wrong domain.

Version 3 is a multi-channel file (an IMU's gyros and accelerometers, fogd.core.columns.CHANNELS): `channels`
maps each channel it covers to that channel's model, a whole version-2 (or 4) document, validated as one; beside it
only `format`, `version`, `name`, `created_utc` and `fogd_version`. Only multi-channel files are version 3: a
single-axis model is still written as version 2, byte for byte as before, so an older fogd keeps loading what
a single-axis training writes, and refuses a multi-channel file by its version rather than misreading it.
`load` reads single-channel files (versions 1, 2, 4 and 5) as it always has and refuses a version-3 file in one line;
`load_channels` reads any of them as a `ChannelModels` (channel name -> FrozenModel; a version-1, -2, -4 or -5
file is the one channel `rate_dph`).

Version 4 is a single-channel model (alone, or as a channel's model in a version-3 file) whose inputs may
carry `dequantise_c`: computed from fogd.core.dequantise's estimate of a coarse sensor's temperature. Only a
model with such an input is written as version 4, so an older fogd refuses it by its version. Such an input
may also carry `dequantise_pace` ("quadratic", fogd.core.dequantise.PACES); without it the estimate runs at
the linear pace, as every version-4 file written before the key existed was trained with. A fogd from before
the key refuses a file with it (an unknown key of an input) rather than serving the wrong estimate.

Version 5 is a single-channel model (alone or as a channel's model) with a `temp_play` input (fogd.core.play,
with `width_c`: the temperature's play operator, for a gyro's heating/cooling hysteresis); its inputs may be
dequantised as in version 4. Only a model with such an input is written as version 5. Its optional `lag_s`
makes it the play of a first-order lag of the temperature (fogd.core.play.LaggedPlay); a fogd from before the key
refuses a file with it, as for `dequantise_pace`.

A version-4 or -5 model's inputs may instead carry `undither_c`, `undither_noise_c` and `undither_tau_s`
(all three): computed from fogd.core.undither's estimate of a fine sensor's temperature (its resolution, the
noise it assumes and the lag that averages the readings). A model with such an input is written as version 4
(5 with a play input); a fogd from before the keys refuses it by the unknown key, never serving the readings
in its place.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from fogd import __version__
from fogd.core.atomic import read_regular, replaced
from fogd.core.channels import ChannelModels
from fogd.core.columns import CHANNELS, SINGLE_CHANNEL
from fogd.core.dequantise import PACES
from fogd.core.domain import GUARD_KINDS, DomainGuard
from fogd.core.estimator import EstimatorSettings
from fogd.core.frozen import FrozenModel, build_evaluator
from fogd.core.outside_range import LINEAR_POLICIES, OutsideRange
from fogd.core.outside_range import POLICIES as OUTSIDE_POLICIES
from fogd.core.inputs import (
    KINDS,
    MAX_RESOLUTION_C,
    TEMP,
    TEMP_LAG,
    TEMP_PLAY,
    TEMP_RATE,
    InputSpec,
    dequantises,
    temperature_columns,
    undithers,
)
from fogd.core.lag import MAX_TAU_S
from fogd.core.play import MAX_WIDTH_C
from fogd.errors import ModelFileError, NoModelFileError, describe_os_error

MODEL_FORMAT = "fogd-model"
UNDITHER_KEYS = {"undither_c", "undither_noise_c", "undither_tau_s"}  # an undithered input's (fogd.core.undither)
MODEL_VERSION = 2  # a single-channel file whose inputs are all computed from the readings
DEQUANTISED_VERSION = 4  # a single-channel file (or a channel's model) with a dequantised input
PLAY_VERSION = 5  # a single-channel file (or a channel's model) with a play input, dequantised or not
READABLE_VERSIONS = (1, 2, DEQUANTISED_VERSION, PLAY_VERSION)  # of a single-channel file (and of each channel's model)
CHANNELS_VERSION = 3  # a multi-channel file
CHANNELS_TOP_KEYS = {"format", "version", "name", "channels", "created_utc", "fogd_version"}
MAX_MODEL_BYTES = 32 * 1024 * 1024
MAX_ROWS = 100_000  # support vectors, centres or polynomial terms
MIN_SCALE = 1e-9  # input scales, RBF widths and SVR gammas: beyond 1e-9..1e9 the arithmetic under/overflows
_FLOAT_MAX = sys.float_info.max
METHODS = ("linear", "ls-poly", "rbf-nn", "pso-svr")
TOP_KEYS = {
    "format", "version", "name", "method", "inputs", "input_scaling", "output_scaling", "domain", "params",
    "reference_dph", "training", "metrics", "created_utc", "fogd_version",
}  # fmt: skip
OPTIONAL_TOP_KEYS = {"domain_guard", "outside_range"}
# outside_range (optional; without it "clamp"): fogd.core.outside_range's policy, and for "trend" and "linear" the
# linear fit's coef and intercept in the model's own scaling
OUTSIDE_KEYS = {"policy"}
OPTIONAL_OUTSIDE_KEYS = {"coef", "intercept"}
# metrics.held_out (optional, from fogd-train's ladder): the chosen model's held-out drift RMSE and its standard
# error over the folds (in the channel's unit: deg/h, or g for an accelerometer), how the folds were cut, the rung
HELD_OUT_KEYS = {"drift_rmse_dph", "spread_dph", "folds"}
OPTIONAL_HELD_OUT_KEYS = {"rung"}
GUARD_KEYS = {"points", "threshold", "fallback"}
OPTIONAL_GUARD_KEYS = {"kind"}  # fogd.core.domain.GUARD_KINDS; without it, "joint"
PARAM_KEYS = {
    "linear": {"coef", "intercept"},
    "ls-poly": {"powers", "coef", "intercept"},
    "rbf-nn": {"centres", "width", "coef", "intercept"},
    "pso-svr": {"support_vectors", "dual_coef", "gamma", "trend_coef", "intercept"},
}
# version 2: a polynomial trend under the SVR (trend_mix: its coil temperature), the kernel's inputs
OPTIONAL_PARAM_KEYS = {"pso-svr": {"trend_powers", "kernel_columns", "trend_mix"}}
_BINARY_MAGIC = {
    b"\x80": "a Python pickle",
    b"PK": "a zip archive (numpy .npz or joblib?)",
    b"\x93NUMPY": "a numpy .npy array",
    b"\x1f\x8b": "a gzip file",
}


def save(path: str | Path, document: dict[str, Any], *, inputs: list[str] = ()) -> None:
    """Write a model document (as built by `document()` or `channels_document()`), checking it loads back
    first. The file is replaced whole (fogd.core.atomic): on a full disk the old model stays as it was; an
    output that is an input is refused."""
    if _is_multi_channel(document):
        from_channels_document(document, source=str(path))
    else:
        from_document(document, source=str(path))
    text = json.dumps(document, indent=1, allow_nan=False)
    with replaced(str(path), inputs=inputs) as stream:  # OutputError (74) naming the path when it cannot be written
        stream.write(text + "\n")


def document(
    *,
    name: str,
    method: str,
    inputs: tuple[InputSpec, ...],
    x_mean: np.ndarray,
    x_scale: np.ndarray,
    y_mean: float,
    y_scale: float,
    domain_min: np.ndarray,
    domain_max: np.ndarray,
    params: dict[str, Any],
    reference_dph: float,
    training: dict[str, Any],
    metrics: dict[str, Any],
    created_utc: str,
    domain_guard: dict[str, Any] | None = None,
    outside_range: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """A model document in the file's layout, ready for `save`."""
    optional = {} if domain_guard is None else {"domain_guard": domain_guard}
    if outside_range is not None:
        optional["outside_range"] = outside_range
    return {
        "format": MODEL_FORMAT,
        "version": _version(inputs),
        "name": name,
        "method": method,
        "inputs": [spec.to_dict() for spec in inputs],
        "input_scaling": {"mean": _floats(x_mean), "scale": _floats(x_scale)},
        "output_scaling": {"mean": float(y_mean), "scale": float(y_scale)},
        "domain": {"min": _floats(domain_min), "max": _floats(domain_max)},
        "params": params,
        "reference_dph": float(reference_dph),
        "training": training,
        "metrics": metrics,
        "created_utc": created_utc,
        "fogd_version": __version__,
        **optional,
    }


def channels_document(*, name: str, documents: dict[str, dict[str, Any]], created_utc: str) -> dict[str, Any]:
    """A multi-channel (version 3) document, ready for `save`: `documents` maps each channel (one of
    fogd.core.columns.CHANNELS) to its model document as built by `document()`."""
    return {
        "format": MODEL_FORMAT,
        "version": CHANNELS_VERSION,
        "name": name,
        "channels": dict(documents),
        "created_utc": created_utc,
        "fogd_version": __version__,
    }


def load(path: str | Path) -> FrozenModel:
    """Read and validate a single-channel model file (version 1, 2, 4 or 5); raises ModelFileError with one line
    saying what is wrong, or that the file is a multi-channel one (`load_channels` reads those)."""
    source = str(path)
    return from_document(_parse(path), source=source)


def load_channels(path: str | Path) -> ChannelModels:
    """Read and validate any model file as its models by channel: a multi-channel file's channels, or a
    single-channel file's model as the one channel `rate_dph`; raises ModelFileError with one line."""
    parsed = _parse(path)
    if _is_multi_channel(parsed):
        return from_channels_document(parsed, source=str(path))
    model = from_document(parsed, source=str(path))
    return ChannelModels({SINGLE_CHANNEL: model}, name=model.name, version=parsed["version"])


def held_out(models: ChannelModels | FrozenModel) -> dict[str, dict[str, Any]]:
    """Each channel's stored held-out estimate (metrics.held_out, validated when the file was loaded), for the
    status file and fogd-top: {channel: {drift_rmse, spread, folds}}; channels trained without one are left
    out (files from before the ladder, or a --method given by name)."""
    if isinstance(models, FrozenModel):
        models = ChannelModels({SINGLE_CHANNEL: models}, name=models.name, version=MODEL_VERSION)
    figures = {}
    for channel, model in models.items():
        stored = (model.meta.get("metrics") or {}).get("held_out")
        if isinstance(stored, dict):
            figures[channel] = {"drift_rmse": stored["drift_rmse_dph"], "spread": stored["spread_dph"],
                                "folds": stored["folds"]}  # fmt: skip
    return figures


def _is_multi_channel(doc: Any) -> bool:
    return isinstance(doc, dict) and type(doc.get("version")) is int and doc["version"] == CHANNELS_VERSION


def _parse(path: str | Path) -> Any:
    """The file's JSON, read safely (size, binary formats, encoding, nesting, duplicate keys)."""
    source = str(path)
    try:
        data = read_regular(path, MAX_MODEL_BYTES)  # never blocks: a FIFO here would hang start-up or a reload
    except OSError as error:
        raise NoModelFileError(f"cannot read model: {describe_os_error(error)}") from None
    if len(data) > MAX_MODEL_BYTES:
        raise ModelFileError(f"{source}: larger than {MAX_MODEL_BYTES // 2**20} MiB; not a fogd model file")
    if not data.strip():
        raise ModelFileError(f"{source}: empty file; not a fogd model file")
    for magic, what in _BINARY_MAGIC.items():
        if data.startswith(magic):
            raise ModelFileError(f"{source}: this is {what}, not a fogd JSON model; fogd never loads pickles")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise ModelFileError(f"{source}: not UTF-8 text; a fogd model file is JSON") from None
    try:
        parsed = json.loads(text, parse_constant=_reject_constant, object_pairs_hook=_unique_keys)
    except RecursionError:
        raise ModelFileError(f"{source}: JSON nested too deeply; not a fogd model file") from None
    except ValueError as error:
        raise ModelFileError(f"{source}: not valid JSON ({error})") from None
    return parsed


def _reject_constant(name: str) -> None:
    raise ValueError(f"{name} is not allowed")


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """A JSON object, refusing a key given twice (json would silently keep the last)."""
    document = dict(pairs)
    if len(document) != len(pairs):
        seen: set[str] = set()
        twice = next(key for key, _ in pairs if key in seen or seen.add(key))
        raise ValueError(f"key {printable(twice)[:40]!r} appears twice in one object")
    return document


def printable(text: str) -> str:
    """`text` with control characters escaped, safe for a log line or a systemd field."""
    return text if text.isprintable() else text.encode("unicode_escape").decode("ascii")


def _control_characters(value: Any, where: str, check: "_Checker") -> None:
    """Refuse a control character (newline, ESC, ...) in any string of the document: names and notes end up
    in log lines and systemd's STATUS= field, where a newline forges a line or a field."""
    if isinstance(value, str):
        if any(ord(char) < 0x20 or 0x7F <= ord(char) < 0xA0 for char in value):
            check.fail(where, f"holds a control character ({printable(value)[:40]!r}); names and notes must be printable")
    elif isinstance(value, dict):
        for key, item in value.items():
            child = f"{where}.{printable(key)[:40]}" if where else printable(key)[:40]
            _control_characters(key, child, check)
            _control_characters(item, child, check)
    elif isinstance(value, list):
        for i, item in enumerate(value):
            _control_characters(item, f"{where}[{i}]", check)


MAX_COMP_DPH = 1e6  # a thermal error beyond this (277 deg/s) is no FOG's: a corrupt or hostile model
MAX_ESTIMATOR_BYTES = 256 * 2**20  # the temperature-rate estimators' buffers at the daemon's rate
_CHECK_CORNERS = 256
_CHECK_RANDOM = 64


class ModelOutputError(ModelFileError):
    """A model whose compensation is not finite or beyond MAX_COMP_DPH somewhere in its own domain."""

    def __init__(self, message: str, value_dph: float) -> None:
        super().__init__(message)
        self.value_dph = value_dph


def check_output(model: FrozenModel, source: str = "model") -> None:
    """The model's compensation must be finite and below MAX_COMP_DPH over its whole (clamped) domain: checked
    at the domain's corners, centre and seeded random points, for the model, its guard's fallback and its
    outside-range policy's linear fit."""
    d = len(model.inputs)
    low, high = model.domain_min, model.domain_max
    rng = np.random.default_rng(0)
    if 2**d <= _CHECK_CORNERS:
        corners = (np.arange(2**d)[:, None] >> np.arange(d)[None, :]) & 1
    else:
        corners = rng.integers(0, 2, size=(_CHECK_CORNERS, d))
    unit = np.vstack([corners, np.full((1, d), 0.5), rng.random((_CHECK_RANDOM, d))])
    points = low + unit * (high - low)
    models = [model]
    guard = model.meta.get("domain_guard")
    if guard is not None:
        models.append(guard.fallback)
    if model.outside is not None and model.outside.coef is not None:  # the outside-range policy's linear fit
        params = {"coef": model.outside.coef, "intercept": model.outside.intercept}
        models.append(FrozenModel("linear", model.inputs, model.x_mean, model.x_scale, model.y_mean, model.y_scale,
                                  low, high, build_evaluator("linear", params),
                                  name=f"{model.name} (outside-range linear fit)"))  # fmt: skip
    for each in models:
        with np.errstate(all="ignore"):
            try:
                y, _ = each.predict(points)
            except (ArithmeticError, ValueError) as error:
                raise ModelFileError(f"{source}: {each.name or 'the model'} cannot be evaluated on its domain ({error})") from None
        bad = ~(np.abs(y) <= MAX_COMP_DPH)
        if bad.any():
            raise ModelOutputError(
                f"{source}: {printable(each.name or 'the model')[:60]} gives {float(y[bad][0])!r} deg/h inside its own domain "
                f"(the limit is {MAX_COMP_DPH:g}); a corrupt or hostile model",
                float(y[bad][0]),
            )


def check_rate(model: FrozenModel, rate_hz: float, source: str = "model") -> None:
    """The model at the daemon's sample rate: its estimator windows must be whole and fit MAX_ESTIMATOR_BYTES."""
    total = 0
    for spec in model.inputs:
        if spec.kind != TEMP_RATE:
            continue
        try:
            window, _, step = spec.estimator.samples(rate_hz)
        except ValueError as error:
            raise ModelFileError(f"{source}: {error}") from None
        total += 8 * (window + step + 1)
    if total > MAX_ESTIMATOR_BYTES:
        raise ModelFileError(
            f"{source}: its temperature-rate windows need {total / 2**20:.0f} MiB at {rate_hz:g} Hz (the limit is "
            f"{MAX_ESTIMATOR_BYTES // 2**20} MiB); shorten the windows or lower rate_hz"
        )


def _version(inputs: tuple[InputSpec, ...]) -> int:
    """The oldest single-channel version that holds these inputs, so an older fogd refuses what it cannot serve."""
    if any(spec.kind == TEMP_PLAY for spec in inputs):
        return PLAY_VERSION
    return DEQUANTISED_VERSION if dequantises(inputs) or undithers(inputs) else MODEL_VERSION


def from_channels_document(doc: Any, *, source: str = "model") -> ChannelModels:
    """Validate a parsed multi-channel (version 3) document and build each channel's frozen model."""
    check = _Checker(source)
    check.mapping(doc, "", CHANNELS_TOP_KEYS)
    _control_characters(doc, "", check)
    if doc["format"] != MODEL_FORMAT:
        check.fail("format", f"is {str(doc['format'])[:40]!r}, expected {MODEL_FORMAT!r}")
    if check.integer(doc["version"], "version") != CHANNELS_VERSION:
        check.fail("version", f"is {doc['version']}; a multi-channel file is version {CHANNELS_VERSION}")
    name = check.string(doc["name"], "name")
    check.string(doc["created_utc"], "created_utc")
    check.string(doc["fogd_version"], "fogd_version")
    check.mapping(doc["channels"], "channels", None)
    if not doc["channels"]:
        check.fail("channels", "is empty; a multi-channel file holds at least one channel's model")
    models = {}
    for channel, entry in doc["channels"].items():
        if channel not in CHANNELS:
            check.fail("channels", f"has unknown channel {channel[:40]!r}; channels are {', '.join(CHANNELS)}")
        if _is_multi_channel(entry) and "channels" in entry:
            check.fail(f"channels.{channel}", "is itself a multi-channel document")
        models[channel] = from_document(entry, source=f"{source}: channel {channel}")
    return ChannelModels(models, name=name, version=CHANNELS_VERSION)


def from_document(doc: Any, *, source: str = "model") -> FrozenModel:
    """Validate a parsed single-channel model document and build the frozen model it describes."""
    check = _Checker(source)
    if _is_multi_channel(doc) and isinstance(doc.get("channels"), dict):
        channels = ", ".join(printable(str(name))[:40] for name in list(doc["channels"])[:len(CHANNELS)])
        check.fail("version", f"is {CHANNELS_VERSION}: a model per channel ({channels}); this reads a single-channel "
                              "model file (version 1, 2, 4 or 5)")
    check.mapping(doc, "", TOP_KEYS, optional=OPTIONAL_TOP_KEYS)
    _control_characters(doc, "", check)
    if doc["format"] != MODEL_FORMAT:
        check.fail("format", f"is {str(doc['format'])[:40]!r}, expected {MODEL_FORMAT!r}")
    version = check.integer(doc["version"], "version")
    if version not in READABLE_VERSIONS:
        check.fail("version", f"is {version}; this fogd reads versions {', '.join(map(str, READABLE_VERSIONS))} (re-train, or upgrade fogd)")
    name = check.string(doc["name"], "name")
    method = check.string(doc["method"], "method")
    if method not in METHODS:
        check.fail("method", f"is {method[:40]!r}; known methods: {', '.join(METHODS)}")
    inputs = check.inputs(doc["inputs"], dequantised=version in (DEQUANTISED_VERSION, PLAY_VERSION),
                          play=version == PLAY_VERSION)
    d = len(inputs)
    check.mapping(doc["input_scaling"], "input_scaling", {"mean", "scale"})
    x_mean = check.vector(doc["input_scaling"]["mean"], "input_scaling.mean", d)
    x_scale = check.vector(doc["input_scaling"]["scale"], "input_scaling.scale", d, positive=True)
    if np.any(x_scale < MIN_SCALE):
        check.fail("input_scaling.scale", f"has an entry below {MIN_SCALE:g}")
    check.mapping(doc["output_scaling"], "output_scaling", {"mean", "scale"})
    y_mean = check.number(doc["output_scaling"]["mean"], "output_scaling.mean")
    y_scale = check.number(doc["output_scaling"]["scale"], "output_scaling.scale", positive=True)
    check.mapping(doc["domain"], "domain", {"min", "max"})
    domain_min = check.vector(doc["domain"]["min"], "domain.min", d)
    domain_max = check.vector(doc["domain"]["max"], "domain.max", d)
    if np.any(domain_min > domain_max):
        check.fail("domain", "has min above max")
    params = check.params(doc["params"], method, d)
    check.number(doc["reference_dph"], "reference_dph")
    for key in ("training", "metrics"):
        check.mapping(doc[key], key, None)
    if "held_out" in doc["metrics"]:
        check.held_out(doc["metrics"]["held_out"])
    created = check.string(doc["created_utc"], "created_utc")
    check.string(doc["fogd_version"], "fogd_version")
    meta = {
        "reference_dph": doc["reference_dph"],
        "training": doc["training"],
        "metrics": doc["metrics"],
        "created_utc": created,
    }
    if "domain_guard" in doc:
        meta["domain_guard"] = check.guard(
            doc["domain_guard"], inputs, x_mean, x_scale, y_mean, y_scale, domain_min, domain_max, name
        )
    model = FrozenModel(
        method=method,
        inputs=inputs,
        x_mean=x_mean,
        x_scale=x_scale,
        y_mean=y_mean,
        y_scale=y_scale,
        domain_min=domain_min,
        domain_max=domain_max,
        evaluator=build_evaluator(method, params),
        name=name,
        meta=meta,
        outside=check.outside(doc["outside_range"], d) if "outside_range" in doc else None,
    )
    check_output(model, source)
    return model


class _Checker:
    """Field checks that raise ModelFileError naming the file and the field."""

    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, where: str, what: str) -> None:
        raise ModelFileError(f"{self.source}: field {where or 'top level'} {what}")

    def mapping(self, value: Any, where: str, keys: set[str] | None, *, optional: set[str] = frozenset()) -> None:
        if not isinstance(value, dict):
            self.fail(where, f"must be an object, found {type(value).__name__}")
        if keys is None:
            return
        missing, unknown = keys - value.keys(), value.keys() - keys - optional
        if missing:
            self.fail(where, f"lacks {', '.join(sorted(missing))}")
        if unknown:
            self.fail(where, f"has unknown key(s) {', '.join(sorted(map(repr, unknown)))}")

    def held_out(self, value: Any) -> None:
        where = "metrics.held_out"
        self.mapping(value, where, HELD_OUT_KEYS, optional=OPTIONAL_HELD_OUT_KEYS)
        for key in ("drift_rmse_dph", "spread_dph"):
            if self.number(value[key], f"{where}.{key}") < 0:
                self.fail(f"{where}.{key}", f"must not be negative, found {value[key]!r}")
        for key in ("folds", "rung"):
            if key in value:
                self.string(value[key], f"{where}.{key}")

    def string(self, value: Any, where: str) -> str:
        if not isinstance(value, str) or len(value) > 256:
            self.fail(where, "must be a string of at most 256 characters")
        return value

    def integer(self, value: Any, where: str) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(where, f"must be an integer, found {value!r:.40}")
        return value

    def number(self, value: Any, where: str, *, positive: bool = False) -> float:
        # a range test, not math.isfinite: a JSON integer of 400 digits overflows float() but compares fine
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not -_FLOAT_MAX <= value <= _FLOAT_MAX:
            self.fail(where, f"must be a finite number, found {value!r:.40}")
        if positive and not value > 0:
            self.fail(where, f"must be positive, found {value!r}")
        return float(value)

    def vector(self, value: Any, where: str, length: int | None, *, positive: bool = False) -> np.ndarray:
        if not isinstance(value, list) or (length is not None and len(value) != length):
            self.fail(where, f"must be a list of {length if length is not None else 'some'} numbers")
        if len(value) > MAX_ROWS:
            self.fail(where, f"has more than {MAX_ROWS} entries")
        return np.array([self.number(item, f"{where}[{i}]", positive=positive) for i, item in enumerate(value)])

    def matrix(self, value: Any, where: str, columns: int, *, allow_empty: bool = False) -> np.ndarray:
        if not isinstance(value, list) or not (value or allow_empty):
            self.fail(where, "must be a non-empty list of rows")
        if len(value) > MAX_ROWS:
            self.fail(where, f"has more than {MAX_ROWS} rows")
        rows = [self.vector(row, f"{where}[{i}]", columns) for i, row in enumerate(value)]
        return np.array(rows).reshape(len(rows), columns)

    def inputs(self, value: Any, *, dequantised: bool = False, play: bool = False) -> tuple[InputSpec, ...]:
        if not isinstance(value, list) or not 1 <= len(value) <= 16:
            self.fail("inputs", "must be a list of 1 to 16 inputs")
        specs = []
        for i, item in enumerate(value):
            where = f"inputs[{i}]"
            kinds = KINDS if play else tuple(kind for kind in KINDS if kind != TEMP_PLAY)
            if not isinstance(item, dict) or item.get("kind") not in kinds:
                self.fail(where, f"must be an object whose kind is one of {', '.join(kinds)}")
            resolution_c = pace = None
            if dequantised and "dequantise_c" in item:
                item = dict(item)
                resolution_c = self.number(item.pop("dequantise_c"), f"{where}.dequantise_c", positive=True)
                if resolution_c > MAX_RESOLUTION_C:
                    self.fail(f"{where}.dequantise_c", f"is above {MAX_RESOLUTION_C:g} C")
                if "dequantise_pace" in item:  # absent: "linear", as every file before it was written
                    pace = item.pop("dequantise_pace")
                    if pace not in PACES[1:]:
                        self.fail(f"{where}.dequantise_pace", f"must be one of {', '.join(PACES[1:])}")
            source = {"dequantise_c": resolution_c, "dequantise_pace": pace}
            if dequantised and UNDITHER_KEYS & item.keys():
                item, source = self.undither(item, where, source)
            if item["kind"] == TEMP_RATE:
                self.mapping(item, where, {"kind", "window_s", "average_s", "step_s"})
                settings = EstimatorSettings(
                    *(self.number(item[key], f"{where}.{key}") for key in ("window_s", "average_s", "step_s"))
                )
                if not (0 < settings.average_s and 2 * settings.average_s <= settings.window_s <= 86400):
                    self.fail(where, "needs 0 < 2 * average_s <= window_s <= 86400")
                if not 0 <= settings.step_s <= settings.window_s:
                    self.fail(where, "needs 0 <= step_s <= window_s")
                specs.append(InputSpec(TEMP_RATE, settings, **source))
            elif item["kind"] == TEMP_LAG:
                self.mapping(item, where, {"kind", "tau_s"})
                tau_s = self.number(item["tau_s"], f"{where}.tau_s")
                if not 0 < tau_s <= MAX_TAU_S:
                    self.fail(where, f"needs 0 < tau_s <= {MAX_TAU_S:g}")
                specs.append(InputSpec(TEMP_LAG, tau_s=tau_s, **source))
            elif item["kind"] == TEMP_PLAY:
                # lag_s (the play of a lag of the temperature) is optional: a fogd before it refuses the key
                self.mapping(item, where, {"kind", "width_c"}, optional={"lag_s"})
                width_c = self.number(item["width_c"], f"{where}.width_c")
                if not 0 < width_c <= MAX_WIDTH_C:
                    self.fail(where, f"needs 0 < width_c <= {MAX_WIDTH_C:g}")
                lag_s = self.number(item["lag_s"], f"{where}.lag_s") if "lag_s" in item else None
                if lag_s is not None and not 0 < lag_s <= MAX_TAU_S:
                    self.fail(where, f"needs 0 < lag_s <= {MAX_TAU_S:g}")
                specs.append(InputSpec(TEMP_PLAY, width_c=width_c, play_lag_s=lag_s, **source))
            else:
                self.mapping(item, where, {"kind"})
                specs.append(InputSpec(item["kind"], **source))
        if len(set(specs)) != len(specs):
            self.fail("inputs", "lists the same input twice")
        return tuple(specs)

    def undither(self, item: dict, where: str, source: dict) -> tuple[dict, dict]:
        """An input's undither keys (all of them, valid together) taken out of `item` into its `source`."""
        if not UNDITHER_KEYS <= item.keys() or source["dequantise_c"] is not None:
            self.fail(where, f"needs all of {', '.join(sorted(UNDITHER_KEYS))} and no dequantise_c")
        item = dict(item)
        values = {key: self.number(item.pop(key), f"{where}.{key}", positive=True) for key in sorted(UNDITHER_KEYS)}
        try:
            InputSpec(TEMP, **values)
        except ValueError as error:
            self.fail(where, str(error))
        return item, source | values

    def outside(self, value: Any, d: int) -> OutsideRange:
        self.mapping(value, "outside_range", OUTSIDE_KEYS, optional=OPTIONAL_OUTSIDE_KEYS)
        policy = value["policy"]
        if policy not in OUTSIDE_POLICIES:
            self.fail("outside_range.policy", f"is {str(policy)[:40]!r}; expected one of {', '.join(OUTSIDE_POLICIES)}")
        if (policy in LINEAR_POLICIES) != ("coef" in value and "intercept" in value):
            self.fail("outside_range", f"needs coef and intercept with policy {policy!r}, and only then")
        if policy not in LINEAR_POLICIES:
            return OutsideRange(policy)
        coef = self.vector(value["coef"], "outside_range.coef", d)
        return OutsideRange(policy, coef, self.number(value["intercept"], "outside_range.intercept"))

    def guard(self, value: Any, inputs, x_mean, x_scale, y_mean, y_scale, domain_min, domain_max, name) -> DomainGuard:
        self.mapping(value, "domain_guard", GUARD_KEYS, optional=OPTIONAL_GUARD_KEYS)
        kind = value.get("kind", "joint")
        if kind not in GUARD_KINDS:
            self.fail("domain_guard.kind", f"is {str(kind)[:40]!r}; expected one of {', '.join(GUARD_KINDS)}")
        d = len(inputs)
        points = self.matrix(value["points"], "domain_guard.points", d)
        threshold = self.number(value["threshold"], "domain_guard.threshold", positive=True)
        fallback = value["fallback"]
        self.mapping(fallback, "domain_guard.fallback", {"method", "params"})
        if fallback["method"] != "linear":
            self.fail("domain_guard.fallback.method", f"is {str(fallback['method'])[:40]!r}; the fallback is 'linear'")
        self.mapping(fallback["params"], "domain_guard.fallback.params", PARAM_KEYS["linear"])
        params = {
            "coef": self.vector(fallback["params"]["coef"], "domain_guard.fallback.params.coef", d),
            "intercept": self.number(fallback["params"]["intercept"], "domain_guard.fallback.params.intercept"),
        }
        model = FrozenModel(
            method="linear", inputs=inputs, x_mean=x_mean, x_scale=x_scale, y_mean=y_mean, y_scale=y_scale,
            domain_min=domain_min, domain_max=domain_max, evaluator=build_evaluator("linear", params),
            name=f"{name} (fallback)",
        )  # fmt: skip
        shared = temperature_columns(inputs) if kind == "range" else ()
        return DomainGuard(points, threshold, x_mean, x_scale, model, kind, shared)

    def params(self, value: Any, method: str, d: int) -> dict[str, Any]:
        self.mapping(value, "params", PARAM_KEYS[method], optional=OPTIONAL_PARAM_KEYS.get(method, set()))
        out: dict[str, Any] = {"intercept": self.number(value["intercept"], "params.intercept")}
        if method == "linear":
            out["coef"] = self.vector(value["coef"], "params.coef", d)
        elif method == "ls-poly":
            out["powers"] = powers = self._powers(value["powers"], "params.powers", d)
            out["coef"] = self.vector(value["coef"], "params.coef", len(powers))
        elif method == "rbf-nn":
            out["centres"] = self.matrix(value["centres"], "params.centres", d)
            out["width"] = self.number(value["width"], "params.width", positive=True)
            if not MIN_SCALE <= out["width"] <= 1 / MIN_SCALE:
                self.fail("params.width", f"is {out['width']!r}; it must be within {MIN_SCALE:g}..{1 / MIN_SCALE:g}")
            out["coef"] = self.vector(value["coef"], "params.coef", len(out["centres"]))
        else:
            # an SVR may keep no support vector at all when its linear trend explains every block
            read = d
            if "kernel_columns" in value:
                out["kernel_columns"] = columns = self._columns(value["kernel_columns"], "params.kernel_columns", d)
                read = len(columns)
            out["support_vectors"] = self.matrix(value["support_vectors"], "params.support_vectors", read, allow_empty=True)
            out["dual_coef"] = self.vector(value["dual_coef"], "params.dual_coef", len(out["support_vectors"]))
            out["gamma"] = self.number(value["gamma"], "params.gamma", positive=True)
            if not MIN_SCALE <= out["gamma"] <= 1 / MIN_SCALE:
                self.fail("params.gamma", f"is {out['gamma']!r}; it must be within {MIN_SCALE:g}..{1 / MIN_SCALE:g}")
            if "trend_mix" in value:  # the coil temperature q = mix . x, read by the trend's monomials after x
                if "trend_powers" not in value:
                    self.fail("params.trend_mix", "needs params.trend_powers (the monomials that read it)")
                out["trend_mix"] = self.vector(value["trend_mix"], "params.trend_mix", d)
            if "trend_powers" in value:
                width = d + ("trend_mix" in value)
                out["trend_powers"] = self._powers(value["trend_powers"], "params.trend_powers", width)
                out["trend_coef"] = self.vector(value["trend_coef"], "params.trend_coef", len(out["trend_powers"]))
            else:
                out["trend_coef"] = self.vector(value["trend_coef"], "params.trend_coef", d)
        return out

    def _columns(self, value: Any, where: str, d: int) -> list[int]:
        """Input indices in increasing order, each once."""
        if (not isinstance(value, list) or not value or any(type(item) is not int for item in value)
                or value != sorted(set(value)) or value[0] < 0 or value[-1] >= d):  # fmt: skip
            self.fail(where, f"must list input indices 0..{d - 1} in increasing order, each once")
        return value

    def _powers(self, value: Any, where: str, d: int) -> np.ndarray:
        powers = self.matrix(value, where, d)
        if np.any(powers != np.round(powers)) or np.any(powers < 0) or np.any(powers > 20):
            self.fail(where, "must hold integers from 0 to 20")
        return powers.astype(np.int64)


def _floats(values: np.ndarray) -> list[float]:
    return [float(value) for value in np.asarray(values, dtype=np.float64).ravel()]
