"""The model's inputs (temperature, temperature rate) and how they are computed, streaming and in batch.

An `InputSpec` is what a model file stores about one input, so that serving computes exactly what training
computed. `InputBank` is the streaming form (O(1) per sample, any chunk size) and `inputs_batch` the batch
form; both give the same floats bit for bit (the rate estimator works in exact integer sums).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fogd.estimator import EstimatorSettings, TempRateEstimator, temp_rate_batch

TEMP = "temp_c"
TEMP_RATE = "temp_rate_cps"
KINDS = (TEMP, TEMP_RATE)


@dataclass(frozen=True)
class InputSpec:
    """One model input: `temp_c`, or `temp_rate_cps` with its eq. 16 estimator settings."""

    kind: str
    estimator: EstimatorSettings | None = None

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"unknown input {self.kind!r}; known inputs: {', '.join(KINDS)}")
        if (self.kind == TEMP_RATE) != (self.estimator is not None):
            raise ValueError(f"input {self.kind!r}: estimator settings go with {TEMP_RATE} only")

    @property
    def label(self) -> str:
        """A short unique name, e.g. 'temp_rate_cps@50s'."""
        if self.estimator is None:
            return self.kind
        return f"{self.kind}@{self.estimator.window_s:g}s"

    def to_dict(self) -> dict:
        if self.estimator is None:
            return {"kind": self.kind}
        return {"kind": self.kind, **self.estimator.to_dict()}


def default_inputs(estimator: EstimatorSettings | None = None) -> tuple[InputSpec, ...]:
    """The paper's inputs: temperature and its eq. 16 rate."""
    return (InputSpec(TEMP), InputSpec(TEMP_RATE, estimator or EstimatorSettings()))


def warmup_samples(specs: tuple[InputSpec, ...], rate_hz: float) -> int:
    """Samples before every input is real (the longest estimator window)."""
    windows = [spec.estimator.samples(rate_hz)[0] for spec in specs if spec.estimator is not None]
    return max(windows, default=1) - 1


def inputs_batch(temp_c: np.ndarray, specs: tuple[InputSpec, ...], rate_hz: float) -> np.ndarray:
    """All inputs for a whole run of finite temperatures: an (n, len(specs)) array."""
    temp_c = np.asarray(temp_c, dtype=np.float64)
    columns = [temp_c if spec.estimator is None else temp_rate_batch(temp_c, spec.estimator, rate_hz) for spec in specs]
    return np.column_stack(columns) if columns else np.empty((temp_c.size, 0))


class InputBank:
    """All inputs, streaming: feed finite temperatures in chunks, get the (k, d) input rows back."""

    def __init__(self, specs: tuple[InputSpec, ...], rate_hz: float) -> None:
        self.specs = specs
        self.rate_hz = float(rate_hz)
        self._estimators = [
            None if spec.estimator is None else TempRateEstimator(spec.estimator, rate_hz) for spec in specs
        ]
        self.warmup = warmup_samples(specs, rate_hz)
        self.count = 0

    @property
    def warm(self) -> bool:
        return self.count > self.warmup

    def reset(self) -> None:
        for estimator in self._estimators:
            if estimator is not None:
                estimator.reset()
        self.count = 0

    def update(self, temp_c: np.ndarray) -> np.ndarray:
        temp_c = np.atleast_1d(np.asarray(temp_c, dtype=np.float64))
        out = np.empty((temp_c.size, len(self.specs)))
        for column, estimator in enumerate(self._estimators):
            out[:, column] = temp_c if estimator is None else estimator.update(temp_c)
        self.count += temp_c.size
        return out
