"""Thermal-chamber temperature profiles: the setpoint a chamber follows, as soaks and linear ramps.

A profile is a list of `(duration_s, target_c)` segments. The run starts at the first target; each segment
moves the setpoint linearly from the previous target to its own target over its duration (a soak repeats
the previous target; a zero duration is a step). This module owns the built-in profiles (shaped like the
paper's section 4 chamber runs), loading a user profile from YAML with errors that name the file and the
entry, and evaluating the setpoint at any time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from fogd.errors import InputError, NoInputError, UsageError, describe_os_error

MIN_TEMP_C = -60.0
MAX_TEMP_C = 125.0
HOUR_S = 3600.0


@dataclass(frozen=True)
class Profile:
    """A chamber setpoint programme; raises ValueError naming the entry if a segment is unusable."""

    name: str
    segments: tuple[tuple[float, float], ...]

    def __post_init__(self) -> None:
        checked = tuple(_check_entry(number, entry) for number, entry in enumerate(self.segments, start=1))
        if not checked:
            raise ValueError("no segments (expected a list of [duration_s, target_c] pairs)")
        if sum(duration for duration, _ in checked) <= 0:
            raise ValueError("total duration is 0 s; give at least one segment a positive duration")
        object.__setattr__(self, "segments", checked)

    @property
    def start_c(self) -> float:
        return self.segments[0][1]

    @property
    def duration_s(self) -> float:
        return float(sum(duration for duration, _ in self.segments))

    def setpoint_c(self, t_s: np.ndarray | float) -> np.ndarray:
        """Setpoint at times `t_s` (held at the first target before 0 and at the last after the end)."""
        knots_t_s = np.concatenate(([0.0], np.cumsum([duration for duration, _ in self.segments])))
        knots_c = np.array([self.start_c] + [target for _, target in self.segments])
        t_s = np.asarray(t_s, dtype=np.float64)
        # side="right" lands on the last of equal knots, so a zero-duration segment acts as a step.
        index = np.clip(np.searchsorted(knots_t_s, t_s, side="right") - 1, 0, knots_t_s.size - 2)
        span_s = knots_t_s[index + 1] - knots_t_s[index]
        fraction = np.clip((t_s - knots_t_s[index]) / np.where(span_s > 0, span_s, 1.0), 0.0, 1.0)
        fraction = np.where(span_s > 0, fraction, 1.0)
        return knots_c[index] + (knots_c[index + 1] - knots_c[index]) * fraction

    def describe(self) -> str:
        """One line such as 'soak 3600 s at -15 C; ramp 10800 s to 50 C'."""
        parts, previous_c = [], self.start_c
        for duration_s, target_c in self.segments:
            verb = "soak" if target_c == previous_c else "ramp"
            parts.append(f"{verb} {duration_s:g} s {'at' if verb == 'soak' else 'to'} {target_c:g} C")
            previous_c = target_c
        return "; ".join(parts)


def _check_entry(number: int, entry: object) -> tuple[float, float]:
    if not isinstance(entry, (list, tuple)) or len(entry) != 2:
        raise ValueError(f"entry {number} ({entry!r}): expected a pair [duration_s, target_c]")
    duration_s, target_c = (_number(number, entry, value) for value in entry)
    if duration_s < 0:
        raise ValueError(f"entry {number} ({list(entry)!r}): duration {duration_s:g} s is negative")
    if not MIN_TEMP_C <= target_c <= MAX_TEMP_C:
        raise ValueError(
            f"entry {number} ({list(entry)!r}): target {target_c:g} C is outside "
            f"{MIN_TEMP_C:g}..{MAX_TEMP_C:g} C"
        )
    return duration_s, target_c


def _number(number: int, entry: object, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"entry {number} ({entry!r}): {value!r} is not a finite number")
    return float(value)


_BUILTIN: dict[str, tuple[str, tuple[tuple[float, float], ...]]] = {
    "paper-train": (
        "-15 C to 50 C heating, like the paper's training run (section 4.1)",
        ((1.0 * HOUR_S, -15.0), (3.0 * HOUR_S, 50.0), (0.75 * HOUR_S, 50.0)),
    ),
    "paper-test": (
        "0 C to 30 C heating, like the paper's real-time test run (section 4.2)",
        ((0.5 * HOUR_S, 0.0), (2.0 * HOUR_S, 30.0), (0.5 * HOUR_S, 30.0)),
    ),
    "cooling": (
        "50 C to -10 C cooling",
        ((0.5 * HOUR_S, 50.0), (3.0 * HOUR_S, -10.0), (0.5 * HOUR_S, -10.0)),
    ),
    "cycle": (
        "-10 C up to 50 C and back down",
        ((0.5 * HOUR_S, -10.0), (2.5 * HOUR_S, 50.0), (0.5 * HOUR_S, 50.0), (2.5 * HOUR_S, -10.0),
         (0.5 * HOUR_S, -10.0)),
    ),
    "fast-ramp": (
        "0 C to 40 C in 30 min (80 C/h), then a soak",
        ((0.5 * HOUR_S, 0.0), (0.5 * HOUR_S, 40.0), (1.0 * HOUR_S, 40.0)),
    ),
    "soak-after-ramp": (
        "10 C to 40 C in 1 h, then a 2 h soak (the thermal transient dies out)",
        ((0.25 * HOUR_S, 10.0), (1.0 * HOUR_S, 40.0), (2.0 * HOUR_S, 40.0)),
    ),
    "cool-40-to-0": (
        "40 C to 0 C cooling in 2 h (20 C/h), 1 h soaks before and after",
        ((1.0 * HOUR_S, 40.0), (2.0 * HOUR_S, 0.0), (1.0 * HOUR_S, 0.0)),
    ),
    "fast-cycle": (
        "10 C up to 40 C and back in 30 min each (60 C/h), then a soak",
        ((0.5 * HOUR_S, 10.0), (0.5 * HOUR_S, 40.0), (0.5 * HOUR_S, 10.0), (1.0 * HOUR_S, 10.0)),
    ),
    # Two more calibration runs of the KVH owner's chamber programme (docs/guides/kvh-chamber.md) (its "soaks" and "fastest ramp" rows),
    # over another range than the held-out runs above
    "cal-soaks": (
        "0 C, then 20 C/h steps to 10, 20 and 35 C with a 90 min soak at each (calibration: the slow lags settle)",
        ((0.5 * HOUR_S, 0.0), (0.5 * HOUR_S, 10.0), (1.5 * HOUR_S, 10.0), (0.5 * HOUR_S, 20.0), (1.5 * HOUR_S, 20.0),
         (0.75 * HOUR_S, 35.0), (1.5 * HOUR_S, 35.0)),
    ),
    "cal-fast-cycle": (
        "-10 C up to 50 C and back at 60 C/h, 30 min soaks (calibration: a fast history and a fast reversal)",
        ((0.5 * HOUR_S, -10.0), (1.0 * HOUR_S, 50.0), (0.5 * HOUR_S, 50.0), (1.0 * HOUR_S, -10.0), (0.5 * HOUR_S, -10.0)),
    ),
}


def names() -> list[str]:
    """Names of the built-in profiles."""
    return list(_BUILTIN)


def summary(name: str) -> str:
    """A short description of built-in profile `name`."""
    return _BUILTIN[name][0] if name in _BUILTIN else ""


def builtin(name: str) -> Profile:
    """Built-in profile `name`; raises UsageError listing the names if there is none."""
    if name not in _BUILTIN:
        raise UsageError(f"unknown profile {name!r}; built-in profiles: {', '.join(_BUILTIN)} (or a YAML file)")
    return Profile(name, _BUILTIN[name][1])


def load(path: str | Path) -> Profile:
    """A profile from a YAML list of [duration_s, target_c] pairs; raises InputError naming file and entry."""
    path = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as error:
        raise NoInputError(f"cannot read profile {describe_os_error(error)}") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text file (expected YAML)") from None
    try:
        entries = yaml.safe_load(text)
    except yaml.YAMLError as error:
        where = getattr(error, "problem_mark", None)
        line = f":{where.line + 1}" if where is not None else ""
        problem = getattr(error, "problem", None) or "invalid YAML"
        raise InputError(f"{path}{line}: {problem}") from None
    if not isinstance(entries, list):
        raise InputError(
            f"{path}: expected a YAML list of [duration_s, target_c] pairs, found {type(entries).__name__}"
        )
    try:
        return Profile(Path(path).stem, tuple(entries))
    except ValueError as error:
        raise InputError(f"{path}: {error}") from None


def resolve(spec: str) -> Profile:
    """A built-in profile by name, or a YAML file when `spec` names an existing file or ends in .yaml/.yml."""
    if spec in _BUILTIN:
        return builtin(spec)
    if Path(spec).suffix.lower() in (".yaml", ".yml") or Path(spec).is_file():
        return load(spec)
    return builtin(spec)
