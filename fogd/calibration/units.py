"""A production line's manifest: the units calibrated together in one chamber, each trained into its own
model file by one `fogd-train --manifest units.yaml --jobs N`.

    units:
      - name: imu-0412
        runs: [chamber-1.csv, chamber-2.csv]
        channels: [rate_x_dph, rate_y_dph, rate_z_dph]   # optional: every channel of the runs
        holdout: [check-1.csv]                            # optional: table 4 of each
        out: models/imu-0412.json                         # optional: <name>.json (beside the manifest or in -o DIR)

Paths are relative to the manifest's directory. The YAML is read bounded and strict (fogd.core.yamlfile,
as the daemon's config); anything unusable is a one-line InputError naming the unit and the key.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fogd.core.columns import CHANNELS
from fogd.core.yamlfile import YamlFileError, read_yaml
from fogd.errors import InputError, NoInputError, describe_os_error

UNIT_KEYS = {"name", "runs", "channels", "holdout", "out"}
REQUIRED_KEYS = {"name", "runs"}
NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")  # also a file name: <name>.json
MAX_UNITS = 1000
MAX_MANIFEST_BYTES = 1 << 20


@dataclass
class Unit:
    """One unit to calibrate: its runs and what to write."""

    name: str
    runs: list[str]
    out: str
    channels: list[str] | None = None
    holdout: list[str] = field(default_factory=list)


def read_manifest(path: str, out_dir: str | None = None) -> list[Unit]:
    """The units of the manifest at `path`; NoInputError when it cannot be read, InputError when unusable."""
    try:
        document = read_yaml(path, "a manifest", MAX_MANIFEST_BYTES)
    except OSError as error:
        raise NoInputError(f"cannot read manifest: {describe_os_error(error)}") from None
    except YamlFileError as error:
        raise InputError(str(error)) from None
    return units_from_manifest(document, path, out_dir)


def units_from_manifest(document: Any, source: str, out_dir: str | None = None) -> list[Unit]:
    """The manifest's units, checked; `source` is the manifest's path (relative paths start from its
    directory), `out_dir` where `<name>.json` goes for a unit without `out` (default: the manifest's directory)."""
    base = Path(source).parent
    if not isinstance(document, dict) or set(document) != {"units"}:
        found = ", ".join(map(repr, document)) if isinstance(document, dict) else type(document).__name__
        raise InputError(f"{source}: a manifest is a mapping with the one key 'units' (a list of units); found {found}")
    entries = document["units"]
    if not isinstance(entries, list) or not 1 <= len(entries) <= MAX_UNITS:
        raise InputError(f"{source}: 'units' must be a list of 1 to {MAX_UNITS} units (each with a name and its runs)")
    units: list[Unit] = []
    for index, entry in enumerate(entries, start=1):
        units.append(_unit(entry, f"{source}: unit {index}", base, out_dir))
    _unique(source, "name", [unit.name for unit in units])
    _unique(source, "out", [str(Path(unit.out).resolve()) for unit in units])
    return units


def _unit(entry: Any, where: str, base: Path, out_dir: str | None) -> Unit:
    if not isinstance(entry, dict):
        raise InputError(f"{where}: must be a mapping with {', '.join(sorted(REQUIRED_KEYS))}, found {type(entry).__name__}")
    name = entry.get("name")
    if isinstance(name, str) and NAME.fullmatch(name):
        where = f"{where.rsplit(': ', 1)[0]}: unit {name}"
    unknown = sorted(set(map(str, entry)) - UNIT_KEYS)
    if unknown:
        raise InputError(f"{where}: unknown key(s) {', '.join(map(repr, unknown))}; a unit has {', '.join(sorted(UNIT_KEYS))}")
    missing = sorted(REQUIRED_KEYS - set(entry))
    if missing:
        raise InputError(f"{where}: lacks {', '.join(missing)}")
    if not isinstance(name, str) or not NAME.fullmatch(name):
        raise InputError(f"{where}: name {str(name)[:40]!r} must be 1 to 64 letters, digits, '.', '_' or '-' "
                         "(it names the model file)")  # fmt: skip
    runs = _paths(entry["runs"], f"{where}: runs", base, allow_empty=False)
    holdout = _paths(entry.get("holdout", []), f"{where}: holdout", base, allow_empty=True)
    channels = entry.get("channels")
    if channels is not None:
        if not isinstance(channels, list) or not channels or not all(isinstance(c, str) for c in channels):
            raise InputError(f"{where}: channels must be a list of channel names")
        bad = [c for c in channels if c not in CHANNELS]
        if bad:
            raise InputError(f"{where}: unknown channel {bad[0][:40]!r}; channels are {', '.join(CHANNELS)}")
    out = entry.get("out")
    if out is None:
        out = str(Path(out_dir) / f"{name}.json") if out_dir else str(base / f"{name}.json")
    elif not isinstance(out, str) or not out:
        raise InputError(f"{where}: out must be a path")
    else:
        out = str(base / out)
    return Unit(name, runs, out, channels, holdout)


def _paths(value: Any, where: str, base: Path, *, allow_empty: bool) -> list[str]:
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list) or not (value or allow_empty) or not all(isinstance(v, str) and v for v in value):
        raise InputError(f"{where} must be a list of run CSV paths")
    paths = [str(base / path) for path in value]
    for path in paths:
        if not Path(path).is_file():
            raise InputError(f"{where}: no run file {path}")
    return paths


def _unique(source: str, key: str, values: list[str]) -> None:
    seen: set[str] = set()
    for value in values:
        if value in seen:
            raise InputError(f"{source}: two units have the same {key} {value!r}; each unit needs its own")
        seen.add(value)
