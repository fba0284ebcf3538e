"""Overlapping Allan deviation (IEEE 952 annex C) of a gyro rate, and the two numbers read off its curve.

For rate samples y at interval tau0, the angle is theta_k = tau0 * sum_{i<k} y_i and, for tau = m * tau0,

    AVAR(tau) = sum_k (theta_{k+2m} - 2 theta_{k+m} + theta_k)^2 / (2 tau^2 (N - 2m))

over every k (overlapping estimator; N angle samples). The tau grid is octave spaced (m = 1, 2, 4, ...) up
to a tenth of the record, beyond which too few independent clusters remain. Read off the curve:
- angle random walk: the -1/2 slope line sigma = N / sqrt(tau) fitted (in log space, slope fixed) over the
  short-tau points, read at tau = 1 h and given in deg/sqrt(h) (with tau in s, N = sigma(1 s) / 60);
- bias instability: the curve's minimum / 0.664 (IEEE 952's flicker-floor factor sqrt(2 ln 2 / pi)), only
  where the curve has one: a minimum at the largest tau computed means the curve is still falling (the record
  is too short to reach the flicker floor), and the bias instability is reported as not reached (None).
The angle is summed in float64 after removing the mean rate, which leaves AVAR unchanged and keeps the
cumulative sum small.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fogd.core.atomic import replaced

BIAS_INSTABILITY_FACTOR = 0.664
ARW_FIT_MAX_TAU_S = 10.0  # short-tau points where white rate noise dominates a FOG's curve
MAX_TAU_FRACTION = 0.1


@dataclass
class AllanResult:
    tau_s: np.ndarray
    adev_dph: np.ndarray  # Allan deviation in deg/h at each tau
    arw_dpsh: float  # angle random walk, deg/sqrt(h)
    bias_instability_dph: float | None  # None: not reached (the curve is still falling at its largest tau)
    bias_instability_tau_s: float  # tau of the curve's minimum (the largest tau when not reached)

    @property
    def bias_instability_text(self) -> str:
        """'0.0123 deg/h at tau = 409.6 s', or 'not reached (curve still falling at tau = 409.6 s)'."""
        return self.bias_instability_in("deg/h")

    def bias_instability_in(self, unit: str) -> str:
        """bias_instability_text for a rate in `unit` (the curve is in the rate's unit: g for an accelerometer)."""
        if self.bias_instability_dph is None:
            return f"not reached (curve still falling at tau = {self.bias_instability_tau_s:.4g} s)"
        return f"{self.bias_instability_dph:.4g} {unit} at tau = {self.bias_instability_tau_s:.4g} s"


def white_noise(result: AllanResult, unit: str = "deg/h") -> tuple[str, float]:
    """(name with its unit, value) of the white noise read off the -1/2 slope: a gyro's angle random walk in
    deg/sqrt(h), or for a rate in another unit (an accelerometer's g) its density sigma(1 s) in unit/sqrt(Hz)."""
    if unit == "deg/h":
        return "ARW (deg/sqrt h)", result.arw_dpsh
    return f"noise ({unit}/sqrt Hz)", 60.0 * result.arw_dpsh  # arw_dpsh is sigma(1 s) / 60


def octave_taus(samples: int, rate_hz: float, max_fraction: float = MAX_TAU_FRACTION) -> np.ndarray:
    """Cluster sizes m = 1, 2, 4, ... with m <= max_fraction * samples (at least m = 1)."""
    top = max(1, int(samples * max_fraction))
    return 2 ** np.arange(int(np.log2(top)) + 1)


def allan_deviation(rate_dph: np.ndarray, rate_hz: float, m: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(tau_s, overlapping ADEV in deg/h) of finite rate samples taken at `rate_hz`."""
    rate = np.asarray(rate_dph, dtype=np.float64)
    if rate.size < 3:
        raise ValueError(f"Allan deviation needs at least 3 samples, got {rate.size}")
    tau0 = 1.0 / rate_hz
    m = octave_taus(rate.size, rate_hz) if m is None else np.asarray(m, dtype=np.int64)
    m = m[(m >= 1) & (2 * m < rate.size + 1)]
    theta = np.zeros(rate.size + 1)
    np.cumsum((rate - rate.mean()) * tau0, out=theta[1:])
    n = theta.size
    adev = np.empty(m.size)
    for index, size in enumerate(m):
        second = theta[2 * size :] - 2.0 * theta[size : n - size] + theta[: n - 2 * size]
        tau = size * tau0
        adev[index] = np.sqrt(np.mean(second**2) / (2.0 * tau * tau))
    return m * tau0, adev


def analyse(rate_dph: np.ndarray, rate_hz: float) -> AllanResult:
    """The ADEV curve on the octave grid, with ARW and bias instability read off it."""
    rate = np.asarray(rate_dph, dtype=np.float64)
    rate = rate[np.isfinite(rate)]
    tau_s, adev = allan_deviation(rate, rate_hz)
    short = tau_s <= max(ARW_FIT_MAX_TAU_S, tau_s[min(2, tau_s.size - 1)])
    # log sigma = log N - log(tau) / 2, slope fixed: the intercept is the mean of log sigma + log(tau) / 2
    with np.errstate(divide="ignore"):  # a constant rate has ADEV 0: log 0 = -inf gives ARW 0, not a warning
        sigma_1s_dph = float(np.exp(np.mean(np.log(adev[short]) + 0.5 * np.log(tau_s[short]))))
    lowest = int(np.argmin(adev))
    reached = lowest < adev.size - 1
    return AllanResult(
        tau_s=tau_s,
        adev_dph=adev,
        arw_dpsh=sigma_1s_dph / 60.0,
        bias_instability_dph=float(adev[lowest] / BIAS_INSTABILITY_FACTOR) if reached else None,
        bias_instability_tau_s=float(tau_s[lowest]),
    )


def summary_lines(results: dict[str, AllanResult], unit: str = "deg/h") -> list[str]:
    """A small table: one row per labelled curve, then a line saying which curves did not reach their bias
    instability; `unit` is the rate's (g for an accelerometer)."""
    noise = white_noise(next(iter(results.values())), unit)[0] if results else "ARW (deg/sqrt h)"
    lines = [f"{'Allan deviation':<24} {noise:>17} {f'bias instab. ({unit})':>21} {'at tau (s)':>11}"]
    for label, result in results.items():
        bias = "not reached" if result.bias_instability_dph is None else f"{result.bias_instability_dph:.4g}"
        lines.append(f"{label:<24} {white_noise(result, unit)[1]:>17.4g} {bias:>21} {result.bias_instability_tau_s:>11.4g}")
    falling: dict[str, list[str]] = {}  # one line per tau: the curves usually share their tau grid
    for label, result in results.items():
        if result.bias_instability_dph is None:
            falling.setdefault(result.bias_instability_in(unit), []).append(label)
    return lines + [f"bias instability: {text} for {', '.join(labels)}" for text, labels in falling.items()]


def plot(path: str, results: dict[str, AllanResult], title: str, unit: str = "deg/h") -> None:
    """Log-log figure of the curves of a rate in `unit` (g for an accelerometer), written as PNG at `path`
    (matplotlib, Agg backend); DeviceError when it cannot be written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axis = plt.subplots(figsize=(7.0, 4.5))
    for label, result in results.items():
        bias = "not reached" if result.bias_instability_dph is None else f"{result.bias_instability_dph:.3g} {unit}"
        name, value = white_noise(result, unit)
        quantity, _, noise_unit = name.partition(" (")
        axis.loglog(result.tau_s, result.adev_dph, "o-", ms=3,
                    label=f"{label} ({quantity} {value:.3g} {noise_unit.rstrip(')')}, BI {bias})")  # fmt: skip
    axis.set_xlabel("tau (s)")
    axis.set_ylabel(f"Allan deviation ({unit})")
    axis.set_title(title)
    axis.grid(True, which="both", alpha=0.4)
    axis.legend(fontsize=8)
    figure.tight_layout()
    try:
        with replaced(path, binary=True) as stream:  # at `path` as given: no ".png" appended behind the caller's back
            figure.savefig(stream, dpi=120, format="png")
    finally:
        plt.close(figure)
