"""The WARMING flag: how far a cold start's equilibrium assumption can be from the truth, sample by sample.

With no usable history (fogd.core.history) the inputs start in equilibrium at the first reading: every lag at
that temperature, the play at rest. That is right for a gyro switched on after hours off and wrong by up to
`rate x tau` on each lag for one switched on mid-ramp. `WarmingBound` measures the error the assumption can
cost: after a probe of the first `probe_s` of valid temperatures it estimates the temperature rate at start
(a least-squares slope) and its standard error, and runs the model on two more input banks whose past was a
steady ramp at that rate plus and minus three standard errors (fogd.core.history.ramp_points), fed the same
samples as the one the compensator runs. The bound is the largest difference of their compensations from the
assumed one; a sample is WARMING while it exceeds `tolerance_dph` (and throughout the probe). The differences
decay as the lags forget their start, fast at equilibrium (the rate's error alone) and slowly mid-ramp, so the
flag clears on the measured decay, not a fixed hour; once it has cleared it stays clear.
"""

from __future__ import annotations

import math
from dataclasses import fields

import numpy as np

from fogd.core.compensator import Compensated, Compensator, temperature_valid
from fogd.core.flags import Flag
from fogd.core.frozen import FrozenModel
from fogd.core.history import MIN_SPAN_S, SPAN_FACTOR, TempHistory, ramp_points, thinned
from fogd.core.inputs import InputBank

PROBE_S = 300.0
SIGMAS = 3.0
TOLERANCE_DPH = 0.002
CHECKS_HZ = 10.0  # how often the bound is evaluated (each sample between holds the last verdict)
MODES = ("compensate", "fallback", "pass")
_WARMING, _RATE_INVALID = int(Flag.WARMING), int(Flag.RATE_INVALID)


class WarmingBound:
    """Feed it each sample's temperature (NaN or None where there is none yet); `warming` says whether the
    sample's inputs rest on the equilibrium assumption beyond the tolerance."""

    def __init__(self, model: FrozenModel, rate_hz: float, *, tolerance_dph: float = TOLERANCE_DPH,
                 probe_s: float = PROBE_S) -> None:  # fmt: skip
        self.model = model
        self.rate_hz = float(rate_hz)
        self.tolerance_dph = float(tolerance_dph)
        self.probe_s = float(probe_s)
        self.active = True  # False once cleared, for good
        self.bound_dph = math.inf
        self.start_rate_cps = math.nan
        self.rate_margin_cps = math.nan
        self.samples = 0  # samples seen while active
        self._probe = TempHistory(rate_hz, span_s=2 * self.probe_s, tail_s=0.0)  # its block means: O(1) a sample
        self._assumed = InputBank(model.inputs, rate_hz)  # what the compensator runs: equilibrium at the first
        self._banks: list[InputBank] = []  # the ramp scenarios, once the probe is full
        self._row: tuple[float, ...] | None = None  # the assumed inputs of the newest sample fed to the banks
        self._rows: list[tuple[float, ...]] = []  # the scenario banks' inputs of that sample
        self._every = max(1, int(round(self.rate_hz / CHECKS_HZ)))
        self._warming = True
        # Valid samples not yet fed to the probe and the banks: they are fed a check's worth at a time, in one
        # InputBank.update (the same floats as one update_one each), not a Python call chain per sample.
        self._pending_t_s: list[float] = []
        self._pending_c: list[float] = []
        self._t0_s: float | None = None

    @property
    def row(self) -> tuple[float, ...] | None:
        """The assumed inputs of the newest sample (None before the first temperature)."""
        self._feed()
        return self._row

    def update(self, t_s: float, temp_c: float | None) -> bool:
        """One sample (sample time `t_s`, its valid temperature or None); True while it is WARMING."""
        if not self.active:
            return False
        if temp_c is None or temp_c != temp_c:
            if self._t0_s is None:  # before the first temperature: WARMUP's, not an assumption yet
                return False
            self.samples += 1
            return True
        self.samples += 1
        if self._t0_s is None:
            self._t0_s = t_s
        self._pending_t_s.append(t_s)
        self._pending_c.append(temp_c)
        if not self._banks:
            if t_s - self._t0_s >= self.probe_s:
                self._feed()
                self._start()
            elif len(self._pending_c) >= self._every:
                self._feed()
            return True
        if self.samples % self._every == 0:
            self._feed()
            predict = self.model.predict_one
            assumed = predict(self._row)[0]
            self.bound_dph = max(abs(predict(row)[0] - assumed) for row in self._rows)
            self._warming = self.bound_dph > self.tolerance_dph
            if not self._warming:
                self.active = False
                self._banks = []
        return self._warming

    def _feed(self) -> None:
        """The pending samples into the probe (while it fills) and every bank; the newest rows kept."""
        temps = self._pending_c
        if not temps:
            return
        if self._probe is not None:
            self._probe.extend(self._pending_t_s, temps)
        chunk = np.array(temps, dtype=np.float64)
        self._row = tuple(self._assumed.update(chunk)[-1].tolist())
        self._rows = [tuple(bank.update(chunk)[-1].tolist()) for bank in self._banks]
        self._pending_t_s, self._pending_c = [], []

    def fallback_dph(self) -> float | None:
        """The model's domain-guard fallback at the newest assumed inputs (None: it has no guard)."""
        guard = self.model.meta.get("domain_guard")
        row = self.row
        return None if guard is None or row is None else guard.fallback.predict_one(row)[0]

    def for_model(self, model: FrozenModel, history: TempHistory) -> WarmingBound:
        """The bound of another model (a reload while warming) over the same start: fed the history since it."""
        bound = WarmingBound(model, self.rate_hz, tolerance_dph=self.tolerance_dph, probe_s=self.probe_s)
        temps = history.recent(min(history.samples, int(history.span_s * self.rate_hz)))
        end_s = history.last[0] if history.last is not None else 0.0
        for index, temp_c in enumerate(temps):
            bound.update(end_s - (len(temps) - 1 - index) / self.rate_hz, temp_c)
        return bound

    def _start(self) -> None:
        """The probe is full: the start rate and its margin from its block means, and the scenario banks, primed
        with a ramp up to the first sample and the probe's block means after it (their difference from the
        samples themselves is far below the tolerance, and gone once the banks have been fed the same samples
        for a while)."""
        probe = self._probe
        means = probe.points()[1:-1] or probe.points()
        self.start_rate_cps, stderr_cps = _slope([t for t, _ in means], [c for _, c in means])
        self.rate_margin_cps = SIGMAS * stderr_cps
        t0_s, temp0_c = probe.first
        span_s = max(MIN_SPAN_S, SPAN_FACTOR * max((spec.tau_s or 0.0 for spec in self.model.inputs), default=0.0))
        before_s = 1.0 / self.rate_hz
        for rate_cps in (self.start_rate_cps - self.rate_margin_cps, self.start_rate_cps + self.rate_margin_cps):
            history = TempHistory(self.rate_hz, span_s=span_s)  # a past that was a steady ramp, to the first sample
            ramp = ramp_points(t0_s - before_s, temp0_c - rate_cps * before_s, rate_cps, span_s)
            history.restore(ramp + probe.points(), probe.samples)
            bank = InputBank(self.model.inputs, self.rate_hz)
            history.prime(bank)
            self._banks.append(bank)
        self._probe = None


def _slope(times: list[float], temps: list[float]) -> tuple[float, float]:
    """Least-squares slope of temps on times and its standard error (0 and 0 for fewer than 3 samples)."""
    n = len(times)
    if n < 3:
        return 0.0, 0.0
    mean_t, mean_c = sum(times) / n, sum(temps) / n
    sxx = sum((t - mean_t) ** 2 for t in times)
    if sxx <= 0:
        return 0.0, 0.0
    slope = sum((t - mean_t) * (c - mean_c) for t, c in zip(times, temps)) / sxx
    residual = sum((c - mean_c - slope * (t - mean_t)) ** 2 for t, c in zip(times, temps))
    return slope, math.sqrt(residual / (n - 2) / sxx)


def apply_mode(columns: list, warming: list[tuple[int, float | None]], mode: str) -> None:
    """Flag the WARMING samples (index, the first column's fallback) of every column (Compensated, arrays or
    lists; the first is the one the bound was computed for) and give them what `mode` says: 'compensate' keeps
    the compensation, 'pass' removes it, 'fallback' uses the domain guard's linear fallback (the first column;
    the others, and a model without a guard, pass)."""
    for number, column in enumerate(columns):
        flags, comp, out = column.flags, column.comp_dph, column.rate_comp_dph
        for index, fallback in warming:
            flags[index] = int(flags[index]) | _WARMING
            if mode == "compensate" or int(flags[index]) & _RATE_INVALID:
                continue
            new_dph = fallback if mode == "fallback" and fallback is not None and number == 0 else 0.0
            out[index] = out[index] + comp[index] - new_dph
            comp[index] = new_dph



def replay_rules(
    compensator: Compensator, t_s: np.ndarray, rate_dph: np.ndarray, temp_c: np.ndarray, start: int = 0, *,
    mode: str = MODES[0], tolerance_dph: float = TOLERANCE_DPH, chunk_rows: int = 1 << 18,
) -> Compensated:  # fmt: skip
    """The daemon's thermal rules over a recorded run (fogd-replay): the rows before `start` are the history a
    restart at row `start` finds (decimated, with no raw tail, as the state file holds it; bridged to that row's
    temperature) and the rows from `start` on are compensated, which it returns; with no valid temperature
    before `start` the run starts cold, its samples flagged WARMING as the daemon's are."""
    rate_hz = compensator.rate_hz
    valid = temperature_valid(temp_c)
    before = np.flatnonzero(valid[:start])
    bound = None
    if before.size:
        taus = [spec.tau_s for spec in compensator.model.inputs if spec.tau_s is not None]
        past = TempHistory(rate_hz, span_s=max(MIN_SPAN_S, SPAN_FACTOR * max(taus, default=0.0)))
        past.extend(t_s[before].tolist(), temp_c[before].tolist())
        restarted = TempHistory(rate_hz, span_s=past.span_s)
        restarted.restore(thinned(past.points()), past.samples)  # what the daemon's state file holds
        later = np.flatnonzero(valid[start:])
        if later.size:
            restarted.bridge(float(t_s[start + later[0]]), float(temp_c[start + later[0]]))
        compensator.prime(restarted)
    else:
        bound = WarmingBound(compensator.model, rate_hz, tolerance_dph=tolerance_dph)
    parts = [compensator.process(rate_dph[i : i + chunk_rows], temp_c[i : i + chunk_rows])
             for i in range(start, t_s.size, chunk_rows)]  # fmt: skip
    result = Compensated(*(np.concatenate([getattr(part, f.name) for part in parts]) for f in fields(Compensated)))
    if bound is not None:
        mark_cold(bound, t_s[start:], temp_c[start:], [result], mode)
    return result


def mark_cold(bound: WarmingBound, t_s: np.ndarray, temp_c: np.ndarray, columns: list[Compensated], mode: str) -> int:
    """A cold-started run's WARMING samples flagged (and given `mode`) in every column, the first being the one
    `bound`'s model compensated; how many there were."""
    warming = []
    fallback = mode == "fallback"
    valid = temperature_valid(temp_c)
    for index, (time_s, temp, ok) in enumerate(zip(t_s.tolist(), temp_c.tolist(), valid.tolist())):
        if bound.update(time_s, temp if ok else None):
            warming.append((index, bound.fallback_dph() if fallback else None))
        elif not bound.active:
            break
    apply_mode(columns, warming, mode)
    return len(warming)
