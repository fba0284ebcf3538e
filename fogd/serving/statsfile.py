"""The stats file: a JSON snapshot of the running daemon, rewritten atomically (a temporary file in the same
directory, then rename) so a reader never sees half a file, and read back by `fogd --status`. NaN and
infinities are written as null, so any JSON reader can parse it. A write that fails is logged once and
retried at the next tick; it never disturbs the data path.
"""

from __future__ import annotations

import json
import logging
import math
import os
import tempfile
import time
from typing import Any

from fogd.core.columns import channel_unit
from fogd.errors import DeviceError, describe_os_error

log = logging.getLogger("fogd.stats")
STALE_AFTER_S = 5.0  # a running daemon rewrites the file every second
_failed_paths: set[str] = set()


def _clean(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {key: _clean(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(item) for item in value]
    return value


def write_stats(path: str, snapshot: dict[str, Any]) -> bool:
    """Replace `path` with `snapshot` as JSON; False (logged once per path) when it cannot be written."""
    temporary = None
    try:
        # a random name made with O_EXCL|O_NOFOLLOW: a link or FIFO planted at a predictable name (stats files
        # live in /tmp in the README's example) is never followed, written or waited on
        directory, name = os.path.split(path)
        fd, temporary = tempfile.mkstemp(dir=directory or ".", prefix=f".{name}.", suffix=".tmp")
        os.fchmod(fd, 0o644)  # readable by fogd-top and --status of other users, as before
        with os.fdopen(fd, "w", encoding="utf-8") as stream:
            json.dump(_clean(snapshot), stream, allow_nan=False, separators=(",", ":"))
            stream.write("\n")
        os.replace(temporary, path)
    except OSError as error:
        if path not in _failed_paths:
            log.warning("cannot write stats file %s", describe_os_error(error))
            _failed_paths.add(path)
        try:
            if temporary is not None:
                os.unlink(temporary)
        except OSError:
            pass
        return False
    _failed_paths.discard(path)
    return True


def default_path(setting: str | None, instance: str) -> str:
    """The stats file `fogd --status` and `fogd-top` read: the stats_file setting, or for 'auto' (and 'none')
    <runtime dir>/<instance>.json, where a service's daemon writes it."""
    from fogd.serving.config import instance_stats_path

    return setting if setting not in ("auto", None) else instance_stats_path(instance)


def read_stats(path: str) -> dict[str, Any]:
    """The snapshot in `path`; DeviceError with one line when there is none to read."""
    try:
        with open(path, encoding="utf-8") as stream:
            snapshot = json.load(stream)
    except FileNotFoundError:
        raise DeviceError(f"{path}: no stats file (is fogd running, with stats_file set?)") from None
    except OSError as error:
        raise DeviceError(f"cannot read stats file {describe_os_error(error)}") from None
    except ValueError as error:
        raise DeviceError(f"{path}: not a fogd stats file ({error})") from None
    if not isinstance(snapshot, dict):
        raise DeviceError(f"{path}: not a fogd stats file")
    return snapshot


def is_live(snapshot: dict[str, Any]) -> bool:
    """Whether the daemon that wrote `snapshot` is still running and writing it."""
    pid = snapshot.get("pid")
    if not snapshot.get("running") or not isinstance(pid, int):
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, owned by another user (the service's)
        pass
    written = snapshot.get("time_unix_s")
    return isinstance(written, (int, float)) and time.time() - written < STALE_AFTER_S


def held_out_text(model: dict[str, Any]) -> str:
    """The model's held-out drift as fogd-train estimated it (model file metrics.held_out), per channel."""
    figures = model.get("held_out")
    if not isinstance(figures, dict) or not figures:
        return "held-out drift not in the model file (trained before fogd-train's ladder, or with --method)"

    def one(channel: str, figure: Any) -> str:
        if not isinstance(figure, dict) or not all(isinstance(figure.get(k), (int, float)) for k in ("drift_rmse", "spread")):
            return f"{channel} ?"
        return f"{figure['drift_rmse']:.3g} ± {figure['spread']:.2g} {channel_unit(channel)}"

    if len(figures) == 1:
        channel, figure = next(iter(figures.items()))
        folds = figure.get("folds") if isinstance(figure, dict) else None
        return f"held-out drift {one(channel, figure)}" + (f" ({folds})" if isinstance(folds, str) else "")
    return "held-out drift " + ", ".join(f"{channel} {one(channel, figure)}" for channel, figure in figures.items())


def describe(snapshot: dict[str, Any]) -> str:
    """A few lines for an operator."""
    live = is_live(snapshot)
    age_s = time.time() - snapshot.get("time_unix_s", 0.0)
    state = "running" if live else f"NOT running (last written {age_s:.0f} s ago)"
    latency = snapshot.get("latency_s") or {}
    latest = snapshot.get("latest") or {}
    model = snapshot.get("model") or {}

    def number(value: Any, spec: str) -> str:
        return format(value, spec) if isinstance(value, (int, float)) else "-"

    channels = latest.get("channels")
    if isinstance(channels, dict) and channels:  # a multi-channel model: each channel's, in its own unit
        comp = "comp " + ", ".join(
            f"{name} {number(one.get('comp') if isinstance(one, dict) else None, '+.6g')} {channel_unit(name)}"
            for name, one in channels.items()
        )
    else:
        comp = f"comp {number(latest.get('comp_dph'), '+.4f')} deg/h"
    cpu = snapshot.get("cpu") or {}
    on = cpu.get("on") if isinstance(cpu, dict) else None
    placed = f", threads on CPU {on} ({cpu.get('setting')}, moved {cpu.get('moves')} times)" if on is not None else ""
    return "\n".join(
        [
            f"fogd {snapshot.get('version', '?')} pid {snapshot.get('pid')} {state}, up {number(snapshot.get('uptime_s'), '.0f')} s, "
            f"port {snapshot.get('port', '?')} {'connected' if snapshot.get('connected') else 'LOST (waiting for it)'}{placed}",
            f"model {model.get('name')} ({model.get('method')}); T {number(latest.get('temp_c'), '.2f')} C, "
            f"dT/dt {number(latest.get('temp_rate_cps'), '+.5f')} C/s, {comp}, "
            f"latency {number(1e3 * latency['last'] if isinstance(latency.get('last'), (int, float)) else None, '.1f')} ms",
            held_out_text(model),
            str(snapshot.get("status", "")),
            *_thermal_lines(snapshot.get("thermal")),
        ]
    )


def _thermal_lines(thermal: Any) -> list[str]:
    """The thermal state's line (serving.thermalstate): how the run started and whether it is still WARMING."""
    if not isinstance(thermal, dict):
        return []
    warming = thermal.get("warming")
    bound = thermal.get("bound_dph")
    return [f"thermal state: {thermal.get('started') or 'waiting for the first temperature'}"
            f"{', WARMING' + (f' (bound {bound:.2g} deg/h)' if isinstance(bound, (int, float)) else '') if warming else ''}, "
            f"{thermal.get('history_points')} points of history, state file {thermal.get('state_file') or 'none'}"]
