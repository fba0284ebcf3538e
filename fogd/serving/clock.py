"""The sample rate the estimator uses, and where it comes from. Protocols whose frames carry the device's own
time (fogd, ascii R/T/I/C lines) are measured: the median step between the rate frames' times over the last
`STEPS` frames (a lost frame, a repeated one or a clock that went back does not move a median). Where the rate
in use and the measured one disagree by more than `TOLERANCE` for `DISAGREE_S`, one warning names both and
the measured rate is used from then on (the estimator warms up again: its windows are counted in samples).
Frames without a time (KVH, DSP-3000 lines) are never measured: the rate is the configured one, and the
daemon says at start where it came from (the unit's own ?DR reply, the config, or the default).
"""

from __future__ import annotations

import logging
from collections import deque

log = logging.getLogger("fogd.daemon")

STEPS = 512  # frame-to-frame steps the median is taken over
MIN_STEPS = 32  # no measurement before this many steps
TOLERANCE = 0.03  # relative disagreement that counts ("a few percent": a crystal is within 0.01 %)
DISAGREE_S = 3.0  # for this long, so a burst of jitter or a short pause never switches
CHECK_S = 1.0  # how often the loop asks (a median of STEPS floats)
FRAMES_CLOCK = "the frames' clock"


class DeviceRate:
    """The rate in use (`rate_hz`, from `source`) and the rate the frames' times say (`measured_hz`)."""

    def __init__(self, rate_hz: float, source: str) -> None:
        self.rate_hz = rate_hz
        self.source = source
        self.configured_hz = rate_hz
        self.measured_hz: float | None = None
        self.switches = 0
        self._steps: deque[float] = deque(maxlen=STEPS)
        self._last_s: float | None = None
        self._off_since_s: float | None = None
        self._next_check_s = 0.0
        self._kept = False  # the measured rate could not be used: measured and shown, never switched to

    def add(self, device_s: list[float | None]) -> None:
        """The device times of a batch's rate frames (None or NaN: the frames carry none)."""
        last_s, steps = self._last_s, self._steps
        for t_s in device_s:
            if t_s is None or t_s != t_s:
                continue
            if last_s is not None and t_s > last_s:
                steps.append(t_s - last_s)
            last_s = t_s
        self._last_s = last_s

    def check(self, now_s: float) -> float | None:
        """A new rate for the estimator once the measured one has disagreed with the one in use for
        DISAGREE_S (logged), else None; measures at most every CHECK_S."""
        if now_s < self._next_check_s or len(self._steps) < MIN_STEPS:
            return None
        self._next_check_s = now_s + CHECK_S
        steps = sorted(self._steps)
        self.measured_hz = measured_hz = float(f"{1.0 / steps[len(steps) // 2]:.6g}")
        if self._kept or abs(measured_hz / self.rate_hz - 1.0) <= TOLERANCE:
            self._off_since_s = None
            return None
        if self._off_since_s is None:
            self._off_since_s = now_s
            return None
        if now_s - self._off_since_s < DISAGREE_S:
            return None
        if self.switches == 0:
            log.warning("rate: the frames' own clock says %g Hz, rate_hz (%s) says %g Hz; using %g Hz from the "
                        "frames from now on (the estimator warms up again)", measured_hz, self.source,
                        self.rate_hz, measured_hz)  # fmt: skip
        else:
            log.info("rate: the frames' own clock now says %g Hz (was %g Hz); using it", measured_hz, self.rate_hz)
        self._off_since_s = None
        return measured_hz

    def use(self, rate_hz: float) -> None:
        """The estimator runs at `rate_hz` now, measured from the frames."""
        self.rate_hz, self.source = rate_hz, FRAMES_CLOCK
        self.switches += 1

    def keep(self) -> None:
        """The measured rate cannot be used (the model's window at it): stay at the rate in use."""
        self._kept = True

    def describe(self) -> str:
        """'200 Hz (the frames' clock; rate_hz 1000 Hz)' or '1000 Hz (the config)'."""
        text = f"{self.rate_hz:g} Hz ({self.source}"
        if self.source == FRAMES_CLOCK:
            text += f"; rate_hz {self.configured_hz:g} Hz"
        elif self.measured_hz is not None:
            text += f"; frames' clock {self.measured_hz:g} Hz"
        return text + ")"

    def as_dict(self) -> dict[str, object]:
        return {"in_use_hz": self.rate_hz, "source": self.source, "configured_hz": self.configured_hz,
                "measured_hz": self.measured_hz, "switches": self.switches}  # fmt: skip
