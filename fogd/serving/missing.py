"""Channels the model compensates that the frames never carry (`--axis x` on a z-only stream, a three-gyro
model on a single-axis FOG): every such sample passes through uncompensated, flagged RATE_INVALID, which
looks like a sensor's invalid bit. This counts the samples that lack a compensated channel and, `WARN_AFTER_S`
after the first rate frame, warns once naming the channels the model wants and the frames have not carried.
"""

from __future__ import annotations

import logging

from fogd.protocols.base import Frame
from fogd.serving.channels import AXES, ChannelPlan

log = logging.getLogger("fogd.daemon")

WARN_AFTER_S = 0.5  # of frames: within the first second, as the operator starts it


class MissingChannels:
    """Which compensated channels the rate frames have carried (present, valid or not) since the start."""

    def __init__(self, plan: ChannelPlan) -> None:
        # a single-axis model's one channel (rate_dph) by the gyro axis it compensates, as --axis names it
        self.names = (f"rate_{AXES[plan.sources[0][1]]}_dph",) if plan.single else plan.covered
        self.sources = plan.sources
        self.seen = [False] * len(plan.covered)
        self.first_s: float | None = None
        self.warned = False

    def add(self, frames: list[Frame], rows: list[int], now_s: float) -> int:
        """Note the rate frames at `rows`; how many of them lack a compensated channel."""
        if self.first_s is None and rows:
            self.first_s = now_s
        lacking = 0
        seen, sources = self.seen, self.sources
        for row in rows:
            frame = frames[row]
            whole = True
            for k, (accel, axis) in enumerate(sources):
                if frame.accel_present[axis] if accel else frame.axis_present[axis]:
                    seen[k] = True
                else:
                    whole = False
            if not whole:
                lacking += 1
        return lacking

    @property
    def missing(self) -> list[str]:
        """The compensated channels no rate frame has carried ([] before the first frame)."""
        if self.first_s is None:
            return []
        return [name for name, seen in zip(self.names, self.seen) if not seen]

    def check(self, now_s: float) -> None:
        """Warn once, WARN_AFTER_S after the first rate frame, if a compensated channel never came."""
        if self.warned or self.first_s is None or now_s - self.first_s < WARN_AFTER_S:
            return
        self.warned = True
        missing = self.missing
        if missing:
            log.warning("the model compensates %s but the frames carry no %s: those samples pass through "
                        "uncompensated (flag RATE_INVALID, counted samples_missing_channel); check --axis, the "
                        "model and the protocol", ", ".join(self.names), ", ".join(missing))  # fmt: skip
