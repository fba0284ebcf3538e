"""The temperature history the daemon keeps, and the model input state it primes (issue 34).

Every input a model has (lags, play, eq. 16 windows, a dequantiser) is a function of the temperature history
alone. `TempHistory` keeps that history compactly: the mean of each `step_s` block of valid temperatures (1 s
by default) over `span_s` (five times the longest lag by default), and the last `tail_s` of raw samples. `prime`
then sets any `InputBank` to the state a run through that history leaves, whatever inputs its model has, so a
reload to a model with other inputs, or a restart that found its history on disk, goes on from the first sample
as `fogd-replay` of the whole run would.

How: the history read as a piecewise-linear temperature through its block means (and the raw tail, exact);
a first-order lag fed a linear ramp has a closed form (`lag_after`, exact for the discrete filter of
fogd.core.lag at the model's rate), so the lags cross hours of history in one step per block; the play operator
of a piecewise-linear input depends only on its vertices; eq. 16 windows, dequantisers and the last stretch of
every input are fed the full-rate samples (the raw tail where there is one, else the line through the blocks).
An undithered input (fogd.core.undither) reads the block means as what they are, means of the readings: its
lag is primed like any lag and the earlier history is taken through its inverse.
The cost of decimation is the lag of a block's deviation from that line: tests/test_history.py measures it.
A gap (a restart) is bridged the same way: the line from the last saved reading to the first new one (`bridge`).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable

import numpy as np

from fogd.core.dequantise import Dequantiser
from fogd.core.estimator import TempRateEstimator
from fogd.core.inputs import InputBank, InputSpec
from fogd.core.lag import LagFilter
from fogd.core.play import LaggedPlay, PlayFilter
from fogd.core.undither import Undither

STEP_S = 1.0
SPAN_FACTOR = 5.0  # the history covers this many of the longest lag's time constants (e^-5: 0.7 % remains)
MIN_SPAN_S = 15000.0  # five times fogd-train's default bank's longest lag (3,000 s), whatever the model loaded
TAIL_S = 300.0  # raw samples kept: eq. 16 windows up to this long are primed exactly
MAX_TAIL_SAMPLES = 100_000
RECENT_S = 600.0  # the last stretch a dequantiser (and every input with it) is fed at full rate when primed
MAX_RECENT_SAMPLES = 200_000
THIN_AFTER_S = 3600.0  # what the state file keeps of the history older than this: every THIN_EVERY-th point
THIN_EVERY = 10
FEED_CHUNK = 4096  # fogd.core.lag.PYTHON_CHUNK: priming never maps scipy


def lag_after(error_c: float, step_c: float, tau_s: float, rate_hz: float, steps: float) -> float:
    """x - y of the lag (fogd.core.lag) after `steps` samples of a temperature rising by `step_c` a sample,
    from x - y = `error_c`: e_k = q^k e_0 + s q (1 - q^k) / (1 - q), q = exp(-1 / (tau f)). Exact for whole
    `steps` (the discrete filter's own recurrence e_n = q (e_{n-1} + s)); the same curve in between."""
    per_sample = 1.0 / (tau_s * rate_hz)
    keep = math.exp(-per_sample)
    decay = math.exp(-per_sample * steps)
    return decay * error_c + step_c * keep * -math.expm1(-per_sample * steps) / -math.expm1(-per_sample)


def lag_through(points: list[tuple[float, float]], tau_s: float, rate_hz: float) -> float:
    """The lag's value at the last of `points` ((t_s, temp_c), times rising), fed the line through them at
    `rate_hz`, starting in steady state at the first (as fogd.core.lag starts)."""
    return lag_at_points(points, tau_s, rate_hz)[-1]


def lag_at_points(points: list[tuple[float, float]], tau_s: float, rate_hz: float) -> list[float]:
    """`lag_through`'s value at each of `points` in turn."""
    error_c = 0.0
    values = [points[0][1]]
    for (t0_s, x0_c), (t1_s, x1_c) in zip(points, points[1:]):
        steps = (t1_s - t0_s) * rate_hz
        if steps > 0:
            error_c = lag_after(error_c, (x1_c - x0_c) / steps, tau_s, rate_hz, steps)
        values.append(x1_c - error_c)
    return values


def ramp_points(t_s: float, temp_c: float, rate_cps: float, span_s: float) -> list[tuple[float, float]]:
    """A history that ends at (t_s, temp_c) after rising at `rate_cps` for `span_s`: the past the warming bound
    assumes (fogd.core.warming)."""
    return [(t_s - span_s, temp_c - rate_cps * span_s), (t_s, temp_c)]


def thinned(points: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """What the state file keeps: every THIN_EVERY-th point older than THIN_AFTER_S (history that old matters
    only to lags of a thousand seconds and more, which a 10 s line serves as well), the rest as they are; a third
    of the bytes of the full history."""
    if not points:
        return points
    cut_s = points[-1][0] - THIN_AFTER_S
    old = [point for point in points[:-1] if point[0] < cut_s]
    return old[::-THIN_EVERY][::-1] + points[len(old) :] if old else points


class TempHistory:
    """The decimated temperature history: block means of valid temperatures and the raw tail, in sample time
    (the device's clock where the protocol has one, else the caller's)."""

    def __init__(self, rate_hz: float, *, span_s: float = MIN_SPAN_S, step_s: float = STEP_S,
                 tail_s: float = TAIL_S) -> None:  # fmt: skip
        self.rate_hz = float(rate_hz)
        self.span_s = float(span_s)
        self.step_s = float(step_s)
        self.blocks: deque[tuple[float, float]] = deque(maxlen=int(self.span_s / self.step_s) + 2)
        self.tail: deque[float] = deque(maxlen=max(1, min(MAX_TAIL_SAMPLES, int(tail_s * rate_hz))))
        self.last: tuple[float, float] | None = None  # the newest sample (t_s, temp_c)
        self.first: tuple[float, float] | None = None  # the first sample, while its block is kept: where a run starts
        self._block = -1  # the current block's index (floor(t / step))
        self._sum_t = self._sum_c = 0.0
        self._count = 0
        self.samples = 0  # samples added since the history began (for the banks' warm-up count)

    def __len__(self) -> int:
        return len(self.blocks) + (1 if self._count else 0)

    def add(self, t_s: float, temp_c: float) -> None:
        """One valid temperature at sample time `t_s` (rising)."""
        self.extend((t_s,), (temp_c,))

    def extend(self, times_s: Iterable[float], temps_c: Iterable[float]) -> None:
        """Valid temperatures at sample times `times_s` (rising), in order (the daemon adds a few hundred at a
        time: one loop here, not a call per sample)."""
        step_s, append = self.step_s, self.tail.append
        starting = self.last is None and not self.blocks
        block, sum_t, sum_c, count, added = self._block, self._sum_t, self._sum_c, self._count, 0
        for t_s, temp_c in zip(times_s, temps_c):
            index = math.floor(t_s / step_s)
            if index != block:
                self._sum_t, self._sum_c, self._count = sum_t, sum_c, count
                self._close()
                block, sum_t, sum_c, count = index, 0.0, 0.0, 0
            sum_t += t_s
            sum_c += temp_c
            count += 1
            append(temp_c)
            if starting:
                self.first, starting = (t_s, temp_c), False
            added += 1
        self._block, self._sum_t, self._sum_c, self._count = block, sum_t, sum_c, count
        if added:
            self.last = (t_s, temp_c)
            self.samples += added

    def _close(self) -> None:
        if self._count:
            if len(self.blocks) == self.blocks.maxlen:
                self.first = None  # the run's start has left the history
            self.blocks.append((self._sum_t / self._count, self._sum_c / self._count))
        self._sum_t = self._sum_c = 0.0
        self._count = 0

    def points(self) -> list[tuple[float, float]]:
        """The first sample (while the history holds the run's start: the lags start in steady state there, as
        fogd.core.lag's do), the block means (the current block's so far) and the newest sample: the line the
        history is read as, oldest first."""
        out = ([self.first] if self.first is not None else []) + list(self.blocks)
        if self._count:
            out.append((self._sum_t / self._count, self._sum_c / self._count))
        if self.last is not None and (not out or self.last[0] > out[-1][0]):
            out.append(self.last)
        return out

    def restore(self, points: list[tuple[float, float]], samples: int) -> None:
        """Start from saved points (fogd.serving.thermalstate): the blocks, then the newest sample; no raw tail."""
        self.blocks.clear()
        self.blocks.extend(points[:-1])
        self.first = None
        self.tail.clear()
        self._block, self._count = -1, 0
        self._sum_t = self._sum_c = 0.0
        self.last = points[-1]
        self.samples = samples

    def bridge(self, t_s: float, temp_c: float) -> float:
        """Before the first sample after a gap: the line from the newest sample to (t_s, temp_c), as far as the
        sample before it (whose state `prime` then gives). Returns the gap in s."""
        assert self.last is not None
        last_t_s, last_c = self.last
        gap_s = t_s - last_t_s
        before_s = t_s - 1.0 / self.rate_hz
        if before_s > last_t_s:
            self._close()
            self.blocks.append(self.last)
            self.last = (before_s, last_c + (temp_c - last_c) * (before_s - last_t_s) / gap_s)
            self.tail.clear()
        return gap_s

    def recent(self, count: int) -> list[float]:
        """The last `count` samples at the history's rate: raw where the tail has them, else read off the line
        through the points."""
        count = max(1, count)
        tail = list(self.tail)[-count:]
        missing = count - len(tail)
        if missing <= 0:
            return tail
        points = self.points()
        times = np.array([t for t, _ in points])
        temps = np.array([c for _, c in points])
        end_s = self.last[0] - len(tail) / self.rate_hz  # the sample before the tail's first
        grid = end_s - np.arange(missing - 1, -1, -1) / self.rate_hz
        return np.interp(grid, times, temps).tolist() + tail

    def prime(self, bank: InputBank) -> None:
        """Set `bank` to the state the history leaves: every input as if it had been fed the whole history."""
        if self.last is None:
            return
        bank.reset()
        needs = [_needs(spec, self.rate_hz) for spec in bank.specs]
        count = min(max(needs + [len(self.tail), 2]), MAX_RECENT_SAMPLES)
        recent = self.recent(count)
        start_s = self.last[0] - (len(recent) - 1) / self.rate_hz
        before = [point for point in self.points() if point[0] < start_s] + [(start_s, recent[0])]
        sources, earlier = {None: recent}, {None: before}
        for key, source in bank.sources.items():
            if isinstance(source, Undither):
                sources[key] = _prime_undither(source, before, recent, self.rate_hz)
                lagged = lag_at_points(before, source.tau_s, self.rate_hz)  # its own average at each point
                earlier[key] = [(t_s, source.invert_one(mean_c)) for (t_s, _), mean_c in zip(before[:-1], lagged)]
                earlier[key].append((start_s, sources[key][0]))
            else:  # (a dequantised source's earlier history: the block means, which its estimate tracks)
                sources[key], earlier[key] = _prime_dequantiser(source, key[1], recent), before
        for spec, part in zip(bank.specs, bank.parts):
            full, points = sources[spec.source], earlier[spec.source]
            if isinstance(part, LagFilter):
                part.set_value(lag_through(points, part.tau_s, self.rate_hz))
                _feed(part, full[1:])
            elif isinstance(part, LaggedPlay):  # the play of the lag at each point (a lag of a line is smooth)
                part.reset()
                lagged = lag_at_points(points, part.lag.tau_s, self.rate_hz)
                for temp_c in lagged:
                    part.play.update_one(temp_c)
                part.lag.set_value(lagged[-1])
                _feed(part, full[1:])
            elif isinstance(part, PlayFilter):
                part.reset()
                for _, temp_c in points:
                    part.update_one(temp_c)
                _feed(part, full[1:])
            elif isinstance(part, TempRateEstimator):
                part.reset()
                _feed(part, full)
        bank.count = max(bank.warmup, self.samples)


def _needs(spec: InputSpec, rate_hz: float) -> int:
    """Samples an input must be fed at full rate to be primed: an eq. 16 window (with its step); a dequantised
    input the last RECENT_S (its dequantiser's state); the others one."""
    if spec.estimator is not None:
        window, _, step = spec.estimator.samples(rate_hz)
        return window + step + 1
    if spec.dequantise_c is not None:
        return int(RECENT_S * rate_hz)
    return 1


def _prime_dequantiser(dequantiser: Dequantiser, resolution_c: float, recent: list[float]) -> list[float]:
    """The dequantiser run over `recent` as its sensor would have read it (rounded to its resolution: the block
    means are not a staircase); its estimates."""
    dequantiser.reset()
    readings = [round(value / resolution_c) * resolution_c for value in recent]
    out: list[float] = []
    for start in range(0, len(readings), FEED_CHUNK):
        out.extend(dequantiser.update(np.array(readings[start : start + FEED_CHUNK])).tolist())
    return out


def _prime_undither(undither: Undither, before: list[tuple[float, float]], recent: list[float],
                    rate_hz: float) -> list[float]:  # fmt: skip
    """The undither's lag primed through the history before `recent` (the block means are means of the readings,
    what its lag estimates), then run over `recent`; its estimates."""
    undither.reset()
    lagged_c = lag_through(before, undither.tau_s, rate_hz)
    undither.lag.set_value(lagged_c)
    out = [undither.invert_one(lagged_c)]
    for start in range(1, len(recent), FEED_CHUNK):
        out.extend(undither.update(np.array(recent[start : start + FEED_CHUNK], dtype=np.float64)).tolist())
    return out


def _feed(part: LagFilter | PlayFilter | LaggedPlay | TempRateEstimator, values: list[float]) -> None:
    for start in range(0, len(values), FEED_CHUNK):
        part.update(np.array(values[start : start + FEED_CHUNK], dtype=np.float64))
