"""Physics-based simulation of a FOG in a thermal chamber: the run a real chamber test would record.

This module owns the physics (`SimParams`, `simulate`, `Simulation`) and the named variants a run can be
made with: the noise grades (`NOISE_PRESETS`), the coil's thermal structures (`THERMAL_STRUCTURES`) and the
sensor's mountings (`SENSOR_MOUNTS`), combined by `params_for`.

The chamber air follows the profile's setpoint through a first-order lag; the FOG housing lags the air
(through a baseplate node when the sensor is mounted there). The fibre coil is either "lumped" (an outer
layer lagging the housing and an inner layer lagging the outer one) or "diffusive" (a chain of
`coil_nodes` layers exchanging heat with their neighbours, the outermost with the housing). The
temperature sensor lags the part it is mounted on. These states are integrated exactly (matrix
exponential, first-order hold on the setpoint) on a coarse thermal step and interpolated to the output
rate. The thermal error is driven by the COIL temperatures (a cubic static term, the Shupe terms of the
paper's eq. 3-4 in the coil's mean temperature rate and radial-gradient rate, and a heating/cooling
hysteresis), so a model fed the sensor's temperature can never be perfect. Angle random walk, bias
instability, a turn-on bias and the Earth rate are added on top and are not part of `true_error_dph`. The
sensor reports a slow, noisy, quantised, sample-and-hold temperature. Everything is seeded and
reproducible.

`Simulation.imu_columns` makes the same run as a three-axis IMU (`IMU_CHANNELS`): z is the single-axis gyro
above, number for number; x and y are gyros whose thermal errors are other functions of the same coil states
(other coefficients and signs, the static term taken nearer the outer or the inner layer); three
accelerometers (g, gravity on z) have their own thermal errors of the same coil states, their play hysteresis
in proportion to the gyro's. Every channel draws its own noise, and each has its own true-error column.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np
from scipy.linalg import expm
from scipy.signal import lfilter

from fogd.core.columns import ACCEL_CHANNELS, CHANNELS, GYRO_CHANNELS, truth_column
from fogd.simulation.profiles import Profile

EARTH_RATE_DPH = 15.041
MIN_RATE_HZ = 1.0
MAX_RATE_HZ = 5000.0
THERMAL_STRUCTURES = ("lumped", "diffusive")
SENSOR_MOUNTS = ("housing", "baseplate")
MAX_COIL_NODES = 50

# Noise grades (SimParams fields). "tactical" is SimParams' default, where the thermal error is only 1.4-3.4x
# the noise floor of 100 s block means and every model looks alike. "navigation" is a gyro like the paper's:
# 30-100x on the built-in profiles in both structures (medians over seeds: paper-test ~33, cooling ~91). That
# window is barely wider than the profiles' own spread of error, so a run now and then lands just outside.
NOISE_PRESETS: dict[str, dict[str, float]] = {
    "tactical": {"arw_dpsh": 0.004, "bias_instability_dph": 0.005},
    # A gyro like the paper's: its thermal error is 30-100x the 100 s noise floor, and (as its 99.5 % in-sample
    # fit from T and dT/dt shows) almost all of it follows the temperature history; the play hysteresis that
    # no finite thermal memory can describe is kept near the noise floor.
    "navigation": {"arw_dpsh": 0.00014, "bias_instability_dph": 0.0001, "hysteresis_dph": 0.001},
}


@dataclass(frozen=True)
class SimParams:
    """Physical parameters of the chamber, the FOG and its temperature sensor (units in the names)."""

    chamber_tau_s: float = 120.0
    housing_tau_s: float = 1500.0
    coil_outer_tau_s: float = 300.0  # the outermost coil layer's lag behind the housing on a steady ramp
    coil_inner_tau_s: float = 240.0  # lumped: the inner layer's lag behind the outer one
    thermal: str = "lumped"  # one of THERMAL_STRUCTURES
    coil_nodes: int = 6  # diffusive: layers in the chain; the two ramp lags hold whatever the count
    coil_diffusion_tau_s: float = 400.0  # diffusive: the innermost node's lag behind the outermost on a ramp
    sensor_on: str = "housing"  # one of SENSOR_MOUNTS
    baseplate_tau_s: float = 300.0  # sensor_on="baseplate": the plate lags the air and the housing lags it
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
    accel_noise_g: float = 2e-5  # accelerometer white noise: per-sample std = this x sqrt(rate_hz), g
    accel_turn_on_bias_g: float = 2e-4  # std of each accelerometer's turn-on bias, g

    def __post_init__(self) -> None:
        positive = ("chamber_tau_s", "housing_tau_s", "coil_outer_tau_s", "coil_inner_tau_s",
                    "coil_diffusion_tau_s", "baseplate_tau_s", "sensor_tau_s", "sensor_rate_hz",
                    "sensor_resolution_c", "static_half_span_c", "hysteresis_deadband_c", "thermal_step_s")
        non_negative = ("sensor_noise_c", "hysteresis_dph", "arw_dpsh", "bias_instability_dph", "turn_on_bias_dph",
                        "accel_noise_g", "accel_turn_on_bias_g")
        for name, allowed in (("thermal", THERMAL_STRUCTURES), ("sensor_on", SENSOR_MOUNTS)):
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name} must be one of {', '.join(allowed)}, got {getattr(self, name)!r}")
        nodes = self.coil_nodes
        if isinstance(nodes, bool) or not isinstance(nodes, int) or not 2 <= nodes <= MAX_COIL_NODES:
            raise ValueError(f"coil_nodes must be a whole number within 2..{MAX_COIL_NODES}, got {nodes!r}")
        for field in fields(self):
            value = getattr(self, field.name)
            if isinstance(value, str):
                continue
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
        return replace(self, sensor_noise_c=0.0, arw_dpsh=0.0, bias_instability_dph=0.0, turn_on_bias_dph=0.0,
                       accel_noise_g=0.0, accel_turn_on_bias_g=0.0)


def params_for(noise: str = "tactical", thermal: str = "lumped", **overrides: object) -> SimParams:
    """SimParams for a noise grade (NOISE_PRESETS) and thermal structure; `overrides` win over the preset.

    params_for() is SimParams(), today's default gyro.
    """
    if noise not in NOISE_PRESETS:
        raise ValueError(f"noise must be one of {', '.join(NOISE_PRESETS)}, got {noise!r}")
    return SimParams(**{**NOISE_PRESETS[noise], "thermal": thermal, **overrides})  # type: ignore[arg-type]


IMU_CHANNELS = CHANNELS  # rate_x_dph, rate_y_dph, rate_z_dph, accel_x_g, accel_y_g, accel_z_g
GRAVITY_G = (0.0, 0.0, 1.0)  # the IMU sits level, z up: +1 g on z, as a KVH reports it


@dataclass(frozen=True)
class ChannelError:
    """One IMU channel's thermal error as a function of the coil states, in the channel's unit (deg/h or g).

    The static cubic is taken at a mix of the coil's temperatures (`coil_mix` -1: the innermost layer, 0: the
    mean, +1: the outermost), the Shupe-like terms on the coil's mean temperature rate and gradient rate, and
    a play hysteresis of the mixed temperature."""

    static: tuple[float, float, float]
    rate_per_cps: float
    gradient_rate_per_cps: float
    hysteresis: float
    coil_mix: float


# x and y gyros as multiples of the single-axis (z) gyro's terms, so a noise grade or an override of SimParams
# scales all three; signs and the coil mix differ so that no channel is a multiple of another.
_GYRO_SCALES = {
    "rate_x_dph": ((-0.7, 1.3, -0.5), -0.6, 1.4, 0.8, 0.7),
    "rate_y_dph": ((-0.3, 2.0, 0.6), 1.3, -0.7, 1.2, -0.7),
}
# The accelerometers' own terms (g): a few mg over the chamber's span, like a tactical MEMS accelerometer. Their
# play hysteresis is given for SimParams' default gyro and follows the gyro's (hysteresis_dph) in proportion, as the
# x and y gyros' does: a grade that keeps the gyro's play near its noise floor (navigation: the play no finite
# thermal memory can describe) keeps theirs there too, and hysteresis_dph=0 removes every channel's.
ACCEL_ERRORS = {
    "accel_x_g": ChannelError((1.2e-3, -4e-4, 3e-4), 6e-2, 0.0, 5e-5, 1.0),
    "accel_y_g": ChannelError((-3e-4, 1.2e-3, -2e-4), -3e-2, 5e-3, 0.0, 0.3),
    "accel_z_g": ChannelError((-2e-4, 3e-4, 9e-4), 1e-2, -2e-2, 5e-5, -0.3),
}


def channel_errors(params: SimParams) -> dict[str, ChannelError]:
    """Every IMU channel's thermal error terms; rate_z_dph is the single-axis gyro's."""
    z = ChannelError(params.static_dph, params.shupe_rate_dph_per_cps, params.shupe_gradient_rate_dph_per_cps,
                     params.hysteresis_dph, 0.0)  # fmt: skip
    errors = {}
    for channel, (static, rate, gradient, hysteresis, mix) in _GYRO_SCALES.items():
        errors[channel] = ChannelError(
            tuple(k * c for k, c in zip(static, z.static)), rate * z.rate_per_cps,  # type: ignore[arg-type]
            gradient * z.gradient_rate_per_cps, hysteresis * z.hysteresis, mix,
        )  # fmt: skip
    errors["rate_z_dph"] = z
    play = params.hysteresis_dph / SimParams.hysteresis_dph  # the default gyro's play, for which ACCEL_ERRORS are given
    errors.update({channel: replace(error, hysteresis=error.hysteresis * play) for channel, error in ACCEL_ERRORS.items()})
    return {channel: errors[channel] for channel in IMU_CHANNELS}


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
    coil_outer_c: np.ndarray  # the outermost coil layer (node)
    coil_inner_c: np.ndarray  # the innermost coil layer (node)
    rate_hz: float
    seed: int
    turn_on_bias_dph: float
    earth_rate_dph: float
    params: SimParams
    profile: Profile


@dataclass(frozen=True)
class ThermalNetwork:
    """The thermal states as dx/dt = a x + b u (u the setpoint), and which state is which."""

    a: np.ndarray
    b: np.ndarray
    air: int
    housing: int
    coil: tuple[int, ...]  # outermost first
    sensor: int


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
        self.network = net = _network(params)
        self.grid_t_s, self.states, rates = _thermal_states(profile, params.thermal_step_s, net)
        coil = list(net.coil)
        coil_mean_c = self.states[coil].mean(axis=0)
        self.error_grid_dph = (
            _static_error_dph(coil_mean_c, params)
            # Shupe (eq. 3) as in IEEE 952's model (eq. 4): the coil's mean temperature rate and gradient rate.
            + params.shupe_rate_dph_per_cps * rates[coil].mean(axis=0)
            + params.shupe_gradient_rate_dph_per_cps * (rates[coil[0]] - rates[coil[-1]])
            + _hysteresis_dph(coil_mean_c, params)
        )
        self.bias_grid_dph = _bias_instability_dph(self.grid_t_s.size, params, bias_rng)
        self.turn_on_bias_dph = float(turn_on_rng.normal(0.0, params.turn_on_bias_dph))
        self.earth_rate_dph = EARTH_RATE_DPH * math.sin(math.radians(params.latitude_deg))  # vertical (zenith) axis
        self.sensor_c = _sensor_readings_c(self.duration_s, self.grid_t_s, self.states[net.sensor], params, sensor_rng)
        self._state_rates = rates
        self._imu: dict[str, tuple[np.ndarray, np.ndarray, float]] | None = None

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

    def imu_columns(self, start: int = 0, stop: int | None = None) -> dict[str, np.ndarray]:
        """Rows [start, stop) of the run as a three-axis IMU: t_s, the IMU_CHANNELS, temp_c, and
        true_error_<channel> for each. rate_z_dph and its truth are `columns`' rate_dph and true_error_dph."""
        single = self.columns(start, stop)
        t_s = single["t_s"]
        start, stop = int(start), int(start) + t_s.size
        columns = {"t_s": t_s}
        truths = {}
        for index, channel in enumerate(IMU_CHANNELS):
            if channel == "rate_z_dph":
                columns[channel], truths[channel] = single["rate_dph"], single["true_error_dph"]
                continue
            error_grid, bias_grid, offset = self._imu_grids()[channel]
            truth = np.interp(t_s, self.grid_t_s, error_grid)
            value = truth + offset + self._white(index, start, stop)
            if bias_grid is not None:
                value += np.interp(t_s, self.grid_t_s, bias_grid)
            columns[channel], truths[channel] = value, truth
        columns["temp_c"] = single["temp_c"]
        columns.update({truth_column(channel): truths[channel] for channel in IMU_CHANNELS})
        return columns

    def _imu_grids(self) -> dict[str, tuple[np.ndarray, np.ndarray | None, float]]:
        """Per channel (but z): thermal error and bias instability on the thermal grid, and the constant
        offset (turn-on bias plus Earth rate or gravity). Made once, on first use, from channel-own seeds."""
        if self._imu is not None:
            return self._imu
        params, net = self.params, self.network
        coil = list(net.coil)
        states, rates = self.states[coil], self._state_rates[coil]
        mean_c, mean_rate = states.mean(axis=0), rates.mean(axis=0)
        gradient_rate = rates[0] - rates[-1]
        earth = {"rate_x_dph": EARTH_RATE_DPH * math.cos(math.radians(params.latitude_deg)), "rate_y_dph": 0.0}
        self._imu = {}
        for index, (channel, error) in enumerate(channel_errors(params).items()):
            if channel == "rate_z_dph":
                continue
            mix = error.coil_mix
            coil_c = mean_c + max(mix, 0.0) * (states[0] - mean_c) + max(-mix, 0.0) * (states[-1] - mean_c)
            x = (coil_c - params.static_ref_c) / params.static_half_span_c
            c1, c2, c3 = error.static
            grid = x * (c1 + x * (c2 + x * c3)) + error.rate_per_cps * mean_rate + error.gradient_rate_per_cps * gradient_rate
            if error.hysteresis:
                grid = grid + error.hysteresis * _played(coil_c, params.hysteresis_deadband_c)
            turn_on_rng, bias_rng = (np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(key, index)))
                                     for key in (4, 5))  # fmt: skip
            if channel in GYRO_CHANNELS:
                bias = _bias_instability_dph(self.grid_t_s.size, params, bias_rng)
                offset = earth[channel] + float(turn_on_rng.normal(0.0, params.turn_on_bias_dph))
            else:
                bias = None  # the accelerometers' slow noise is not modelled: white noise and a turn-on bias
                offset = GRAVITY_G[ACCEL_CHANNELS.index(channel)] + float(turn_on_rng.normal(0.0, params.accel_turn_on_bias_g))
            self._imu[channel] = (grid, bias, offset)
        return self._imu

    def _white(self, index: int, start: int, stop: int) -> np.ndarray | float:
        """Channel `index`'s white noise for rows [start, stop), drawn per fixed block like `_arw_dph`."""
        gyro = IMU_CHANNELS[index] in GYRO_CHANNELS
        std = (60.0 * self.params.arw_dpsh if gyro else self.params.accel_noise_g) * math.sqrt(self.rate_hz)
        if std == 0 or stop <= start:
            return 0.0
        size = self.ARW_BLOCK_ROWS
        first, last = start // size, (stop - 1) // size
        blocks = [
            np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(6, index, block))).normal(0.0, std, size)
            for block in range(first, last + 1)
        ]
        return np.concatenate(blocks)[start - first * size : stop - first * size]

    def run(self) -> SimRun:
        """The whole run, with the thermal states at the output rate for diagnostics."""
        columns = self.columns()
        t_s = columns["t_s"]
        net = self.network
        return SimRun(
            **columns,
            setpoint_c=self.profile.setpoint_c(t_s),
            chamber_c=np.interp(t_s, self.grid_t_s, self.states[net.air]),
            housing_c=np.interp(t_s, self.grid_t_s, self.states[net.housing]),
            coil_outer_c=np.interp(t_s, self.grid_t_s, self.states[net.coil[0]]),
            coil_inner_c=np.interp(t_s, self.grid_t_s, self.states[net.coil[-1]]),
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


def _network(params: SimParams) -> ThermalNetwork:
    """The chamber, FOG and sensor as a linear thermal network (state order: air, housing, coil, sensor[, plate])."""
    lumped = params.thermal == "lumped"
    nodes = 2 if lumped else params.coil_nodes
    air, housing, coil, sensor = 0, 1, tuple(range(2, 2 + nodes)), 2 + nodes
    plate = sensor + 1 if params.sensor_on == "baseplate" else None
    size = sensor + (2 if plate is not None else 1)
    a = np.zeros((size, size))
    b = np.zeros(size)

    def couple(stage: int, source: int | None, tau_s: float) -> None:
        """`stage` relaxes towards `source` (the setpoint when None) with time constant `tau_s`."""
        a[stage, stage] -= 1.0 / tau_s
        if source is None:
            b[stage] += 1.0 / tau_s
        else:
            a[stage, source] += 1.0 / tau_s

    couple(air, None, params.chamber_tau_s)
    couple(housing, air if plate is None else plate, params.housing_tau_s)
    if lumped:
        couple(coil[0], housing, params.coil_outer_tau_s)
        couple(coil[1], coil[0], params.coil_inner_tau_s)
    else:
        # Equal layers: the housing contact carries the whole coil's heat (so the outermost node's ramp lag is
        # coil_outer_tau_s), and link j carries the heat of the nodes inside it (so the lags add up to
        # coil_diffusion_tau_s). The coil is too light to load the housing; its hub is adiabatic.
        couple(coil[0], housing, params.coil_outer_tau_s / nodes)
        link_tau_s = 2.0 * params.coil_diffusion_tau_s / (nodes * (nodes - 1))
        for outer, inner in zip(coil[:-1], coil[1:]):
            couple(outer, inner, link_tau_s)
            couple(inner, outer, link_tau_s)
    if plate is not None:
        couple(plate, air, params.baseplate_tau_s)
    couple(sensor, housing if plate is None else plate, params.sensor_tau_s)
    return ThermalNetwork(a, b, air, housing, coil, sensor)


def _thermal_states(profile: Profile, step_s: float, net: ThermalNetwork) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(grid times, states[n, k], state rates[n, k] in C/s) on the thermal step, starting soaked at the start."""
    grid_t_s = np.arange(int(math.ceil(profile.duration_s / step_s)) + 1) * step_s
    setpoint_c = profile.setpoint_c(grid_t_s)
    a, b = net.a, net.b
    n = b.size
    # Exact discretisation for a setpoint linear over each step: augment with u and du/dt and exponentiate.
    augmented = np.zeros((n + 2, n + 2))
    augmented[:n, :n] = a
    augmented[:n, n] = b
    augmented[n, n + 1] = 1.0
    transition = expm(augmented * step_s)
    phi, gain_u, gain_slope = transition[:n, :n], transition[:n, n], transition[:n, n + 1]
    slope_cps = np.append(np.diff(setpoint_c) / step_s, 0.0)
    states = np.empty((grid_t_s.size, n))
    state = np.full(n, profile.start_c)
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


def _played(coil_c: np.ndarray, width_c: float) -> np.ndarray:
    """The play operator's normalised output, (T - played) / width: +1 after heating, -1 after cooling."""
    played = np.empty_like(coil_c)
    position_c = float(coil_c[0])
    for k, temp_c in enumerate(coil_c.tolist()):
        position_c = min(max(position_c, temp_c - width_c), temp_c + width_c)
        played[k] = position_c
    return (coil_c - played) / width_c


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
