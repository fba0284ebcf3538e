"""Shared pieces of the thermal-state tests (issue 34): a lag-bank model whose compensation follows the coil's
gradients as fogd-train's default does, the paper's model, and a chamber profile with a long ramp."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fogd.core import modelfile
from fogd.core.estimator import EstimatorSettings
from fogd.core.inputs import default_inputs, parse_inputs

RATE_HZ = 5.0
BANK_INPUTS = "temp,lags@10..3000/7,play@2"
# deg/h per C of each lag-difference: the coil's radial gradient (fast) and the housing's memory (slow)
GRADIENT_DPH_PER_C = (0.02, 0.015, 0.01, 0.008, 0.006, 0.004, 0.003)


def bank_document(name: str = "bank") -> dict:
    """comp = sum_i g_i (lag_{i-1} - lag_i) + 0.001 T + 0.002 play deg/h over fogd-train's default inputs (the
    sensor's temperature as lag 0): a linear model whose answer depends on hours of temperature history."""
    inputs = parse_inputs(BANK_INPUTS)
    count = len(inputs)
    coef = np.zeros(count)
    coef[0] = 0.001
    for i, gain in enumerate(GRADIENT_DPH_PER_C):
        coef[i] += gain
        coef[i + 1] -= gain
    coef[-1] = 0.002  # play
    return modelfile.document(
        name=name, method="linear", inputs=inputs, x_mean=np.zeros(count), x_scale=np.ones(count), y_mean=0.0,
        y_scale=1.0, domain_min=np.r_[np.full(count - 1, -50.0), -1.0], domain_max=np.r_[np.full(count - 1, 120.0), 1.0],
        params={"coef": coef.tolist(), "intercept": 0.0}, reference_dph=0.0, training={}, metrics={},
        created_utc="2026-01-01T00:00:00Z",
    )  # fmt: skip


def paper_document(name: str = "paper") -> dict:
    """comp = 0.003 T + 20 dT/dt deg/h over the paper's inputs (temperature and its 50 s eq. 16 rate, 1 s averages: at 5 Hz 0.5 s is a rounding tie that a CSV's estimated rate tips)."""
    return modelfile.document(
        name=name, method="linear", inputs=default_inputs(EstimatorSettings(window_s=50.0, average_s=1.0)),
        x_mean=np.zeros(2), x_scale=np.ones(2), y_mean=0.0, y_scale=1.0,
        domain_min=np.array([-50.0, -1.0]), domain_max=np.array([120.0, 1.0]),
        params={"coef": [0.003, 20.0], "intercept": 0.0}, reference_dph=0.0, training={}, metrics={},
        created_utc="2026-01-01T00:00:00Z",
    )  # fmt: skip


def save(path: Path, doc: dict) -> Path:
    modelfile.save(path, doc)
    return path


def ramp_run(duration_s: float = 9000.0, *, rate_hz: float = RATE_HZ, seed: int = 1, noise_c: float = 0.01,
             soak_s: float = 1800.0, ramp_cps: float = 0.003) -> dict[str, np.ndarray]:  # fmt: skip
    """A soak at 20 C, then a ramp at `ramp_cps` to the end: t_s, rate_dph (white noise), temp_c (with noise)."""
    rng = np.random.default_rng(seed)
    t_s = np.arange(int(duration_s * rate_hz)) / rate_hz
    temp_c = 20.0 + ramp_cps * np.clip(t_s - soak_s, 0.0, None) + rng.normal(0.0, noise_c, t_s.size)
    rate_dph = rng.normal(0.0, 0.005, t_s.size)
    return {"t_s": t_s, "rate_dph": rate_dph, "temp_c": np.round(temp_c, 4)}


def write_run(path: Path, run: dict[str, np.ndarray], rows: slice = slice(None)) -> Path:
    lines = ["t_s,rate_dph,temp_c"]
    lines += [f"{t:.3f},{r!r},{c:.4f}" for t, r, c in
              zip(run["t_s"][rows].tolist(), run["rate_dph"][rows].tolist(), run["temp_c"][rows].tolist())]  # fmt: skip
    path.write_text("\n".join(lines) + "\n")
    return path
