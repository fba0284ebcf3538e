"""The daemon's settings: the table of every key (type, unit, default, range), where the config file is looked
for, reading and validating it, and merging defaults < config file < command line. Every problem is a
`ConfigError` (exit 78) whose one line names the file, the key and the reason; nothing here raises anything else.

The config file is YAML with the same keys as the long options (underscores for dashes). Without `--config`
the daemon reads `$FOGD_CONFIG_DIR/<instance>.yaml` (for `--instance NAME`) or else `$FOGD_CONFIG_DIR/fogd.yaml`
when one exists; `FOGD_CONFIG_DIR` defaults to /etc/fogd. A file named with `--config` must exist.
"""

from __future__ import annotations

import argparse
import difflib
import ipaddress
import math
import os
import reprlib
from dataclasses import dataclass
from typing import Any, Callable

from fogd import protocols
from fogd.core.numbers import number_in, whole_number
from fogd.core.yamlfile import YamlFileError, read_yaml
from fogd.errors import ConfigError, describe_os_error
from fogd.protocols import kvh
from fogd.serving import placement

CONFIG_DIR = "/etc/fogd"
CONFIG_DIR_ENV = "FOGD_CONFIG_DIR"
DEFAULT_INSTANCE = "fogd"
DEFAULT_MODEL = "/var/lib/fogd/model.json"
RUNTIME_DIR = "/run/fogd"
MAX_CONFIG_BYTES = 1 << 20
AXES = ("x", "y", "z")
KVH_ONLY = ("rotfmt", "angle_unit", "linfmt", "lin_unit", "temp_unit", "query_settings")  # a KVH unit's settings
OUT_FORMATS = ("same", "fogd", "csv", "jsonl")
NONE_WORDS = ("none", "off")  # for optional paths on the command line


def _text(text: str) -> str:
    if not text:
        raise argparse.ArgumentTypeError("must not be empty")
    if not text.isprintable():  # a newline in a path or name would forge log lines and systemd fields
        raise argparse.ArgumentTypeError(f"{_show(text)} holds a control character")
    return text


def _optional_jump(text: str) -> float | None:
    return None if text.lower() in NONE_WORDS else number_in(0.0, math.inf, "deg/h", low_open=True)(text)


def _optional_path(text: str) -> str | None:
    return None if text.lower() in NONE_WORDS else _text(text)


def _address(text: str) -> str:
    try:
        return str(ipaddress.ip_address(text))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an IP address (e.g. 127.0.0.1 or ::1)") from None


def _optional_port(text: str) -> int | None:
    if text.lower() in NONE_WORDS:
        return None
    port = whole_number(1)(text)
    if port > 65535:
        raise argparse.ArgumentTypeError(f"{text!r} is outside 1..65535")
    return port


def _baud(text: str) -> int:
    baud = whole_number(50)(text)
    if baud > 12_000_000:
        raise argparse.ArgumentTypeError(f"{text!r} is outside 50..12000000")
    return baud


@dataclass(frozen=True)
class Option:
    """One setting: the command-line conversion (text -> value), its kind in the config file ('number',
    'text' or 'choice'), default, unit and help."""

    key: str
    convert: Callable[[str], Any]
    kind: str
    default: Any
    help: str
    unit: str = ""
    metavar: str | None = None
    choices: tuple[str, ...] | None = None
    reloadable: bool = False  # applied by SIGHUP without a restart
    # kind 'flag': true/false in the config file, --NAME / --no-NAME on the command line


OPTIONS = (
    Option("port", _text, "text", None, "serial port the FOG is on, e.g. /dev/ttyUSB0 (required unless --demo)",
           metavar="PATH"),
    Option("baud", _baud, "number", 921600, "baud rate of the port, and of --out when it is a serial port "
           "(50..12000000; default: %(default)s)", "baud", "BAUD"),
    Option("protocol", _text, "choice", "auto", "wire protocol of the port; auto recognises kvh-a, fogd and ascii "
           "from the first frames (default: %(default)s)", choices=("auto", *protocols.names())),
    Option("model", _text, "text", DEFAULT_MODEL, f"model file from fogd-train (default: {DEFAULT_MODEL}; with "
           "--demo the bundled demo model)", metavar="PATH", reloadable=True),
    Option("out", _text, "text", "-", "where compensated frames go: '-' stdout, a file or serial/pty device path, "
           "or pty:PATH (fogd makes a pty and links PATH to it) (default: '-' when stdout is a terminal; "
           "required otherwise, as under systemd)", metavar="SINK"),
    Option("out_format", _text, "choice", "same", "output format: 'same' re-encodes the input protocol with the "
           "compensated rate and a fresh CRC; 'fogd' fogd compensated-output frames; 'csv' fogd-replay's columns; "
           "'jsonl' one JSON object per sample (default: %(default)s)", choices=OUT_FORMATS),
    Option("rate_hz", number_in(0.0, 100_000.0, "Hz", low_open=True), "number", 1000.0, "FOG sample rate, for the "
           "temperature-rate estimator and for output time where the protocol has no timestamp (KVH Format A has "
           "none) (0..100000 Hz; default: %(default)s)", "Hz", "HZ"),
    Option("axis", _text, "choice", "z", "gyro axis a single-axis model compensates; the other axes pass through "
           "untouched (a three-axis model compensates every channel it has; default: %(default)s)", choices=AXES),
    Option("rotfmt", _text, "choice", "rate", "protocol kvh-a: the unit's =ROTFMT, gyros as rate (angle/s) or delta "
           "(angle per sample at rate_hz; compensation x sample period is subtracted) (default: %(default)s)",
           choices=kvh.ROTFMTS),
    Option("angle_unit", _text, "choice", "rad", "protocol kvh-a: the unit's =ROTUNITS (default: %(default)s)",
           choices=kvh.ANGLE_UNITS),
    Option("linfmt", _text, "choice", "accel", "protocol kvh-a: the unit's =LINFMT, accelerometers as accel (g) or "
           "delta (velocity change per sample at rate_hz) (default: %(default)s)", choices=kvh.LINFMTS),
    Option("lin_unit", _text, "choice", "m", "protocol kvh-a: the unit's =LINUNITS, delta velocity in m/s or ft/s "
           "(default: %(default)s)", choices=kvh.LIN_UNITS),
    Option("temp_unit", _text, "choice", "C", "protocol kvh-a: the unit's =TEMPUNITS (default: %(default)s)",
           choices=kvh.TEMP_UNITS),
    Option("query_settings", bool, "flag", False, "protocol kvh-a: at start, ask the unit for its settings "
           "(=CONFIG,1, ?ROTFMT ?ROTUNITS ?LINFMT ?LINUNITS ?TEMPUNITS ?DR, =CONFIG,0) and refuse to run if one "
           "contradicts the config (exit 78) (default: off)"),
    Option("temp_stale_s", number_in(0.0, 3600.0, "s", low_open=True), "number", 2.0, "flag samples TEMP_STALE "
           "when the newest temperature arrived more than this long ago (0..3600 s; default: %(default)s)", "s", "S",
           reloadable=True),
    Option("status_interval_s", number_in(0.1, 86400.0, "s"), "number", 10.0, "seconds between one-line status "
           "logs (0.1..86400 s; default: %(default)s)", "s", "S", reloadable=True),
    Option("duration_s", number_in(0.0, math.inf, "s", low_open=True), "number", None, "stop after this many "
           "seconds (default: run until SIGTERM/SIGINT)", "s", "S"),
    Option("stats_file", _optional_path, "path", "auto", "JSON stats file rewritten atomically every second, read "
           f"by 'fogd --status'; 'auto': {RUNTIME_DIR}/<instance>.json when {RUNTIME_DIR} exists, else none; "
           "'none' disables it (default: %(default)s)", metavar="PATH"),
    Option("metrics_port", _optional_port, "port", None, "serve Prometheus text metrics on this TCP port "
           "(1..65535; default: off)", metavar="PORT"),
    Option("max_rate_jump_dph", _optional_jump, "port", None, "protocol ascii: flag a rate (axis invalid, "
           "counted as implausible) that jumps by more than this from both the previous and the last accepted "
           "rate, on lines without a checksum (DSP-3000 lines always) (deg/h, above 0; default: off)", "deg/h",
           "DPH", reloadable=False),
    Option("cpu", placement.cpu_setting, "cpu", placement.AUTO, "CPU the daemon's threads run on: 'auto' keeps them "
           "together on the CPU fogd starts on and moves them when other processes keep it busy; a number keeps "
           "them there; 'any' lets the kernel place each thread (together they cost less CPU: one cache, no "
           "cross-CPU wake-ups) (default: %(default)s)", metavar="auto|any|N"),
    Option("state_file", _optional_path, "path", "auto", "the thermal state (temperature history) kept across "
           "restarts, written atomically every few seconds and at stop (docs/reference/thermal-state.md); 'auto': "
           f"$STATE_DIRECTORY/<instance>-thermal.json when systemd gives a state directory, else none; 'none' "
           "disables it (every start is then a cold start) (default: %(default)s)", metavar="PATH"),
    Option("warming", _text, "choice", "compensate", "what a cold start's WARMING samples get: 'compensate' "
           "(compensated and flagged), 'fallback' (the domain guard's linear fallback where the model has one, "
           "else passed), 'pass' (passed through uncompensated) (default: %(default)s)",
           choices=("compensate", "fallback", "pass")),
    Option("warming_tolerance_dph", number_in(0.0, 1e6, "deg/h", low_open=True), "number", 0.002, "a cold start's "
           "samples are flagged WARMING while the equilibrium assumption can cost more than this (deg/h; default: "
           "%(default)s)", "deg/h", "DPH"),
    Option("metrics_address", _address, "text", "127.0.0.1", "address the metrics endpoint binds to "
           "(default: %(default)s; anything else exposes it beyond this machine)", metavar="ADDR"),
)
OPTION_BY_KEY = {option.key: option for option in OPTIONS}


def config_dir() -> str:
    return os.environ.get(CONFIG_DIR_ENV) or CONFIG_DIR


def default_config_path(instance: str | None) -> str | None:
    """The config file used without --config: <dir>/<instance>.yaml, else <dir>/fogd.yaml, if one exists."""
    names = ([f"{instance}.yaml"] if instance and instance != DEFAULT_INSTANCE else []) + [f"{DEFAULT_INSTANCE}.yaml"]
    for name in names:
        path = os.path.join(config_dir(), name)
        if os.path.exists(path):
            return path
    return None


def load(path: str) -> dict[str, Any]:
    """Settings from a YAML file, each checked like its command-line option; ConfigError names the key."""
    try:
        document = read_yaml(path, "a fogd config", MAX_CONFIG_BYTES)
    except OSError as error:
        raise ConfigError(f"cannot read config {describe_os_error(error)}") from None
    except YamlFileError as error:
        raise ConfigError(str(error)) from None
    if document is None:
        return {}
    if not isinstance(document, dict):
        raise ConfigError(f"{path}: expected a mapping of settings (key: value), found {type(document).__name__}")
    settings = {}
    for key, value in document.items():
        option = OPTION_BY_KEY.get(key) if isinstance(key, str) else None
        if option is None:
            raise ConfigError(f"{path}: unknown key {str(key)[:40]!r}{_did_you_mean(key)}; known keys: "
                              f"{', '.join(OPTION_BY_KEY)}")  # fmt: skip
        settings[key] = _value(path, option, value)
    return settings


def _did_you_mean(key: Any) -> str:
    """' (did you mean out_format?)' for a key spelt with dashes, like the long option, or mistyped."""
    if not isinstance(key, str):
        return ""
    underscored = key.strip().lstrip("-").replace("-", "_").lower()
    if underscored in OPTION_BY_KEY:
        return f" (did you mean {underscored}? keys use underscores where options use dashes)"
    close = difflib.get_close_matches(underscored, OPTION_BY_KEY, n=1, cutoff=0.75)
    return f" (did you mean {close[0]}?)" if close else ""


def _value(path: str, option: Option, value: Any) -> Any:
    where = f"{path}: key {option.key!r}"
    if value is None:
        if option.default is None or option.kind in ("path", "port"):
            return None
        raise ConfigError(f"{where} needs a value (default: {option.default})")
    if option.kind == "flag":
        if not isinstance(value, bool):
            raise ConfigError(f"{where} must be true or false, found {_show(value)}")
        return value
    if option.kind == "cpu":  # a word or a CPU number
        if isinstance(value, bool) or not isinstance(value, (int, str)):
            raise ConfigError(f"{where} must be auto, any or a CPU number, found {_show(value)}")
        try:
            return option.convert(str(value))
        except argparse.ArgumentTypeError as error:
            raise ConfigError(f"{where}: {error}") from None
    if option.kind in ("number", "port"):
        # YAML 1.1 reads 1e3 as a string: accept text that is a number, refuse everything else
        ok_type = isinstance(value, (int, float, str)) and not isinstance(value, bool)
        expected = "a number"
        if isinstance(value, str):
            try:
                float(value)
            except ValueError:
                ok_type = option.kind == "port" and value.lower() in NONE_WORDS
    else:
        ok_type = isinstance(value, str)
        expected = "a string"
    if not ok_type:
        raise ConfigError(f"{where} must be {expected}, found {_show(value)}")
    if option.choices is not None and value not in option.choices:
        raise ConfigError(f"{where} is {_show(value)}; valid values: {', '.join(option.choices)}")
    try:
        return option.convert(str(value))
    except (argparse.ArgumentTypeError, ValueError) as error:
        raise ConfigError(f"{where}: {error}") from None


def _show(value: Any) -> str:
    text = _SHORT.repr(value)  # never the whole value: it may be huge
    return text if len(text) <= 40 else text[:37] + "..."


_SHORT = reprlib.Repr()
_SHORT.maxstring = _SHORT.maxother = _SHORT.maxlong = 40
_SHORT.maxlevel = 2


def merge(config: dict[str, Any], command_line: dict[str, Any]) -> dict[str, Any]:
    """Defaults, overridden by the config file, overridden by the command line."""
    settings = {option.key: option.default for option in OPTIONS}
    settings.update(config)
    settings.update(command_line)
    return settings


def check(settings: dict[str, Any], *, demo: bool) -> None:
    """Cross-key checks and the model's presence; raises ConfigError naming the key."""
    if settings["port"] is None and not demo:
        raise ConfigError("key 'port' is not set: give --port PATH (or port: in the config), or try --demo")
    if settings["protocol"] == "ascii" and settings["axis"] != "z":
        raise ConfigError("key 'axis': protocol ascii carries the z axis only; use axis z")
    if settings["protocol"] not in ("kvh-a", "auto"):
        for key in KVH_ONLY:
            if settings[key] != OPTION_BY_KEY[key].default:
                raise ConfigError(f"key '{key}' sets a KVH unit's output: it applies to protocol kvh-a only, "
                                  f"not {settings['protocol']}")  # fmt: skip
    model = settings["model"]
    try:
        os.stat(model)
    except PermissionError:
        raise ConfigError(f"key 'model': {model}: permission denied (fogd's user must be able to read it and "
                          "its directories)") from None  # fmt: skip
    except OSError:
        raise ConfigError(
            f"key 'model': {model}: no such file (train one with fogd-train and install it there, or set model:)"
        ) from None


def instance_stats_path(instance: str) -> str:
    """Where a daemon named `instance` writes its stats by default: <runtime dir>/<instance>.json."""
    return os.path.join(RUNTIME_DIR, f"{instance}.json")


def state_path(setting: str | None, instance: str) -> str | None:
    """The thermal state file: the setting, or for 'auto' <$STATE_DIRECTORY>/<instance>-thermal.json when systemd
    set a state directory (StateDirectory=), else none."""
    if setting != "auto":
        return setting
    directory = os.environ.get("STATE_DIRECTORY", "").split(":")[0]
    return os.path.join(directory, f"{instance}-thermal.json") if directory else None


def stats_path(setting: str | None, instance: str) -> str | None:
    """The stats file to write: the setting, or for 'auto' <runtime dir>/<instance>.json if that dir exists."""
    if setting != "auto":
        return setting
    return instance_stats_path(instance) if os.path.isdir(RUNTIME_DIR) else None
