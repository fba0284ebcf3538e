"""Several channels of one unit (an IMU's gyros and accelerometers) compensated from its one temperature.

`ChannelModels` is what a model file holds by channel (fogd.core.modelfile.load_channels): each channel's
frozen model. `ChannelCompensator` compensates them all, sample for sample as the daemon and `fogd-replay` do,
with the model inputs (eq. 16 rates, lags) computed once per batch for each distinct input configuration:
channels whose models have the same inputs share one `InputBank` (`_SharedBank`: the first caller feeds it, the
others are handed the very rows it returned).

The channels of one bank are compensated together (`_Stack`): the temperature policies and flags they share
once per sample, their models in one numpy pass (fogd.core.frozen.StackedModels), so six channels cost far
less than six compensators. Each channel's temperatures, rates and flags are a `Compensator` of its own's bit
for bit, its compensation within 1e-12 relative (the kernel and trend sums run in another order); streaming
equals batch bit for bit, whatever the batch sizes (a row's floats are the same alone or in a block). A channel
alone on its bank (a single-axis model above all) goes through its own `Compensator`, exactly as before.

`ChannelCompensator.process_row` is the daemon's one-sample form (its batches at real rates are one frame):
the same policies and the same evaluators, pre-bound per input bank, in plain Python floats, giving the floats
and flags of `process_few` for that sample bit for bit and leaving the same state behind.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Iterable, Iterator, Mapping
from typing import Any

import numpy as np

from fogd.core.compensator import (
    _CLAMPED,
    _OUT_OF_DOMAIN,
    _RATE_INVALID,
    _TEMP_INVALID,
    _TEMP_STALE,
    _WARMUP,
    TEMP_VALID_C,
    Compensated,
    Compensator,
    hold_temperature,
    temperature_valid,
)
from fogd.core.estimator import SCALAR_CHUNK
from fogd.core.frozen import FrozenModel, StackedModels
from fogd.core.history import TempHistory
from fogd.core.inputs import InputBank, InputSpec


class ChannelModels(Mapping[str, FrozenModel]):
    """A model file's models by channel, in file order: `rate_x_dph` ... `accel_z_g` for a multi-channel
    (version 3) file, or the one channel `rate_dph` for a single-channel (version 1, 2, 4 or 5) file."""

    def __init__(self, models: Mapping[str, FrozenModel], *, name: str, version: int) -> None:
        if not models:
            raise ValueError("ChannelModels needs at least one channel")
        self._models = dict(models)
        self.name = name
        self.version = version

    def __getitem__(self, channel: str) -> FrozenModel:
        return self._models[channel]

    def __iter__(self) -> Iterator[str]:
        return iter(self._models)

    def __len__(self) -> int:
        return len(self._models)

    def __repr__(self) -> str:
        return f"ChannelModels({self.name!r}, version {self.version}, channels {', '.join(self._models)})"

    @property
    def channels(self) -> tuple[str, ...]:
        return tuple(self._models)

    def split(self, available: Iterable[str]) -> tuple[tuple[str, ...], tuple[str, ...]]:
        """(the channels of `available` this file compensates, those it does not: passed through), in the
        order of `available`."""
        available = tuple(available)
        return tuple(c for c in available if c in self._models), tuple(c for c in available if c not in self._models)


class _SharedBank:
    """One InputBank for several channels' compensators: in each batch the first channel's calls are made on
    the bank and recorded, and every other channel is handed the recorded results in the same order."""

    def __init__(self, specs: tuple[InputSpec, ...], rate_hz: float) -> None:
        self.bank = InputBank(specs, rate_hz)
        self.calls: list[Any] = []
        self.start = 0  # the bank's count when the batch began

    def begin(self) -> None:
        self.calls.clear()
        self.start = self.bank.count

    def reset(self) -> None:
        self.bank.reset()
        self.begin()


class _BankView:
    """What one channel's Compensator sees as its InputBank: the shared bank's rows of the current batch."""

    def __init__(self, shared: _SharedBank) -> None:
        self._shared = shared
        self.specs = shared.bank.specs
        self.rate_hz = shared.bank.rate_hz
        self.warmup = shared.bank.warmup
        self._call = 0
        self._used = 0  # samples this channel has taken in the batch

    def begin(self) -> None:
        self._call = self._used = 0

    @property
    def count(self) -> int:
        return self._shared.start + self._used

    @property
    def warm(self) -> bool:
        return self.count > self.warmup

    def reset(self) -> None:
        self._shared.reset()
        self.begin()

    def update(self, temp_c: np.ndarray) -> np.ndarray:
        calls = self._shared.calls
        if self._call == len(calls):
            rows = self._shared.bank.update(temp_c)
            rows.flags.writeable = False  # handed to every channel: none may change what the others read
            calls.append(rows)
        rows = calls[self._call]
        self._call += 1
        self._used += rows.shape[0]
        return rows

    def update_one(self, temp_c: float) -> tuple[float, ...]:
        calls = self._shared.calls
        if self._call == len(calls):
            calls.append(self._shared.bank.update_one(temp_c))
        row = calls[self._call]
        self._call += 1
        self._used += 1
        return row


class _Stack:
    """The channels of one input bank whose models stack (fogd.core.frozen.StackedModels), compensated together:
    the temperature policies, the bank update and the flags they share once per sample, the models in one numpy
    pass, and per channel only what is its own (its rate, its validity, its clamp, its domain guard). The
    policies are `Compensator`'s, in the same order; each channel's `Compensator` holds its state (its held
    temperature, which is every channel's) and its model."""

    def __init__(self, channels: list[str], compensators: list[Compensator], view: _BankView) -> None:
        self.channels = channels
        self.compensators = compensators
        self.view = view
        self.models = StackedModels([compensator.model for compensator in compensators])
        self.rate_column = compensators[0]._rate_column
        self.guards = [(index, compensator.guard) for index, compensator in enumerate(compensators)
                       if compensator.guard is not None]  # fmt: skip

    def _held(self, temp_c: float) -> None:
        for compensator in self.compensators:
            compensator._held_temp_c = temp_c

    def process(self, rates: list[Any], temp_c: Any, valid: list[Any], temp_stale: Any) -> list[Compensated]:
        """`Compensator.process` of every channel: `rates` and `valid` (None: every sample valid) by channel."""
        rates = [np.atleast_1d(np.asarray(rate, dtype=np.float64)) for rate in rates]
        temp_in = np.atleast_1d(np.asarray(temp_c, dtype=np.float64))
        n = temp_in.size
        if any(rate.size != n for rate in rates):
            raise ValueError("every channel needs one rate sample for each temperature sample")
        if n <= SCALAR_CHUNK:
            few = self.process_few(
                [rate.tolist() for rate in rates], temp_in.tolist(),
                [[True] * n if ok is None else np.asarray(ok, dtype=bool).tolist() for ok in valid],
                [False] * n if temp_stale is None else np.asarray(temp_stale, dtype=bool).tolist(),
            )  # fmt: skip
            return [Compensated(np.array(one.temp_c, dtype=np.float64), np.array(one.temp_rate_cps, dtype=np.float64),
                                np.array(one.comp_dph, dtype=np.float64), np.array(one.rate_comp_dph, dtype=np.float64),
                                np.array(one.flags, dtype=np.uint16)) for one in few]  # fmt: skip
        count = len(self.compensators)
        flags = np.zeros(n, dtype=np.uint16)
        temp_ok = temperature_valid(temp_in)
        flags[~temp_ok] |= _TEMP_INVALID
        temp_used = hold_temperature(temp_in, temp_ok, self.compensators[0]._held_temp_c)
        if n:
            self._held(float(temp_used[-1]))
        known = np.isfinite(temp_used)
        temp_rate_cps = np.zeros(n)
        comps = np.zeros((n, count))
        clamped = np.zeros((n, count), dtype=bool)
        outside = np.zeros((n, count), dtype=bool)
        if known.any():
            first = int(np.argmax(known))
            bank = self.view
            warm_before = bank.count
            x = bank.update(temp_used[first:])
            warmup = np.arange(warm_before, warm_before + x.shape[0]) < bank.warmup
            flags[first:][warmup] |= _WARMUP
            comps[first:], clamped[first:] = self.models.predict(x)
            for index, guard in self.guards:
                out = guard.outside(x) & ~warmup
                if out.any():
                    comps[first:, index][out] = guard.fallback.predict(x[out])[0]
                    outside[first:, index] = out
            if self.rate_column is not None:
                temp_rate_cps[first:] = x[:, self.rate_column]
        flags[~known] |= _WARMUP
        if temp_stale is not None:
            flags[np.asarray(temp_stale, dtype=bool)] |= _TEMP_STALE
        # every channel at once, (samples, channels), then a contiguous column each
        rate_dph = np.column_stack(rates) if count > 1 else rates[0][:, None]
        rate_ok = np.isfinite(rate_dph)
        for index, rate_valid in enumerate(valid):
            if rate_valid is not None:
                rate_ok[:, index] &= np.asarray(rate_valid, dtype=bool)
        own = (flags[:, None] | np.where(clamped, _CLAMPED, 0) | np.where(outside, _OUT_OF_DOMAIN, 0)
               | np.where(rate_ok, 0, _RATE_INVALID)).astype(np.uint16)  # fmt: skip
        rate_comp_dph = np.where(rate_ok, rate_dph - comps, rate_dph)
        comps = np.where(rate_ok, comps, 0.0)  # what was subtracted: nothing where the rate is invalid
        own, comps, rate_comp_dph = own.T.copy(), comps.T.copy(), rate_comp_dph.T.copy()
        return [Compensated(temp_used.copy(), temp_rate_cps.copy(), comps[index], rate_comp_dph[index], own[index])
                for index in range(count)]

    def process_few(
        self, rates: list[list[float]], temp_c: list[float], valid: list[list[bool]], temp_stale: list[bool]
    ) -> list[Compensated]:
        """`Compensator.process_few` of every channel, a sample at a time, the models stacked."""
        low_c, high_c = TEMP_VALID_C
        bank, models, guards, rate_column = self.view, self.models, self.guards, self.rate_column
        count = len(self.compensators)
        held = self.compensators[0]._held_temp_c
        none, zeros = [False] * count, [0.0] * count
        temps, temp_rates = [], []
        comps_out: list[list[float]] = [[] for _ in range(count)]
        rates_out: list[list[float]] = [[] for _ in range(count)]
        flags_out: list[list[int]] = [[] for _ in range(count)]
        for sample, (temp, is_stale) in enumerate(zip(temp_c, temp_stale)):
            flags = 0
            if low_c <= temp <= high_c:  # (NaN is not)
                held = temp
            else:
                flags |= _TEMP_INVALID
            temp_rate = 0.0
            outside = none
            if held == held:  # a valid temperature has been seen
                if bank.count < bank.warmup:
                    flags |= _WARMUP
                x = bank.update_one(held)
                comps, clamped = models.predict_one(x)
                if guards and not flags & _WARMUP:
                    for index, guard in guards:
                        if guard.outside_one(x):
                            if outside is none:
                                comps, outside = list(comps), list(none)
                            comps[index] = guard.fallback.predict_one(x)[0]
                            outside[index] = True
                if rate_column is not None:
                    temp_rate = x[rate_column]
            else:
                flags |= _WARMUP
                comps, clamped = zeros, none
            if is_stale:
                flags |= _TEMP_STALE
            temps.append(held)
            temp_rates.append(temp_rate)
            for index in range(count):
                rate, comp, own = rates[index][sample], comps[index], flags
                if clamped[index]:
                    own |= _CLAMPED
                if outside[index]:
                    own |= _OUT_OF_DOMAIN
                if valid[index][sample] and math.isfinite(rate):
                    rates_out[index].append(rate - comp)
                else:
                    own |= _RATE_INVALID
                    rates_out[index].append(rate)
                    comp = 0.0  # what was subtracted
                comps_out[index].append(comp)
                flags_out[index].append(own)
        self._held(held)
        return [Compensated(list(temps), list(temp_rates), comps_out[index], rates_out[index], flags_out[index])  # type: ignore[arg-type]
                for index in range(count)]  # fmt: skip


class _RowGroup:
    """The channels of one input bank as `ChannelCompensator.process_row` evaluates them: the shared bank, its parts
    (an evaluator returning (compensations, clamped) by channel for an input row, the channels' positions, the
    domain guards by index in the part), and the compensators whose held temperature is the group's."""

    def __init__(self, shared: _SharedBank, parts: list[tuple[Any, list[int], list[tuple[int, Any]]]],
                 compensators: list[Compensator]) -> None:  # fmt: skip
        self.shared = shared
        self.parts = parts
        self.compensators = compensators
        self.rate_column = compensators[0]._rate_column
        self.first = any(0 in channels for _, channels, _ in parts)  # holds the first channel: what is reported


def _as_lists(predict_one: Any) -> Any:
    """A model's `predict_one` ((value, clamped)) as a stack's ([value], [clamped])."""

    def one(x: tuple[float, ...]) -> tuple[list[float], list[bool]]:
        value, clamped = predict_one(x)
        return [value], [clamped]

    return one


class ChannelCompensator:
    """Stateful, chunk-size independent compensation of several channels from one temperature: each channel
    with its own frozen model, the inputs computed once per batch for each distinct input configuration."""

    def __init__(self, models: Mapping[str, FrozenModel], rate_hz: float) -> None:
        if not models:
            raise ValueError("ChannelCompensator needs at least one channel's model")
        self.rate_hz = float(rate_hz)
        self._banks: dict[tuple[InputSpec, ...], _SharedBank] = {}
        self._views: list[_BankView] = []
        self.compensators: dict[str, Compensator] = {}
        for channel, model in models.items():
            shared = self._banks.get(model.inputs)
            if shared is None:
                shared = self._banks[model.inputs] = _SharedBank(model.inputs, rate_hz)
            view = _BankView(shared)
            self._views.append(view)
            self.compensators[channel] = Compensator(model, rate_hz, bank=view)  # type: ignore[arg-type]
        # the channels of a bank whose models stack go through one _Stack; the others (and a bank's only
        # channel: one channel is compensated exactly as a Compensator of its own) one by one
        self._stacks: list[_Stack] = []
        self._alone: dict[str, Compensator] = {}
        for shared in self._banks.values():
            stackable = [channel for channel, model in models.items()
                         if model.inputs == shared.bank.specs and StackedModels.supports(model)]  # fmt: skip
            if len(stackable) >= 2:
                view = _BankView(shared)
                self._views.append(view)
                self._stacks.append(_Stack(stackable, [self.compensators[channel] for channel in stackable], view))
        stacked = {channel for stack in self._stacks for channel in stack.channels}
        self._alone = {channel: compensator for channel, compensator in self.compensators.items() if channel not in stacked}
        self._rows = self._row_groups()
        if len(self.compensators) == 1:  # one channel (a single-axis model, the daemon's usual one): its own row form
            self._one, self._one_bank = next(iter(self.compensators.values())), next(iter(self._banks.values()))
            self.process_row = self._process_one  # type: ignore[method-assign]
        # (reading, temperature, usable, stale) -> (held, its rate, comp, out, flags): _process_one without its
        # lists, for a caller with the one channel's reading at hand (the daemon's row path); None: several channels
        self.sample_one: Callable[[float, float, bool, bool], tuple[float, float, float, float, int]] | None = None
        self._bind_sample_one()

    def _bind_sample_one(self) -> None:
        """`sample_one` on the one channel's bank as it is now (a hand-over replaces the bank)."""
        if len(self.compensators) == 1:
            self.sample_one = functools.partial(self._one.sample, self._one_bank.bank)

    def carry_state_from(self, old: ChannelCompensator) -> bool:
        """Go on from `old`'s input banks and held temperatures (a reload that keeps every channel's inputs:
        the same channels with the same input configurations group into the same banks); False, and nothing
        taken, when they differ."""
        if self.channels != old.channels or any(
            self.compensators[channel].model.inputs != old.compensators[channel].model.inputs for channel in self.channels
        ):
            return False
        for inputs, shared in self._banks.items():
            shared.bank = old._banks[inputs].bank
        for channel, compensator in self.compensators.items():
            compensator._held_temp_c = old.compensators[channel]._held_temp_c
        self._bind_sample_one()
        return True

    @property
    def channels(self) -> tuple[str, ...]:
        return tuple(self.compensators)

    @property
    def stacked(self) -> tuple[tuple[str, ...], ...]:
        """The channels evaluated together (fogd.core.frozen.StackedModels), by input bank."""
        return tuple(tuple(stack.channels) for stack in self._stacks)

    @property
    def banks(self) -> int:
        """Distinct input configurations: the input banks computed per batch."""
        return len(self._banks)

    @property
    def warmup(self) -> int:
        """Samples before every channel's inputs are real (the longest warm-up of any bank)."""
        return max(shared.bank.warmup for shared in self._banks.values())

    def reset(self) -> None:
        """Forget the temperature history of every channel."""
        for compensator in self.compensators.values():
            compensator.reset()
        self._begin()

    def prime(self, history: TempHistory) -> None:
        """Every channel's inputs as if fed the whole `history` (fogd.core.history), the temperature held its
        newest; nothing changes for an empty history."""
        if history.last is None:
            return
        for shared in self._banks.values():
            history.prime(shared.bank)
        for compensator in self.compensators.values():
            compensator._held_temp_c = history.last[1]
        self._begin()

    def process(
        self,
        rates: Mapping[str, np.ndarray],
        temp_c: np.ndarray,
        *,
        rate_valid: Mapping[str, np.ndarray] | None = None,
        temp_stale: np.ndarray | None = None,
    ) -> dict[str, Compensated]:
        """Compensate the next samples of every channel: `rates` holds each channel's samples (every channel
        of the models; others are ignored), `temp_c` the temperature held for each sample, `rate_valid` the
        channels' own validity where the caller knows it. Returns each channel's `Compensator.process`."""
        self._begin()
        valid = rate_valid or {}
        out = {
            channel: compensator.process(
                self._rates(rates, channel), temp_c, rate_valid=valid.get(channel), temp_stale=temp_stale
            )
            for channel, compensator in self._alone.items()
        }
        for stack in self._stacks:
            results = stack.process([self._rates(rates, channel) for channel in stack.channels], temp_c,
                                    [valid.get(channel) for channel in stack.channels], temp_stale)  # fmt: skip
            out.update(zip(stack.channels, results))
        return out if len(self._stacks) == 0 else {channel: out[channel] for channel in self.compensators}

    def process_few(
        self,
        rates: Mapping[str, list[float]],
        temp_c: list[float],
        rate_valid: Mapping[str, list[bool]],
        temp_stale: list[bool],
    ) -> dict[str, Compensated]:
        """`process` of a few samples as Python lists (the daemon's batches at real rates): each channel's
        `Compensator.process_few`; `rate_valid` must hold every channel's."""
        self._begin()
        out = {
            channel: compensator.process_few(self._rates(rates, channel), temp_c, rate_valid[channel], temp_stale)
            for channel, compensator in self._alone.items()
        }
        for stack in self._stacks:
            results = stack.process_few([self._rates(rates, channel) for channel in stack.channels], temp_c,
                                        [rate_valid[channel] for channel in stack.channels], temp_stale)  # fmt: skip
            out.update(zip(stack.channels, results))
        return out if len(self._stacks) == 0 else {channel: out[channel] for channel in self.compensators}

    def _row_groups(self) -> list[_RowGroup]:
        """What `process_row` walks: per input bank, its stack (if any) and each of its channels alone."""
        position = {channel: index for index, channel in enumerate(self.compensators)}
        groups = []
        for shared in self._banks.values():
            parts: list[tuple[Any, list[int], list[tuple[int, Any]]]] = []
            compensators: list[Compensator] = []
            for stack in self._stacks:
                if stack.view._shared is shared:
                    parts.append((stack.models.predict_one, [position[c] for c in stack.channels], stack.guards))
                    compensators += stack.compensators
            for channel, compensator in self._alone.items():
                if compensator.bank._shared is shared:  # type: ignore[attr-defined]
                    guards = [(0, compensator.guard)] if compensator.guard is not None else []
                    parts.append((_as_lists(compensator.model.predict_one), [position[channel]], guards))
                    compensators.append(compensator)
            groups.append(_RowGroup(shared, parts, compensators))
        return groups

    def process_row(
        self, values: list[float], usable: list[bool], temp_c: float, temp_stale: bool
    ) -> tuple[float, float, list[float], list[float], list[int]]:
        """`process_few` of one sample, pre-bound: every channel's reading and usability in `channels` order,
        the temperature held for the sample and whether it is stale. Returns (the first channel's temperature
        used and temperature rate, then per channel its compensation, compensated reading and flags): the very
        floats and flags `process_few` gives for a one-sample batch, in plain Python (no per-row numpy call
        outside a large model's kernel), the inputs computed once per input bank. The three lists are new at
        each call: the daemon keeps them as a one-frame batch's columns."""
        low_c, high_c = TEMP_VALID_C
        count = len(values)
        comps, outs, flags_out = [0.0] * count, [0.0] * count, [0] * count
        temp_used = temp_rate = 0.0
        for group in self._rows:
            compensators = group.compensators
            flags = 0
            held = compensators[0]._held_temp_c
            if low_c <= temp_c <= high_c:  # (NaN is not)
                held = temp_c
            else:
                flags |= _TEMP_INVALID
            for compensator in compensators:
                compensator._held_temp_c = held
            rate = 0.0
            x = None
            if held == held:  # a valid temperature has been seen
                bank = group.shared.bank  # read at each call: a reload hands a warm bank over (serving.daemon)
                if bank.count < bank.warmup:
                    flags |= _WARMUP
                x = bank.update_one(held)
                if group.rate_column is not None:
                    rate = x[group.rate_column]
            else:
                flags |= _WARMUP
            if temp_stale:
                flags |= _TEMP_STALE
            for predict_one, channels, guards in group.parts:
                if x is not None:
                    part_comps, clamped = predict_one(x)
                    outside = None
                    if guards and not flags & _WARMUP:
                        for index, guard in guards:
                            if guard.outside_one(x):
                                if outside is None:
                                    part_comps, outside = list(part_comps), [False] * len(part_comps)
                                part_comps[index] = guard.fallback.predict_one(x)[0]
                                outside[index] = True
                for index, channel in enumerate(channels):
                    own, comp = flags, 0.0
                    if x is not None:
                        comp = part_comps[index]
                        if clamped[index]:
                            own |= _CLAMPED
                        if outside is not None and outside[index]:
                            own |= _OUT_OF_DOMAIN
                    value = values[channel]
                    if usable[channel] and math.isfinite(value):
                        outs[channel] = value - comp
                    else:
                        own |= _RATE_INVALID
                        outs[channel] = value
                        comp = 0.0  # what was subtracted
                    comps[channel] = comp
                    flags_out[channel] = own
            if group.first:
                temp_used, temp_rate = held, rate
        return temp_used, temp_rate, comps, outs, flags_out

    def _process_one(
        self, values: list[float], usable: list[bool], temp_c: float, temp_stale: bool
    ) -> tuple[float, float, list[float], list[float], list[int]]:
        """`process_row` of one channel: its Compensator's `sample` on the shared bank, without the walk over
        banks, parts and channels (a third of a one-axis row's cost)."""
        held, temp_rate, comp, out, flags = self._one.sample(self._one_bank.bank, values[0], temp_c, usable[0], temp_stale)
        return held, temp_rate, [comp], [out], [flags]

    def _begin(self) -> None:
        for shared in self._banks.values():
            shared.begin()
        for view in self._views:
            view.begin()

    @staticmethod
    def _rates(rates: Mapping[str, Any], channel: str) -> Any:
        try:
            return rates[channel]
        except KeyError:
            raise ValueError(f"no samples for channel {channel!r}, which the model compensates") from None


def output_columns(channel: str) -> tuple[str, str, str]:
    """A compensated channel's columns in a multi-channel output CSV, beside the channel's own reading:
    its compensation, its compensated reading and its flags (rate_x_dph: comp_rate_x_dph, rate_x_comp_dph,
    flags_rate_x_dph; accel_z_g: comp_accel_z_g, accel_z_comp_g, flags_accel_z_g)."""
    stem, _, unit = channel.rpartition("_")
    return f"comp_{channel}", f"{stem}_comp_{unit}", f"flags_{channel}"
