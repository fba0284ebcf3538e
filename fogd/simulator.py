"""Physics-based simulation of a FOG in a thermal chamber: the run a real chamber test would record.

The chamber air follows the profile's setpoint through a first-order lag; the FOG housing lags the air, the
fibre coil's outer layer lags the housing and its inner layer lags the outer layer; the temperature sensor
lags the housing. These five states are integrated exactly (matrix exponential, first-order hold on the
setpoint) on a coarse thermal step and interpolated to the output rate. The thermal error is driven by the
COIL temperatures (a cubic static term, the Shupe terms of the paper's eq. 3-4 in the coil's mean
temperature rate and radial-gradient rate, and a heating/cooling hysteresis), so a model fed the sensor's
temperature can never be perfect. Angle random walk, bias instability, a turn-on bias and the Earth rate
are added on top and are not part of `true_error_dph`. The sensor reports a slow, noisy, quantised,
sample-and-hold housing temperature. Everything is seeded and reproducible.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np
from scipy.linalg import expm
from scipy.signal import lfilter

from fogd.profiles import Profile

EARTH_RATE_DPH = 15.041
MIN_RATE_HZ = 1.0
MAX_RATE_HZ = 5000.0


@dataclass(frozen=True)
class SimParams:
    """Physical parameters of the chamber, the FOG and its temperature sensor (units in the names)."""

    chamber_tau_s: float = 120.0
    housing_tau_s: float = 1500.0
    coil_outer_tau_s: float = 300.0
    coil_inner_tau_s: float = 240.0
    sensor_tau_s: float = 20.0
    sensor_rate_hz: float = 4.0
    sensor_resolution_c: float = 0.0625  # a DS18B20's LSB; 1.0 for a KVH's whole degrees
    sensor_noise_c: float = 0.01
    static_ref_c: float = 17.5
    static_half_span_c: float = 32.5
    static_dph: tuple[float, float, float] = (0.06, 0.04, 0.05)  # coefficients of x, x^2, x^3
    shupe_rate_dph_per_cps: float = 6.0
    shupe_gradient_rate_dph_per_cps: float = 20.0
    hysteresis_dph: float = 0.02
    hysteresis_deadband_c: float = 2.0
    arw_dpsh: float = 0.004
    bias_instability_dph: float = 0.005
    bias_corr_times_s: tuple[float, ...] = (20.0, 200.0, 2000.0)
    turn_on_bias_dph: float = 0.02
    latitude_deg: float = 30.5
    thermal_step_s: float = 0.5

    def __post_init__(self) -> None:
        positive = ("chamber_tau_s", "housing_tau_s", "coil_outer_tau_s", "coil_inner_tau_s", "sensor_tau_s",
                    "sensor_rate_hz", "sensor_resolution_c", "static_half_span_c", "hysteresis_deadband_c",
                    "thermal_step_s")
        non_negative = ("sensor_noise_c", "hysteresis_dph", "arw_dpsh", "bias_instability_dph", "turn_on_bias_dph")
        for field in fields(self):
            value = getattr(self, field.name)
            values = value if isinstance(value, tuple) else (value,)
            if not all(math.isfinite(v) for v in values):
                raise ValueError(f"{field.name} must be finite, got {value!r}")
            if field.name in positive and value <= 0:
                raise ValueError(f"{field.name} must be positive, got {value!r}")
            if field.name in non_negative and value < 0:
                raise ValueError(f"{field.name} must not be negative, got {value!r}")
        if any(tau <= 0 for tau in self.bias_corr_times_s):
            raise ValueError(f"bias_corr_times_s must be positive, got {self.bias_corr_times_s!r}")
        if abs(self.latitude_deg) > 90:
            raise ValueError(f"latitude_deg must be within -90..90, got {self.latitude_deg!r}")

    def without_noise(self) -> SimParams:
        """The same FOG with no random terms (the Earth rate and the sensor quantisation stay)."""
        return replace(self, sensor_noise_c=0.0, arw_dpsh=0.0, bias_instability_dph=0.0, turn_on_bias_dph=0.0)


@dataclass
class SimRun:
    """A simulated run at the output rate; coil, housing and chamber temperatures are for diagnostics."""

    t_s: np.ndarray
    rate_dph: np.ndarray
    temp_c: np.ndarray
    true_error_dph: np.ndarray
    setpoint_c: np.ndarray
    chamber_c: np.ndarray
    housing_c: np.ndarray
    coil_outer_c: np.ndarray
    coil_inner_c: np.ndarray
    rate_hz: float
    seed: int
    turn_on_bias_dph: float
    earth_rate_dph: float
    params: SimParams
    profile: Profile


# Thermal state order: chamber air, housing, coil outer layer, coil inner layer, sensor element.
_AIR, _HOUSING, _OUTER, _INNER, _SENSOR = range(5)


def simulate(profile: Profile, rate_hz: float, seed: int, params: SimParams | None = None) -> SimRun:
    """Simulate `profile` at `rate_hz` (1..5000 Hz) with the random terms drawn from `seed`."""
    return Simulation(profile, rate_hz, seed, params).run()


class Simulation:
    """One run's physics, prepared on the thermal step; output rows are made on demand, block by block.

    Rows [start, stop) are the same whichever blocks they are asked in, so a long run at a high rate can be
    written without holding it in memory.
    """

    ARW_BLOCK_ROWS = 1 << 16

    def __init__(self, profile: Profile, rate_hz: float, seed: int, params: SimParams | None = None) -> None:
        if not MIN_RATE_HZ <= rate_hz <= MAX_RATE_HZ:
            raise ValueError(f"rate_hz must be within {MIN_RATE_HZ:g}..{MAX_RATE_HZ:g} Hz, got {rate_hz!r}")
        self.profile = profile
        self.rate_hz = float(rate_hz)
        self.seed = seed
        self.params = params = params or SimParams()
        self.rows = int(math.floor(profile.duration_s * rate_hz + 1e-9)) + 1
        turn_on_rng, bias_rng, sensor_rng = (np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(key,)))
                                             for key in range(3))
        self.grid_t_s, self.states, rates = _thermal_states(profile, params)
        coil_mean_c = 0.5 * (self.states[_OUTER] + self.states[_INNER])
        self.error_grid_dph = (
            _static_error_dph(coil_mean_c, params)
            # Shupe (eq. 3) as in IEEE 952's model (eq. 4): the coil's mean temperature rate and gradient rate.
            + params.shupe_rate_dph_per_cps * 0.5 * (rates[_OUTER] + rates[_INNER])
            + params.shupe_gradient_rate_dph_per_cps * (rates[_OUTER] - rates[_INNER])
            + _hysteresis_dph(coil_mean_c, params)
        )
        self.bias_grid_dph = _bias_instability_dph(self.grid_t_s.size, params, bias_rng)
        self.turn_on_bias_dph = float(turn_on_rng.normal(0.0, params.turn_on_bias_dph))
        self.earth_rate_dph = EARTH_RATE_DPH * math.sin(math.radians(params.latitude_deg))  # vertical (zenith) axis
        self.sensor_c = _sensor_readings_c(self.duration_s, self.grid_t_s, self.states[_SENSOR], params, sensor_rng)

    @property
    def duration_s(self) -> float:
        return (self.rows - 1) / self.rate_hz

    def columns(self, start: int = 0, stop: int | None = None) -> dict[str, np.ndarray]:
        """Rows [start, stop) as the CSV columns t_s, rate_dph, temp_c, true_error_dph."""
        stop = self.rows if stop is None else min(stop, self.rows)
        t_s = np.arange(start, stop) / self.rate_hz
        true_error_dph = np.interp(t_s, self.grid_t_s, self.error_grid_dph)
        rate_dph = true_error_dph + np.interp(t_s, self.grid_t_s, self.bias_grid_dph)
        rate_dph += self.earth_rate_dph + self.turn_on_bias_dph + self._arw_dph(start, stop)
        held = np.floor(t_s * self.params.sensor_rate_hz + 1e-9).astype(np.int64)
        temp_c = self.sensor_c[np.minimum(held, self.sensor_c.size - 1)]
        return {"t_s": t_s, "rate_dph": rate_dph, "temp_c": temp_c, "true_error_dph": true_error_dph}

    def run(self) -> SimRun:
        """The whole run, with the thermal states at the output rate for diagnostics."""
        columns = self.columns()
        t_s = columns["t_s"]
        return SimRun(
            **columns,
            setpoint_c=self.profile.setpoint_c(t_s),
            chamber_c=np.interp(t_s, self.grid_t_s, self.states[_AIR]),
            housing_c=np.interp(t_s, self.grid_t_s, self.states[_HOUSING]),
            coil_outer_c=np.interp(t_s, self.grid_t_s, self.states[_OUTER]),
            coil_inner_c=np.interp(t_s, self.grid_t_s, self.states[_INNER]),
            rate_hz=self.rate_hz,
            seed=self.seed,
            turn_on_bias_dph=self.turn_on_bias_dph,
            earth_rate_dph=self.earth_rate_dph,
            params=self.params,
            profile=self.profile,
        )

    def _arw_dph(self, start: int, stop: int) -> np.ndarray | float:
        """White rate noise for rows [start, stop): per-sample std 60 * ARW * sqrt(rate), drawn per fixed block."""
        std_dph = 60.0 * self.params.arw_dpsh * math.sqrt(self.rate_hz)
        if std_dph == 0 or stop <= start:
            return 0.0
        size = self.ARW_BLOCK_ROWS
        first, last = start // size, (stop - 1) // size
        blocks = [
            np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(3, block))).normal(0.0, std_dph, size)
            for block in range(first, last + 1)
        ]
        return np.concatenate(blocks)[start - first * size : stop - first * size]


def _thermal_states(profile: Profile, params: SimParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(grid times, states[5, n], state rates[5, n] in C/s) on the thermal step, starting soaked at the start."""
    step_s = params.thermal_step_s
    grid_t_s = np.arange(int(math.ceil(profile.duration_s / step_s)) + 1) * step_s
    setpoint_c = profile.setpoint_c(grid_t_s)
    # dx/dt = A x + b u: every stage is a first-order lag on the stage it is mounted in.
    a = np.zeros((5, 5))
    b = np.zeros(5)
    for stage, source, tau_s in (
        (_AIR, None, params.chamber_tau_s),
        (_HOUSING, _AIR, params.housing_tau_s),
        (_OUTER, _HOUSING, params.coil_outer_tau_s),
        (_INNER, _OUTER, params.coil_inner_tau_s),
        (_SENSOR, _HOUSING, params.sensor_tau_s),
    ):
        a[stage, stage] = -1.0 / tau_s
        if source is None:
            b[stage] = 1.0 / tau_s
        else:
            a[stage, source] = 1.0 / tau_s
    # Exact discretisation for a setpoint linear over each step: augment with u and du/dt and exponentiate.
    augmented = np.zeros((7, 7))
    augmented[:5, :5] = a
    augmented[:5, 5] = b
    augmented[5, 6] = 1.0
    transition = expm(augmented * step_s)
    phi, gain_u, gain_slope = transition[:5, :5], transition[:5, 5], transition[:5, 6]
    slope_cps = np.append(np.diff(setpoint_c) / step_s, 0.0)
    states = np.empty((grid_t_s.size, 5))
    state = np.full(5, profile.start_c)
    for k in range(grid_t_s.size):
        states[k] = state
        state = phi @ state + gain_u * setpoint_c[k] + gain_slope * slope_cps[k]
    rates = states @ a.T + np.outer(setpoint_c, b)
    return grid_t_s, states.T.copy(), rates.T.copy()


def _static_error_dph(coil_c: np.ndarray, params: SimParams) -> np.ndarray:
    """Nonlinear static term (the D_T term of eq. 4, extended to a cubic in the coil temperature)."""
    x = (coil_c - params.static_ref_c) / params.static_half_span_c
    c1, c2, c3 = params.static_dph
    return x * (c1 + x * (c2 + x * c3))


def _hysteresis_dph(coil_c: np.ndarray, params: SimParams) -> np.ndarray:
    """A play (backlash) operator on the coil temperature: +hysteresis after heating, - after cooling."""
    width_c = params.hysteresis_deadband_c
    played = np.empty_like(coil_c)
    position_c = float(coil_c[0])
    for k, temp_c in enumerate(coil_c.tolist()):
        position_c = min(max(position_c, temp_c - width_c), temp_c + width_c)
        played[k] = position_c
    return params.hysteresis_dph * (coil_c - played) / width_c


def _bias_instability_dph(size: int, params: SimParams, rng: np.random.Generator) -> np.ndarray:
    """A sum of Gauss-Markov processes, one per correlation time, each of stationary std B.

    Processes a decade apart with equal std give a roughly flat Allan deviation near 0.66 B, like flicker
    noise of bias instability B. Each is an exact AR(1) on the thermal step, started in its stationary state.
    """
    total_dph = np.zeros(size)
    sigma_dph = params.bias_instability_dph
    if sigma_dph == 0:
        return total_dph
    for tau_s in params.bias_corr_times_s:
        phi = math.exp(-params.thermal_step_s / tau_s)
        drive = rng.normal(0.0, sigma_dph * math.sqrt(1.0 - phi * phi), size)
        start = np.array([phi * rng.normal(0.0, sigma_dph)])
        total_dph += lfilter([1.0], [1.0, -phi], drive, zi=start)[0]
    return total_dph


def _sensor_readings_c(
    duration_s: float, grid_t_s: np.ndarray, element_c: np.ndarray, params: SimParams, rng: np.random.Generator
) -> np.ndarray:
    """The sensor's successive reports at its own rate: noisy and quantised (held between reports)."""
    samples = int(math.floor(duration_s * params.sensor_rate_hz + 1e-9)) + 1
    reading_c = np.interp(np.arange(samples) / params.sensor_rate_hz, grid_t_s, element_c)
    if params.sensor_noise_c > 0:
        reading_c = reading_c + rng.normal(0.0, params.sensor_noise_c, samples)
    return np.round(reading_c / params.sensor_resolution_c) * params.sensor_resolution_c
