"""Several channels of one unit (an IMU's gyros and accelerometers) compensated from its one temperature.

`ChannelModels` is what a model file holds by channel (fogd.core.modelfile.load_channels): each channel's
frozen model. `ChannelCompensator` compensates them all, sample for sample as the daemon and `fogd-replay` do:
every channel goes through its own `Compensator` (one code path for one channel or six), while the model
inputs (eq. 16 rates, lags) are computed once per batch for each distinct input configuration. Channels whose
models have the same inputs share one `InputBank`: the first of them feeds it, the others are handed the very
rows it returned (`_SharedBank`). So each channel's output is the same, float for float and flag for flag, as
a `Compensator` of its own on that channel, whatever the batch sizes.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from typing import Any

import numpy as np

from fogd.core.compensator import Compensated, Compensator
from fogd.core.frozen import FrozenModel
from fogd.core.inputs import InputBank, InputSpec


class ChannelModels(Mapping[str, FrozenModel]):
    """A model file's models by channel, in file order: `rate_x_dph` ... `accel_z_g` for a multi-channel
    (version 3) file, or the one channel `rate_dph` for a single-channel (version 1 or 2) file."""

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

    @property
    def channels(self) -> tuple[str, ...]:
        return tuple(self.compensators)

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
        return {
            channel: compensator.process(
                self._rates(rates, channel), temp_c, rate_valid=valid.get(channel), temp_stale=temp_stale
            )
            for channel, compensator in self.compensators.items()
        }

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
        return {
            channel: compensator.process_few(self._rates(rates, channel), temp_c, rate_valid[channel], temp_stale)
            for channel, compensator in self.compensators.items()
        }

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
