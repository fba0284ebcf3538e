"""The streaming compensator: the one code path the daemon and `fogd-replay` both run (paper section 3.2).

Feed it gyro rates and the temperature held for each rate sample, in chunks of any size (one frame in the
daemon, a million rows in replay): it estimates the temperature rate (eq. 16), evaluates the frozen model
and returns the compensation, the compensated rate and per-sample flags. The result does not depend on how
the samples were chunked: chunks of up to `SCALAR_CHUNK` samples (the daemon's batches at real rates are one
frame) go sample by sample through the estimators' `update_one` and `FrozenModel.predict_one` in Python
floats, because numpy's per-call overhead would cost ten times the work; their temperatures, rates and flags
are the same bit for bit, and so is their compensation for the linear model (within 1e-12 relative for the
kernel models, whose `predict_one` sums in another order).

Policies (documented in docs/reference/flags-and-counters.md):
- Warm-up: until the estimator window is full the temperature rate is taken as 0 C/s; the model is still
  evaluated at the current temperature and the sample is flagged WARMUP.
- Invalid temperature (NaN, Inf, outside `TEMP_VALID_C`): the last valid temperature is held and the sample
  flagged TEMP_INVALID; before the first valid temperature nothing is fed to the estimator and the
  compensation is 0.
- Invalid rate (NaN, Inf, or the caller's `rate_valid` false): flagged RATE_INVALID; the estimator still
  advances, the compensated rate is the input passed through unchanged and the compensation is 0 (what
  was subtracted).
- Calibrated domain: a sample with an input beyond the training range is flagged CLAMPED and served by the
  model's outside-range policy (fogd.core.outside_range: the model at the clamped edge, continued along the
  linear fit's slope by default), inside FrozenModel.predict and predict_one alike.
- Guarded domain (models with a `domain_guard`, fogd.core.domain): a sample beyond the calibrated range by
  more than the guard's margin ("range", lag-bank models), or far from every calibration block in the scaled
  joint space ("joint", the paper's inputs), is flagged OUT_OF_DOMAIN and compensated by the fallback model
  stored with the guard (the linear fit on the same blocks and inputs) instead of the main model. Warm-up
  samples are not guarded (their rate inputs are not real yet).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from fogd.core.domain import DomainGuard
from fogd.core.estimator import SCALAR_CHUNK
from fogd.core.flags import Flag
from fogd.core.frozen import FrozenModel
from fogd.core.inputs import InputBank

if TYPE_CHECKING:
    from fogd.core.history import TempHistory

TEMP_VALID_C = (-100.0, 200.0)  # a reading outside this is a broken sensor or a corrupt frame
_TEMP_INVALID, _WARMUP, _CLAMPED = int(Flag.TEMP_INVALID), int(Flag.WARMUP), int(Flag.CLAMPED)
_OUT_OF_DOMAIN, _RATE_INVALID, _TEMP_STALE = int(Flag.OUT_OF_DOMAIN), int(Flag.RATE_INVALID), int(Flag.TEMP_STALE)


@dataclass
class Compensated:
    """One chunk of compensated samples (all the length of the input chunk): arrays, or lists from
    `Compensator.process_few`."""

    temp_c: np.ndarray  # the temperature used (held where the input was invalid)
    temp_rate_cps: np.ndarray
    comp_dph: np.ndarray
    rate_comp_dph: np.ndarray
    flags: np.ndarray  # uint16, fogd.core.flags.Flag bits


def temperature_valid(temp_c: np.ndarray) -> np.ndarray:
    """True where a temperature reading can be used."""
    low, high = TEMP_VALID_C
    with np.errstate(invalid="ignore"):
        return np.isfinite(temp_c) & (temp_c >= low) & (temp_c <= high)


def hold_temperature(temp_c: np.ndarray, valid: np.ndarray, previous_c: float = np.nan) -> np.ndarray:
    """Each sample's temperature with the last valid one carried over invalid samples (`previous_c` before
    the first valid one: NaN if none is known yet)."""
    source = np.where(valid, np.arange(temp_c.size), -1)
    np.maximum.accumulate(source, out=source)
    return np.where(source >= 0, temp_c[np.maximum(source, 0)], previous_c)


class Compensator:
    """Stateful, chunk-size independent compensation of one gyro axis with one frozen model."""

    def __init__(self, model: FrozenModel, rate_hz: float, bank: InputBank | None = None) -> None:
        """`bank`: the model's inputs from elsewhere (fogd.core.channels shares one bank between the channels
        whose models have the same inputs); by default a bank of its own."""
        self.model = model
        self.rate_hz = float(rate_hz)
        self.bank = InputBank(model.inputs, rate_hz) if bank is None else bank
        self._held_temp_c = np.nan
        # the temperature rate reported with each sample: the first eq. 16 input, if the model has one
        self._rate_column = next((i for i, spec in enumerate(model.inputs) if spec.estimator is not None), None)
        self.guard: DomainGuard | None = model.meta.get("domain_guard")

    def reset(self) -> None:
        """Forget the temperature history (e.g. after a gap longer than the caller bridges)."""
        self.bank.reset()
        self._held_temp_c = np.nan

    def prime(self, history: TempHistory) -> None:
        """The inputs as if fed the whole `history` (fogd.core.history), the temperature held its newest."""
        if history.last is not None:
            history.prime(self.bank)
            self._held_temp_c = history.last[1]

    def process(
        self,
        rate_dph: np.ndarray,
        temp_c: np.ndarray,
        *,
        rate_valid: np.ndarray | None = None,
        temp_stale: np.ndarray | None = None,
    ) -> Compensated:
        """Compensate the next samples; `temp_c` is the temperature held for each rate sample."""
        rate_dph = np.atleast_1d(np.asarray(rate_dph, dtype=np.float64))
        temp_in = np.atleast_1d(np.asarray(temp_c, dtype=np.float64))
        n = rate_dph.size
        if n <= SCALAR_CHUNK:
            few = self.process_few(
                rate_dph.tolist(), temp_in.tolist(),
                [True] * n if rate_valid is None else np.asarray(rate_valid, dtype=bool).tolist(),
                [False] * n if temp_stale is None else np.asarray(temp_stale, dtype=bool).tolist(),
            )  # fmt: skip
            return Compensated(
                np.array(few.temp_c, dtype=np.float64), np.array(few.temp_rate_cps, dtype=np.float64),
                np.array(few.comp_dph, dtype=np.float64), np.array(few.rate_comp_dph, dtype=np.float64),
                np.array(few.flags, dtype=np.uint16),
            )  # fmt: skip
        flags = np.zeros(n, dtype=np.uint16)

        temp_ok = temperature_valid(temp_in)
        flags[~temp_ok] |= int(Flag.TEMP_INVALID)
        temp_used = self._hold(temp_in, temp_ok)
        known = np.isfinite(temp_used)  # False only before the first valid temperature ever

        temp_rate_cps = np.zeros(n)
        comp_dph = np.zeros(n)
        if known.any():
            first = int(np.argmax(known))  # once known, a temperature stays known
            warm_before = self.bank.count
            x = self.bank.update(temp_used[first:])
            warmup = np.arange(warm_before, warm_before + x.shape[0]) < self.bank.warmup
            flags[first:][warmup] |= int(Flag.WARMUP)
            comp, clamped = self.model.predict(x)
            if self.guard is not None:
                outside = self.guard.outside(x) & ~warmup
                if outside.any():
                    comp[outside] = self.guard.fallback.predict(x[outside])[0]
                    flags[first:][outside] |= int(Flag.OUT_OF_DOMAIN)
            flags[first:][clamped] |= int(Flag.CLAMPED)
            comp_dph[first:] = comp
            if self._rate_column is not None:
                temp_rate_cps[first:] = x[:, self._rate_column]
        flags[~known] |= int(Flag.WARMUP)

        rate_ok = np.isfinite(rate_dph)
        if rate_valid is not None:
            rate_ok &= np.asarray(rate_valid, dtype=bool)
        flags[~rate_ok] |= int(Flag.RATE_INVALID)
        if temp_stale is not None:
            flags[np.asarray(temp_stale, dtype=bool)] |= int(Flag.TEMP_STALE)
        rate_comp_dph = np.where(rate_ok, rate_dph - comp_dph, rate_dph)
        comp_dph[~rate_ok] = 0.0  # what was subtracted: nothing
        return Compensated(temp_used, temp_rate_cps, comp_dph, rate_comp_dph, flags)

    def process_few(
        self, rate_dph: list[float], temp_c: list[float], rate_valid: list[bool], temp_stale: list[bool]
    ) -> Compensated:
        """`process` of a few samples given as Python lists (the daemon's batches at real rates), one sample at
        a time in Python floats: the same policies, in the same order. The result holds lists, not arrays: a
        frame's values go on to its encoding without a numpy call on the way."""
        bank, sample = self.bank, self.sample
        temps, temp_rates, comps, rates_out, flags_out = [], [], [], [], []
        for rate, temp, rate_ok, is_stale in zip(rate_dph, temp_c, rate_valid, temp_stale):
            held, temp_rate, comp, rate_comp, flags = sample(bank, rate, temp, rate_ok, is_stale)
            temps.append(held)
            temp_rates.append(temp_rate)
            comps.append(comp)
            rates_out.append(rate_comp)
            flags_out.append(flags)
        return Compensated(temps, temp_rates, comps, rates_out, flags_out)  # type: ignore[arg-type]

    def sample(self, bank: InputBank, rate: float, temp: float, rate_ok: bool, is_stale: bool) -> tuple[float, float, float, float, int]:
        """One sample of `process_few`, its inputs from `bank` (the compensator's own, or the shared bank a
        one-channel fogd.core.channels.ChannelCompensator feeds directly): the temperature used, its rate, the
        compensation, the compensated rate and the flags."""
        flags = _TEMP_STALE if is_stale else 0
        low_c, high_c = TEMP_VALID_C
        if low_c <= temp <= high_c:  # (NaN is not)
            self._held_temp_c = temp
        else:
            flags |= _TEMP_INVALID
        held = self._held_temp_c
        temp_rate = comp = 0.0
        if held == held:  # a valid temperature has been seen
            if bank.count < bank.warmup:
                flags |= _WARMUP
            x = bank.update_one(held)
            comp, clamped = self.model.predict_one(x)
            guard = self.guard
            if guard is not None and not flags & _WARMUP and guard.outside_one(x):
                comp = guard.fallback.predict_one(x)[0]
                flags |= _OUT_OF_DOMAIN
            if clamped:
                flags |= _CLAMPED
            if self._rate_column is not None:
                temp_rate = x[self._rate_column]
        else:
            flags |= _WARMUP
        if rate_ok and math.isfinite(rate):
            return held, temp_rate, comp, rate - comp, flags
        return held, temp_rate, 0.0, rate, flags | _RATE_INVALID  # nothing subtracted: comp 0

    def _hold(self, temp_c: np.ndarray, valid: np.ndarray) -> np.ndarray:
        held = hold_temperature(temp_c, valid, self._held_temp_c)
        if held.size:
            self._held_temp_c = float(held[-1])
        return held
