"""The daemon's thermal past across restarts and reloads (issue 34): the temperature history (fogd.core.history)
kept as samples are compensated, saved to the state file, read back at start, and the WARMING flag
(fogd.core.warming) when there is none.

The state file is JSON: the device it came from (the unit's serial number where it reports one, else the port),
the clock its times are on ("device": the protocol's timestamps; "wall": Unix time of the sample count), the
newest sample, and the history's block means. It is written atomically (a temporary file beside it, fsynced,
renamed over it: the link itself, never a symlink's target) every SAVE_EVERY_S and at stop. At start it is an
input like any other: opened without following a symlink, a regular file only, at most MAX_STATE_BYTES read,
parsed strictly; anything wrong with it is one warning and a cold start. A history from another device or
clock, or whose newest sample is older than the model's longest memory (its slowest lag's time constant;
MIN_MEMORY_S at least), is not used either (said so). A usable one is bridged to the first new sample with a
straight line (fogd.core.history.bridge), and the log says how long the gap was.
"""

from __future__ import annotations

import json
import logging
import math
import os
import stat
import tempfile
import threading
import time
from dataclasses import dataclass
from typing import Any

from fogd.core.channels import ChannelCompensator
from fogd.core.compensator import TEMP_VALID_C
from fogd.core.flags import Flag
from fogd.core.frozen import FrozenModel
from fogd.core.history import MIN_SPAN_S, SPAN_FACTOR, TempHistory, thinned
from fogd.core.modelfile import printable
from fogd.core.warming import MODES, WarmingBound, apply_mode

log = logging.getLogger("fogd.thermal")

FORMAT = "fogd-thermal-state"
VERSION = 1
MAX_STATE_BYTES = 4 << 20  # 15,000 block means take about 300 kB
MAX_POINTS = 200_000
SAVE_EVERY_S = 5.0
FLUSH_SAMPLES = 256  # observed temperatures gathered before they go into the history (see Thermal)
MIN_MEMORY_S = 600.0  # a model without lags still has its eq. 16 windows and play: a gap up to this is bridged
_TEMP_INVALID, _WARMING = int(Flag.TEMP_INVALID), int(Flag.WARMING)


class StateFileError(ValueError):
    """The state file cannot be used; the message says why, in one line."""


@dataclass(frozen=True)
class Saved:
    device: str
    clock: str
    samples: int
    points: list[tuple[float, float]]

    @property
    def last_t_s(self) -> float:
        return self.points[-1][0]


def memory_s(models: list[FrozenModel]) -> float:
    """How far back the models remember: their slowest lag's time constant (MIN_MEMORY_S at least)."""
    taus = [spec.tau_s for model in models for spec in model.inputs if spec.tau_s is not None]
    return max([MIN_MEMORY_S, *taus])


def span_s(models: list[FrozenModel]) -> float:
    taus = [spec.tau_s for model in models for spec in model.inputs if spec.tau_s is not None]
    return max(MIN_SPAN_S, SPAN_FACTOR * max(taus, default=0.0))


def read(path: str) -> Saved:
    """The state file, strictly; StateFileError for anything but a regular file of the expected form."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except FileNotFoundError:
        raise
    except OSError as error:
        raise StateFileError(f"cannot open it ({error.strerror or error}; a symlink is not followed)") from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise StateFileError("not a regular file")
        if info.st_size > MAX_STATE_BYTES:
            raise StateFileError(f"{info.st_size} bytes, more than the {MAX_STATE_BYTES} a state file can be")
        data = os.read(fd, MAX_STATE_BYTES + 1)
    finally:
        os.close(fd)
    if len(data) > MAX_STATE_BYTES:
        raise StateFileError(f"more than the {MAX_STATE_BYTES} bytes a state file can be")
    return parse(data)


def _constant(name: str) -> None:
    raise StateFileError(f"{name} is not a number a state file holds")


def parse(data: bytes) -> Saved:
    try:
        doc = json.loads(data.decode("utf-8"), parse_constant=_constant)
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as error:
        raise StateFileError(f"not JSON ({printable(str(error))[:80]})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT or doc.get("version") != VERSION:
        raise StateFileError(f"not a {FORMAT} version {VERSION} file")
    device, clock, samples = doc.get("device"), doc.get("clock"), doc.get("samples")
    times, temps = doc.get("t_s"), doc.get("temp_c")
    if not isinstance(device, str) or len(device) > 256 or clock not in ("device", "wall"):
        raise StateFileError("its device or clock is missing or malformed")
    if not isinstance(samples, int) or isinstance(samples, bool) or samples < 0:
        raise StateFileError("its sample count is missing or malformed")
    if not (isinstance(times, list) and isinstance(temps, list) and 1 <= len(times) == len(temps) <= MAX_POINTS):
        raise StateFileError(f"its t_s and temp_c are not two lists of the same length (1 to {MAX_POINTS})")
    low_c, high_c = TEMP_VALID_C
    points: list[tuple[float, float]] = []
    for t_s, temp_c in zip(times, temps):
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in (t_s, temp_c)):
            raise StateFileError("a t_s or temp_c is not a number")
        if not (math.isfinite(t_s) and low_c <= temp_c <= high_c) or (points and t_s <= points[-1][0]):
            raise StateFileError("its times do not rise or a temperature is out of range")
        points.append((float(t_s), float(temp_c)))
    return Saved(device, clock, samples, points)


def write(path: str, history: TempHistory, device: str, clock: str) -> None:
    """The history, atomically: a temporary file in the same directory, fsynced, renamed over `path` (a symlink
    there is replaced, its target never written)."""
    points = thinned(history.points())
    doc = {
        "format": FORMAT, "version": VERSION, "device": device, "clock": clock, "samples": history.samples,
        "saved_unix_s": round(time.time(), 3), "last_t_s": points[-1][0], "last_temp_c": points[-1][1],
        "t_s": [round(t_s, 3) for t_s, _ in points], "temp_c": [round(temp_c, 5) for _, temp_c in points],
    }  # fmt: skip
    text = json.dumps(doc, separators=(",", ":"))
    directory = os.path.dirname(os.path.abspath(path))
    fd, temporary = tempfile.mkstemp(dir=directory, prefix=f".{os.path.basename(path)}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as stream:
            stream.write(text)
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(temporary, path)
    except BaseException:
        try:
            os.unlink(temporary)
        except OSError:
            pass
        raise


@dataclass
class ThermalCounters:
    state_saves: int = 0
    state_save_errors: int = 0


class Thermal:
    """The daemon's thermal past: `start` before the first batch is compensated (restore or cold start),
    `observe` after each batch (history, WARMING, the warming mode), `reloaded` after a model swap, `save`
    every SAVE_EVERY_S and at stop."""

    def __init__(self, models: list[FrozenModel], rate_hz: float, *, path: str | None, device: str,
                 warming: str = MODES[0], tolerance_dph: float = 0.002) -> None:  # fmt: skip
        self.models = models
        self.rate_hz = float(rate_hz)
        self.path = path
        self.device = device
        self.warming_mode = warming
        self.tolerance_dph = tolerance_dph
        self._history = TempHistory(rate_hz, span_s=span_s(models))
        # valid temperatures not yet in the history: added FLUSH_SAMPLES at a time (on a dedicated box a call
        # chain per frame runs cold; a batch runs warm), and before anything reads the history
        self._pending_t_s: list[float] = []
        self._pending_c: list[float] = []
        self.counters = ThermalCounters()
        self.pending = True  # before the first valid temperature: restore or cold start then
        self.clock = ""  # "device" or "wall", from the first sample
        self.offset_s = 0.0  # history time = sample time + offset (the Unix time of count 0 on a wall clock)
        self.bound: WarmingBound | None = None
        self.started = ""  # how this run started, for the status
        self._saving: threading.Thread | None = None

    @property
    def history(self) -> TempHistory:
        """The temperature history, every observed sample in it (read it on the thread that observes, or while
        it is held off: the daemon's `_handing_on`)."""
        self._flush()
        return self._history

    def _flush(self) -> None:
        if self._pending_c:
            self._history.extend(self._pending_t_s, self._pending_c)
            self._pending_t_s, self._pending_c = [], []

    # -- start ------------------------------------------------------------------------------------------------
    def start(self, t_s: float, device_clock: bool, temp_c: float, compensator: ChannelCompensator) -> None:
        """The first valid temperature (`t_s` in sample time) is about to be compensated: prime the compensator
        from the saved history if it is usable, else start cold with the WARMING bound."""
        self.pending = False
        self.clock = "device" if device_clock else "wall"
        self.offset_s = 0.0 if device_clock else time.time() - t_s
        now_s = t_s + self.offset_s
        reason = self._restore(now_s, temp_c)
        if reason is None:
            compensator.prime(self.history)
            return
        log.warning("thermal state: %s; cold start: the inputs assume equilibrium at %.3f C, samples flagged "
                    "WARMING until the assumption's error bound is below %g deg/h",
                    reason, temp_c, self.tolerance_dph)  # fmt: skip
        self.started = "cold"
        self.bound = WarmingBound(self.models[0], self.rate_hz, tolerance_dph=self.tolerance_dph)

    def _restore(self, now_s: float, temp_c: float) -> str | None:
        """None when the saved history was restored and bridged to (now_s, temp_c); else why not."""
        if self.path is None:
            return "no state file configured"
        try:
            saved = read(self.path)
        except FileNotFoundError:
            return f"no state file {printable(self.path)} yet"
        except StateFileError as error:
            return f"state file {printable(self.path)} ignored: {error}"
        except OSError as error:
            return f"state file {printable(self.path)} unreadable ({error.strerror or error})"
        if saved.device != self.device:
            return (f"state file {printable(self.path)} is of another device ({printable(saved.device)[:80]}, "
                    f"not {printable(self.device)})")  # fmt: skip
        if saved.clock != self.clock:
            return f"state file {printable(self.path)} is on the {saved.clock} clock, this run on the {self.clock} clock"
        gap_s = now_s - saved.last_t_s
        memory = memory_s(self.models)
        if not 0 < gap_s <= memory:
            what = "before the saved history ends (a device clock reset?)" if gap_s <= 0 else "too old"
            return (f"state file {printable(self.path)}: its newest sample is {gap_s:.1f} s before the first new one, "
                    f"{what}; the model remembers {memory:g} s")  # fmt: skip
        self.history.restore(saved.points, saved.samples)
        self.history.bridge(now_s, temp_c)
        self.started = f"restored (gap {gap_s:.1f} s)"
        log.warning("thermal state: restored %d points (%.0f s) from %s; a gap of %.1f s bridged by a straight line "
                    "from %.3f C to %.3f C", len(saved.points), saved.last_t_s - saved.points[0][0],
                    printable(self.path), gap_s, saved.points[-1][1], temp_c)  # fmt: skip
        return None

    # -- each batch -------------------------------------------------------------------------------------------
    def observe(self, times_s: list[float], comp: Any, comps: dict[str, Any] | None) -> int:
        """After a batch: its valid temperatures into the history, and while warming the WARMING flag and the
        warming mode on every channel's samples (`comp`: the first channel's columns, `comps` every channel's).
        Returns how many samples are WARMING."""
        offset_s, bound = self.offset_s, self.bound
        add_t_s, add_c = self._pending_t_s.append, self._pending_c.append
        temps, flags = comp.temp_c, comp.flags
        warming: list[tuple[int, float | None]] = []
        fallback = self.warming_mode == "fallback"
        flag_only = comps is None and self.warming_mode == "compensate"  # apply_mode's whole work: the flag
        count = 0
        for index, t_s in enumerate(times_s):
            temp_c = temps[index]
            valid = not int(flags[index]) & _TEMP_INVALID and temp_c == temp_c
            if valid:
                add_t_s(t_s + offset_s)
                add_c(temp_c)
            if bound is not None and bound.update(t_s + offset_s, temp_c if valid else None):
                count += 1
                if flag_only:
                    flags[index] = int(flags[index]) | _WARMING
                else:
                    warming.append((index, bound.fallback_dph() if fallback else None))
        if len(self._pending_c) >= FLUSH_SAMPLES:
            self._flush()
        if bound is not None and not bound.active:
            log.warning("thermal state: WARMING cleared after %d samples (bound %.2g deg/h; start rate %+.2g "
                        "+- %.2g C/s)", bound.samples, bound.bound_dph, bound.start_rate_cps, bound.rate_margin_cps)  # fmt: skip
            self.bound = None
        if warming:  # (every channel's columns, the first channel's first: the one the bound was computed for)
            apply_mode([comp] if comps is None else list(comps.values()), warming, self.warming_mode)
        return count

    # -- reload -----------------------------------------------------------------------------------------------
    def reloaded(self, models: list[FrozenModel], compensator: ChannelCompensator, *, prime: bool) -> str:
        """A new model: its compensator primed from the history when its inputs differ (`prime`), and the WARMING
        bound of the new model over the same start while it lasts; what was done, for the log."""
        self.models = models
        if self.bound is not None:
            self.bound = self.bound.for_model(models[0], self.history)
        if not prime:
            return "kept (same inputs)"
        if self.history.last is None:
            return "reset (inputs differ; no temperature yet)"
        compensator.prime(self.history)
        points = self.history.points()
        return f"new inputs primed from {len(points)} points of history ({points[-1][0] - points[0][0]:.0f} s)"

    # -- persistence ------------------------------------------------------------------------------------------
    def save(self, *, wait: bool = False) -> None:
        """Write the state file (on a helper thread unless `wait`; one write at a time)."""
        if self.path is None or self.history.last is None:
            return
        if self._saving is not None and self._saving.is_alive():
            if not wait:
                return
            self._saving.join()
        snapshot = TempHistory(self.rate_hz, span_s=self.history.span_s)
        snapshot.restore(self.history.points(), self.history.samples)
        if wait:
            self._write(snapshot)
        else:
            self._saving = threading.Thread(target=self._write, args=(snapshot,), name="fogd-state", daemon=True)
            self._saving.start()

    def _write(self, snapshot: TempHistory) -> None:
        try:
            write(self.path, snapshot, self.device, self.clock)
            self.counters.state_saves += 1
        except OSError as error:
            self.counters.state_save_errors += 1
            if self.counters.state_save_errors == 1:
                log.warning("thermal state: cannot write %s (%s); a restart will start cold", printable(self.path),
                            error.strerror or error)  # fmt: skip

    def status(self) -> dict:
        bound = self.bound
        return {
            "started": self.started, "warming": bound is not None, "warming_mode": self.warming_mode,
            "bound_dph": None if bound is None or math.isinf(bound.bound_dph) else bound.bound_dph,
            "history_points": len(self._history), "state_file": self.path, **vars(self.counters),
        }  # fmt: skip
