"""`fogd-sim`: write a simulated thermal-chamber FOG run as a CSV (`t_s,rate_dph,temp_c,true_error_dph`), or with
--imu a three-axis IMU's (`t_s,rate_x_dph,...,accel_z_g,temp_c,true_error_<channel>...`).

This module owns the command line only: parsing and checking options, turning them into a profile and
`SimParams`, and writing the run with `fogd.core.runio.write_csv`. The physics lives in `fogd.simulation.simulator`, the
chamber profiles in `fogd.simulation.profiles`.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from collections.abc import Callable

import numpy as np

from fogd.cli.common import ArgumentParser
from fogd.core.atomic import check_output
from fogd.core.columns import ACCEL_CHANNELS, truth_column
from fogd.core.numbers import number_in, seed
from fogd.core.runio import write_csv
from fogd.errors import FogdError, UsageError
from fogd.simulation import profiles
from fogd.simulation.simulator import (
    IMU_CHANNELS,
    MAX_COIL_NODES,
    MAX_RATE_HZ,
    MIN_RATE_HZ,
    NOISE_PRESETS,
    SENSOR_MOUNTS,
    THERMAL_STRUCTURES,
    SimParams,
    Simulation,
    params_for,
)

PROG = "fogd-sim"
DEFAULTS = SimParams()
positive_s = number_in(0.0, 1e6, "s", low_open=True)


def coil_nodes(text: str) -> int:
    """An argparse type: a whole number of coil layers within 2..MAX_COIL_NODES."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if not 2 <= value <= MAX_COIL_NODES:
        raise argparse.ArgumentTypeError(f"{text!r} is outside 2..{MAX_COIL_NODES}")
    return value


def _parser() -> argparse.ArgumentParser:
    builtins = "\n".join(f"  {name:16s} {profiles.summary(name)}" for name in profiles.names())
    parser = ArgumentParser(
        prog=PROG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Simulate a fibre-optic gyro in a thermal chamber and write the run as CSV with columns\n"
        "t_s (s), rate_dph (deg/h), temp_c (the temperature sensor's report, C) and true_error_dph\n"
        "(the thermal error alone, deg/h; rate_dph - true_error_dph is the best possible compensation).\n"
        "With --imu: a three-axis IMU instead, t_s, rate_x_dph, rate_y_dph, rate_z_dph (deg/h), accel_x_g,\n"
        "accel_y_g, accel_z_g (g; gravity on z), temp_c and true_error_<channel> for each; rate_z_dph is the\n"
        "single-axis rate_dph of the same seed, number for number, and every other channel has its own\n"
        "thermal error (other coefficients and signs, of the same coil temperatures) and its own noise.",
        epilog=f"built-in profiles:\n{builtins}\n\n"
        "A profile file is a YAML list of [duration_s, target_c] pairs: the run starts at the first target\n"
        "and each segment moves linearly to its target over its duration (a soak repeats the target).",
    )
    add = parser.add_argument
    add("--profile", metavar="NAME|FILE", help="a built-in profile name or a YAML profile file (required)")
    add("-o", "--output", metavar="PATH", help="CSV file to write, '-' for stdout (required)")
    add("--rate-hz", metavar="HZ", type=number_in(MIN_RATE_HZ, MAX_RATE_HZ, "Hz"), default=200.0,
        help=f"gyro output rate, {MIN_RATE_HZ:g}..{MAX_RATE_HZ:g} Hz (default: 200)")
    add("--seed", metavar="N", type=seed, default=1, help="random seed; the same seed gives the same file (default: 1)")
    add("--sensor-resolution-c", metavar="C", type=number_in(0.0, math.inf, "C", low_open=True), default=DEFAULTS.sensor_resolution_c,
        help=f"temperature sensor quantum, C (default: {DEFAULTS.sensor_resolution_c:g}, a DS18B20; "
        "1 for whole degrees)")
    add("--sensor-rate-hz", metavar="HZ", type=number_in(0.0, math.inf, "Hz", low_open=True), default=DEFAULTS.sensor_rate_hz,
        help=f"temperature sensor update rate, Hz; held between updates (default: {DEFAULTS.sensor_rate_hz:g})")
    add("--sensor-tau-s", metavar="S", type=positive_s, default=DEFAULTS.sensor_tau_s,
        help=f"temperature sensor's lag behind the part it is mounted on, s (default: {DEFAULTS.sensor_tau_s:g})")
    add("--sensor-on", choices=SENSOR_MOUNTS, default=DEFAULTS.sensor_on,
        help=f"where the sensor is mounted: {' or '.join(SENSOR_MOUNTS)}, a plate between the chamber air and "
        f"the housing (default: {DEFAULTS.sensor_on})")
    add("--baseplate-tau-s", metavar="S", type=positive_s, default=None,
        help=f"baseplate's lag behind the air, s; with --sensor-on baseplate (default: {DEFAULTS.baseplate_tau_s:g})")
    add("--housing-tau-s", metavar="S", type=positive_s, default=DEFAULTS.housing_tau_s,
        help=f"housing's lag behind the air (or the baseplate), s (default: {DEFAULTS.housing_tau_s:g})")
    add("--thermal", choices=THERMAL_STRUCTURES, default=DEFAULTS.thermal,
        help="the coil's thermal structure: lumped (an outer and an inner layer, each lagging the one outside) "
        f"or diffusive (a chain of layers exchanging heat with their neighbours) (default: {DEFAULTS.thermal})")
    add("--coil-nodes", metavar="N", type=coil_nodes, default=None,
        help=f"layers in the diffusive coil, 2..{MAX_COIL_NODES}; with --thermal diffusive "
        f"(default: {DEFAULTS.coil_nodes})")
    presets = "; ".join(f"{name}: ARW {values['arw_dpsh']:g} deg/sqrt(h), bias instability "
                        f"{values['bias_instability_dph']:g} deg/h"
                        + (f", hysteresis {values['hysteresis_dph']:g} deg/h" if "hysteresis_dph" in values else "")
                        for name, values in NOISE_PRESETS.items())  # fmt: skip
    add("--noise", choices=NOISE_PRESETS, default=None,
        help=f"gyro noise grade ({presets}); --arw-dpsh and --bias-instability-dph override it "
        "(default: tactical)")
    add("--arw-dpsh", metavar="DPSH", type=number_in(0.0, 10.0, "deg/sqrt(h)"), default=None,
        help=f"angle random walk, deg/sqrt(h) (default: {DEFAULTS.arw_dpsh:g}, or the --noise grade's)")
    add("--bias-instability-dph", metavar="DPH", type=number_in(0.0, 100.0, "deg/h"), default=None,
        help=f"bias instability, deg/h (default: {DEFAULTS.bias_instability_dph:g}, or the --noise grade's)")
    add("--turn-on-bias-dph", metavar="DPH", type=number_in(0.0, 100.0, "deg/h"), default=DEFAULTS.turn_on_bias_dph,
        help="std of the turn-on bias, a constant drawn once per run (per seed), deg/h "
        f"(default: {DEFAULTS.turn_on_bias_dph:g})")
    add("--latitude-deg", metavar="DEG", type=number_in(-90.0, 90.0, "deg"), default=DEFAULTS.latitude_deg,
        help=f"latitude for the Earth rate on the vertical sensing axis, deg (default: {DEFAULTS.latitude_deg:g})")
    add("--no-noise", action="store_true",
        help="no ARW, bias instability, turn-on bias or sensor noise (Earth rate and quantisation stay)")
    add("--imu", action="store_true",
        help="write a three-axis IMU (three gyros, three accelerometers) instead of the single-axis gyro")
    add("--list-profiles", action="store_true", help="print the built-in profile names and exit")
    return parser


def main(argv: list[str] | None = None) -> int:
    try:
        return _run(_parser().parse_args(argv))
    except FogdError as error:
        print(f"{PROG}: {error}", file=sys.stderr)
        return error.exit_status
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130


def _run(args: argparse.Namespace) -> int:
    if args.list_profiles:
        print("\n".join(profiles.names()))
        return 0
    missing = [option for option, value in (("--profile", args.profile), ("-o/--output", args.output)) if not value]
    if missing:
        raise UsageError(f"missing {' and '.join(missing)} (see {PROG} --help)")
    params = _params(args)
    profile = profiles.resolve(args.profile)
    check_output(args.output)  # before the simulation, not after it
    if args.no_noise:
        params = params.without_noise()
    started = time.perf_counter()
    run = Simulation(profile, args.rate_hz, args.seed, params)
    try:
        _write(args.output, run, imu=args.imu)
    except BrokenPipeError:
        # The reader (e.g. `head`) has gone: stop quietly like other Unix filters.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    if args.output != "-":
        print(
            f"{PROG}: wrote {args.output}: {run.rows} rows, {profile.duration_s / 3600:.2f} h at "
            f"{run.rate_hz:g} Hz in {time.perf_counter() - started:.1f} s",
            file=sys.stderr,
        )
    return 0


def _params(args: argparse.Namespace) -> SimParams:
    """SimParams from the options; an option that the chosen structure or mount would ignore is refused."""
    if args.coil_nodes is not None and args.thermal != "diffusive":
        raise UsageError(f"--coil-nodes applies to --thermal diffusive only (see {PROG} --help)")
    if args.baseplate_tau_s is not None and args.sensor_on != "baseplate":
        raise UsageError(f"--baseplate-tau-s applies to --sensor-on baseplate only (see {PROG} --help)")
    given = {
        "arw_dpsh": args.arw_dpsh,
        "bias_instability_dph": args.bias_instability_dph,
        "coil_nodes": args.coil_nodes,
        "baseplate_tau_s": args.baseplate_tau_s,
    }
    return params_for(
        args.noise or "tactical",
        args.thermal,
        sensor_resolution_c=args.sensor_resolution_c,
        sensor_rate_hz=args.sensor_rate_hz,
        sensor_tau_s=args.sensor_tau_s,
        sensor_on=args.sensor_on,
        housing_tau_s=args.housing_tau_s,
        turn_on_bias_dph=args.turn_on_bias_dph,
        latitude_deg=args.latitude_deg,
        **{name: value for name, value in given.items() if value is not None},
    )


def _write(path: str, run: Simulation, imu: bool = False) -> None:
    params = run.params
    comments = [
        f"fogd-sim run: profile {run.profile.name} ({run.profile.describe()})",
        f"seed {run.seed}, rate {run.rate_hz:g} Hz, duration {run.profile.duration_s:g} s",
        f"thermal: {_structure(params)}; housing lag {params.housing_tau_s:g} s",
        f"sensor: {params.sensor_on} temperature, lag {params.sensor_tau_s:g} s, {params.sensor_rate_hz:g} Hz, "
        f"resolution {params.sensor_resolution_c:g} C, noise {params.sensor_noise_c:g} C"
        + (f", baseplate lag {params.baseplate_tau_s:g} s" if params.sensor_on == "baseplate" else ""),
        f"noise: ARW {params.arw_dpsh:g} deg/sqrt(h), bias instability {params.bias_instability_dph:g} deg/h, "
        f"turn-on bias {run.turn_on_bias_dph:+.6f} deg/h, Earth rate {run.earth_rate_dph:.6f} deg/h "
        f"(latitude {params.latitude_deg:g} deg)",
        "true_error_dph is the thermal error alone; rate_dph - true_error_dph is the best possible compensation",
    ]
    temp_format = f"%.{_decimals(params.sensor_resolution_c)}f"
    if imu:
        comments[-1] = ("an IMU: gravity on z; true_error_<channel> is that channel's thermal error alone (deg/h or g); "
                        f"accelerometer noise {params.accel_noise_g:g} g x sqrt(rate), turn-on bias "
                        f"{params.accel_turn_on_bias_g:g} g")  # fmt: skip
        blocks = _Blocks(run, run.imu_columns)
        formats = {"t_s": "%.6f"}
        formats.update({name: "%.9f" if name in ACCEL_CHANNELS else "%.6f" for name in IMU_CHANNELS})
        formats["temp_c"] = temp_format
        formats.update({truth_column(name): "%.10f" if name in ACCEL_CHANNELS else "%.7f" for name in IMU_CHANNELS})
    else:
        blocks = _Blocks(run, run.columns)
        formats = {"t_s": "%.6f", "rate_dph": "%.6f", "temp_c": temp_format, "true_error_dph": "%.7f"}
    columns = {name: _Column(blocks, name) for name in formats}
    write_csv(path, columns, formats, comments=comments)


class _Blocks:
    """The run's rows made one slice at a time; write_csv asks every column for the same slice in turn."""

    def __init__(self, run: Simulation, make: Callable[[int, int], dict[str, np.ndarray]]) -> None:
        self.run = run
        self.make = make
        self.rows: tuple[int, int] | None = None
        self.columns: dict[str, np.ndarray] = {}

    def get(self, name: str, start: int, stop: int) -> np.ndarray:
        if self.rows != (start, stop):
            self.rows, self.columns = (start, stop), self.make(start, stop)
        return self.columns[name]


class _Column:
    """A column that write_csv can take (len and slicing) without the whole run being in memory."""

    def __init__(self, blocks: _Blocks, name: str) -> None:
        self.blocks, self.name = blocks, name

    def __len__(self) -> int:
        return self.blocks.run.rows

    def __getitem__(self, rows: slice) -> np.ndarray:
        start, stop, _ = rows.indices(len(self))
        return self.blocks.get(self.name, start, stop) + 0.0  # -0.0 (a sensor rounding to 0 from below) as 0


def _structure(params: SimParams) -> str:
    if params.thermal == "lumped":
        return (f"lumped coil, outer layer lag {params.coil_outer_tau_s:g} s, inner layer lag "
                f"{params.coil_inner_tau_s:g} s")
    return (f"diffusive coil, {params.coil_nodes} layers, outermost lag {params.coil_outer_tau_s:g} s, innermost "
            f"{params.coil_diffusion_tau_s:g} s behind it")


def _decimals(resolution_c: float) -> int:
    """Fewest decimals that print every multiple of the sensor's resolution exactly (at most 6)."""
    for decimals in range(7):
        scaled = resolution_c * 10**decimals
        if abs(scaled - round(scaled)) < 1e-9 * max(1.0, scaled):
            return decimals
    return 6


if __name__ == "__main__":
    sys.exit(main())
