"""`fogd --demo`: no hardware. A navigation-grade gyro is simulated in a thermal chamber run sped up
`DEMO_SPEED` times and streamed by the emulator onto a pty in this process; fogd recognises its protocol,
compensates it with the bundled model, and shows what compensation does: the gyro's drift (the mean of its
rate over the last 100 s of its own time, less the mean of its first 100 s) as read and as compensated, side
by side. On a terminal that is one line rewritten in place, which log records clear before they are written
(they never share its line); off a terminal, a plain line every `LINE_EVERY_S`. Ctrl-C (or --duration-s) ends
with a short summary; the counters' JSON only with -v.
"""

from __future__ import annotations

import logging
import math
import os
import shutil
import sys
import threading
from collections import deque
from pathlib import Path
from typing import Any, TextIO

from fogd.simulation.profiles import HOUR_S, Profile

MODEL = Path(__file__).resolve().parent.parent / "data" / "demo-model.json"
# The chamber ramps 0 -> 30 C and back. The demo starts with the ramp, from a gyro soaked at 0 C: what fogd
# assumes of a gyro it starts on (a start in mid-ramp has the model's thermal state wrong until its lags settle,
# a quarter of an hour of the gyro's time, which is not what a first look should show).
PROFILE = Profile("demo-cycle", ((0.0, 0.0), (2.0 * HOUR_S, 30.0), (0.5 * HOUR_S, 30.0), (2.0 * HOUR_S, 0.0)))
START_S = 0.0
RATE_HZ = 10.0  # the gyro's samples per second of its own time (the model was trained at this rate)
SPEED = 120.0  # two chamber hours a minute: the whole run in 2 min 15 s, 100 s of the gyro's time in 0.8 s
NOISE = "navigation"  # a gyro whose 100 s means show its thermal drift 30-100x above their noise
PROTOCOL = "fogd"  # fogd frames carry the sensor's 0.0625 C temperature (a KVH's whole degrees: --protocol kvh-a)
WINDOW_S = 100.0
LINE_EVERY_S = 5.0  # off a terminal: a plain line this often instead of the live line
LEGEND = (
    "drift = the gyro's rate averaged over the last 100 s of its time, less its average over the first 100 s "
    "(deg/h): raw as read, compensated as fogd writes it; T = the gyro's temperature sensor (C); "
    "chamber = hours:minutes into the chamber run"
)


class DriftMeans:
    """The raw and compensated rates of one axis averaged over the last `window_s` of the gyro's time, from
    the batches the daemon's loop encodes (1 s bins); the live line and the summary read them."""

    def __init__(self, axis: int, window_s: float = WINDOW_S, bin_s: float = 1.0) -> None:
        self.axis, self.bin_s = axis, bin_s
        self.window_bins = round(window_s / bin_s)
        self._bins: deque[list[float]] = deque()  # [bin index, samples, raw sum, compensated sum]
        self._lock = threading.Lock()
        self.first: tuple[float, float] | None = None  # the first full window's (raw, compensated) means
        self.blocks: list[tuple[float, float]] = []  # each full, non-overlapping window's drifts, for the summary
        self._next_block = 0
        self.t_s = 0.0

    def add(self, t_s, raw_dph, comp_dph) -> None:
        with self._lock:
            bins = self._bins
            for t, raw, comp in zip(t_s, raw_dph, comp_dph):
                if not (math.isfinite(raw) and math.isfinite(comp)):
                    continue
                index = int(t // self.bin_s)
                if not bins or bins[-1][0] != index:
                    bins.append([index, 0, 0.0, 0.0])
                    self._closed(index)
                last = bins[-1]
                last[1] += 1
                last[2] += raw
                last[3] += comp
                self.t_s = t

    def _closed(self, index: int) -> None:
        """Bin `index` begins, so those before it are complete: keep a window of them; when it is full, note the
        first window, and every `window_bins` a block."""
        bins = self._bins
        while bins[0][0] < index - self.window_bins:
            bins.popleft()
        if bins[0][0] != index - self.window_bins or index < self._next_block:
            return
        raw, comp = self._means(list(bins)[:-1])
        if self.first is None:
            self.first = (raw, comp)
        self.blocks.append((raw - self.first[0], comp - self.first[1]))
        self._next_block = index + self.window_bins

    @staticmethod
    def _means(bins) -> tuple[float, float]:
        samples = sum(b[1] for b in bins)
        return sum(b[2] for b in bins) / samples, sum(b[3] for b in bins) / samples

    def drift(self) -> tuple[float, float] | None:
        """The last window's (raw, compensated) means less the first window's; None until a window is full."""
        with self._lock:
            if self.first is None or not self._bins:
                return None
            raw, comp = self._means(self._bins)
            return raw - self.first[0], comp - self.first[1]


class Tap:
    """The daemon's formatter, noting each batch's raw and compensated rates in `means` before encoding it
    (on the loop's thread: a few sums per batch)."""

    def __init__(self, formatter, means: DriftMeans) -> None:
        self._formatter, self._means = formatter, means

    def __getattr__(self, name: str):
        return getattr(self._formatter, name)

    def encode(self, batch):
        axis, frames = self._means.axis, batch.frames
        raw = [frames[row].rate_dph[axis] for row in batch.rate_rows]
        self._means.add(batch.t_s, raw, batch.comp.rate_comp_dph)
        return self._formatter.encode(batch)


class LiveLine:
    """One line rewritten in place at the bottom of a terminal. It is also the stream log records are written
    to: a record clears the line first and the line is drawn again after it, so the two never share a line."""

    def __init__(self, out: TextIO) -> None:
        self.out = out
        self.text = ""
        self._shown = False
        self._lock = threading.RLock()

    def show(self, text: str) -> None:
        width = shutil.get_terminal_size((100, 24)).columns - 1  # a wrapped line could not be rewritten
        with self._lock:
            self.text = text[:width]
            self.out.write(f"\r{self.text}\x1b[K")
            self.out.flush()
            self._shown = True

    def write(self, data: str) -> int:
        with self._lock:
            if self._shown:
                self.out.write("\r\x1b[K")
                self._shown = False
            return self.out.write(data)

    def flush(self) -> None:
        with self._lock:
            if not self._shown and self.text:  # after a record: the line again, below it
                self.out.write(self.text)
                self._shown = True
            self.out.flush()

    def end(self) -> None:
        """Leave the last line as it is and move below it."""
        with self._lock:
            if self._shown:
                self.out.write("\n")
                self._shown = False
            self.text = ""
            self.out.flush()


def status_text(daemon, means: DriftMeans) -> str:
    latest, lexer = daemon.latest, daemon.reader.lexer.counters
    drops = lexer.bad_crc + lexer.truncated + lexer.bad_line + daemon.ring.overruns
    drift = means.drift()
    if drift is None:
        shown = f"drift: measuring the first {WINDOW_S:g} s ({min(means.t_s, WINDOW_S):3.0f} s)"
    else:
        shown = f"drift raw {drift[0]:+.4f}  compensated {drift[1]:+.4f} deg/h"
    minutes = int((START_S + means.t_s) // 60)
    return f"{shown} | T {latest.temp_c:5.2f} C | chamber {minutes // 60}:{minutes % 60:02d} | frames {lexer.frames_ok} drops {drops}"


def summary(daemon, means: DriftMeans, wall_s: float) -> str:
    """A few lines for a person: how long, the drift's spread raw and compensated, frames and drops."""
    lexer = daemon.reader.lexer.counters
    drops = lexer.bad_crc + lexer.truncated + lexer.bad_line + daemon.ring.overruns
    head = f"fogd demo: {_hours(means.t_s)} of the gyro's time in {_hours(wall_s)}"
    blocks = means.blocks
    if len(blocks) < 2:
        lines = [head, f"  too short to compare drifts: run it for at least {2 * WINDOW_S / SPEED + 1:.0f} s"]
    else:
        raw = [block[0] for block in blocks]
        comp = [block[1] for block in blocks]
        raw_spread, comp_spread = max(raw) - min(raw), max(comp) - min(comp)
        less = f": {100 * (1 - comp_spread / raw_spread):.0f} % less" if raw_spread > 0 else ""
        lines = [f"{head}; drift over {len(blocks)} blocks of {WINDOW_S:g} s:",
                 f"  raw          {min(raw):+.4f} .. {max(raw):+.4f} deg/h (spread {raw_spread:.4f})",
                 f"  compensated  {min(comp):+.4f} .. {max(comp):+.4f} deg/h (spread {comp_spread:.4f}){less}"]  # fmt: skip
    lines.append(f"  frames {lexer.frames_ok}, drops {drops}")
    return "\n".join(lines)


def _hours(seconds: float) -> str:
    seconds = max(0.0, seconds)
    if seconds < 60:
        return f"{seconds:.0f} s"
    minutes = int(seconds // 60)
    return f"{minutes // 60} h {minutes % 60:02d} min" if minutes >= 60 else f"{minutes} min {int(seconds % 60):02d} s"


class Later:
    """A source of samples (fogd.simulation.emulator's SimSource) from `start_s` on, its time starting at 0 there."""

    def __init__(self, source, start_s: float) -> None:
        self.source = source
        self.first = int(round(start_s * source.rate_hz))
        self.rate_hz = source.rate_hz
        self.rows = source.rows - self.first

    def columns(self, start: int, stop: int):
        t_s, rate_dph, temp_c = self.source.columns(start + self.first, stop + self.first)
        return t_s - self.first / self.rate_hz, rate_dph, temp_c


def run(settings: dict[str, Any], protocol, model, serve, *, out_given: bool, verbose: bool) -> int:
    """The demo: the emulator on a pty in this process, `serve` (fogd.cli.daemon's) reading it."""
    import time

    from fogd.simulation.emulator import Emulator, SimSource
    from fogd.simulation.simulator import params_for

    sent = protocol.name if protocol is not None else PROTOCOL  # auto: fogd recognises what it is sent
    source = Later(SimSource(PROFILE, RATE_HZ, seed=1, params=params_for(NOISE)), START_S)
    emulator = Emulator(source, sent, speed=SPEED, wait_reader=True, drain_timeout_s=0.0)
    path = emulator.start()
    terminal = sys.stderr.isatty()
    live = LiveLine(sys.stderr) if terminal else None
    if live is not None:  # log records go through the live line, which clears itself for them
        for handler in logging.getLogger().handlers:
            if isinstance(handler, logging.StreamHandler) and handler.stream is sys.stderr:
                handler.setStream(live)
    if not verbose:  # the live line says what the status log would; the counters' JSON only with -v
        logging.getLogger("fogd.status").setLevel(logging.WARNING)
    print(f"fogd demo: a simulated {NOISE}-grade FOG on {path} in a chamber going 0 -> 30 C in 2 h, 30 min at 30 C, "
          f"back to 0 C in 2 h ({SPEED:g}x real time, {RATE_HZ:g} Hz, {sent} frames); "
          f"model {model.name}; Ctrl-C to stop\n{LEGEND}", file=live or sys.stderr, flush=True)  # fmt: skip
    settings = {**settings, "port": path, "rate_hz": RATE_HZ, "out": settings["out"] if out_given else os.devnull}
    means = DriftMeans(axis=2 if settings["axis"] == "z" else "xyz".index(settings["axis"]))
    finished = threading.Event()
    holder: dict[str, Any] = {}
    started_s = time.monotonic()

    def show(daemon) -> None:
        while not finished.wait(1.0 if terminal else LINE_EVERY_S):
            text = status_text(daemon, means)
            if live is not None:
                live.show(text)
            else:
                print(text, file=sys.stderr, flush=True)

    def on_daemon(daemon) -> None:
        daemon.formatter = Tap(daemon.formatter, means)
        holder["daemon"] = daemon
        threading.Thread(target=show, args=(daemon,), name="fogd-demo-status", daemon=True).start()

    try:
        status = serve(settings, protocol, model, on_daemon=on_daemon)
    finally:
        finished.set()
        if live is not None:
            live.end()
        emulator.stop()
        emulator.join(1.0)
    if "daemon" in holder:
        print(summary(holder["daemon"], means, time.monotonic() - started_s), file=sys.stderr, flush=True)
    return status
