"""Which values of a frame the daemon compensates: the model file's channels matched to what the protocol carries.

A single-channel model (file version 1 or 2) compensates the one gyro axis the config names (`axis`, default
z) as the channel `rate_dph`, as fogd always has. A multi-channel model (version 3) compensates each channel
it has a model for (`rate_x_dph` ... `accel_z_g`) in the frame it came in; the channels the frames carry that
it has no model for pass through untouched. A model channel the protocol cannot carry is refused at start:
the channel compensator needs every channel's sample in every call.
"""

from __future__ import annotations

from dataclasses import dataclass

from fogd.core.channels import ChannelModels
from fogd.core.columns import ACCEL_CHANNELS, GYRO_CHANNELS, SINGLE_CHANNEL
from fogd.core.frozen import FrozenModel
from fogd.core.modelfile import CHANNELS_VERSION, MODEL_VERSION
from fogd.errors import ConfigError
from fogd.protocols import Protocol

AXES = ("x", "y", "z")


@dataclass(frozen=True)
class ChannelPlan:
    """The compensated channels (in frame order), where each comes from in a frame, and the channels passed
    through. `single`: a single-channel model on one gyro axis (today's output formats)."""

    covered: tuple[str, ...]
    sources: tuple[tuple[bool, int], ...]  # per covered channel: (an accelerometer?, axis 0..2)
    passed: tuple[str, ...]  # channels the frames carry that the model does not compensate
    carried: tuple[str, ...]  # every channel the protocol carries, in frame order (the multi-channel outputs' columns)
    single: bool

    @property
    def gyro_axes(self) -> tuple[int, ...]:
        """The gyro axes compensated (what `same` output re-encodes)."""
        return tuple(axis for accel, axis in self.sources if not accel)

    @property
    def accel_axes(self) -> tuple[int, ...]:
        return tuple(axis for accel, axis in self.sources if accel)

    def describe(self) -> str:
        """'compensates rate_x_dph, ...; passes through accel_x_g, ... untouched' for the start line and status."""
        covered = f"rate on axis {AXES[self.sources[0][1]]}" if self.single else ", ".join(self.covered)
        passed = f"; passes through {', '.join(self.passed)} untouched" if self.passed else ""
        return f"compensates {covered}{passed}"


def as_models(model: FrozenModel | ChannelModels) -> ChannelModels:
    """A single model as the one-channel ChannelModels a version-2 file loads as."""
    if isinstance(model, ChannelModels):
        return model
    return ChannelModels({SINGLE_CHANNEL: model}, name=model.name, version=MODEL_VERSION)


def carried_channels(protocol: Protocol) -> tuple[str, ...]:
    """The channels the protocol's frames can carry (gyros, then accelerometers)."""
    gyros = tuple(name for name, carried in zip(GYRO_CHANNELS, protocol.gyro_axes) if carried)
    return gyros + tuple(name for name, carried in zip(ACCEL_CHANNELS, protocol.accel_axes) if carried)


def plan(models: ChannelModels, protocol: Protocol, axis: int) -> ChannelPlan:
    """The channels `models` compensates on `protocol`'s frames; ConfigError (one line) for a channel the
    protocol does not carry."""
    carried = carried_channels(protocol)
    if models.version != CHANNELS_VERSION:
        gyro = GYRO_CHANNELS[axis]
        if gyro not in carried:
            raise ConfigError(f"key 'axis': protocol {protocol.name} carries no {AXES[axis]} axis")
        passed = tuple(channel for channel in carried if channel != gyro)
        return ChannelPlan((SINGLE_CHANNEL,), ((False, axis),), passed, carried, single=True)
    missing = [channel for channel in models if channel not in carried]
    if missing:
        raise ConfigError(f"key 'model': {models.name} compensates {', '.join(missing)}, which protocol "
                          f"{protocol.name} does not carry (it carries {', '.join(carried)})")  # fmt: skip
    covered, passed = models.split(carried)
    sources = tuple(source(channel) for channel in covered)
    return ChannelPlan(covered, sources, passed, carried, single=False)


def source(channel: str) -> tuple[bool, int]:
    """Where `channel` is in a frame: (an accelerometer?, axis 0..2)."""
    if channel in GYRO_CHANNELS:
        return False, GYRO_CHANNELS.index(channel)
    return True, ACCEL_CHANNELS.index(channel)


def method(models: ChannelModels) -> str:
    """The model family, or the families of a multi-channel file ('pso-svr', 'linear+pso-svr')."""
    return "+".join(sorted({model.method for model in models.values()}))
