"""`fogd-emu`: a FOG on a pseudo-terminal, for tests, CI and the demo (like gpsd's gpsfake). This module owns
the command line only: options, building the source, faults and `fogd.simulation.emulator.Emulator`, printing the pty
path(s) on stdout and the summary on stderr, and stopping cleanly on SIGTERM/SIGINT.
"""

from __future__ import annotations

import argparse
import logging
import math
import signal
import sys
from typing import Sequence

from fogd import protocols
from fogd.cli.common import ArgumentParser, run
from fogd.core.numbers import (
    non_negative_float,
    positive_float,
    positive_int,
    probability,
    seed,
)
from fogd.core.runio import read_run
from fogd.errors import UsageError
from fogd.protocols.kvh import ANGLE_UNITS as KVH_ANGLE_UNITS
from fogd.protocols.kvh import LIN_UNITS as KVH_LIN_UNITS
from fogd.protocols.kvh import LINFMTS as KVH_LINFMTS
from fogd.protocols.kvh import ROTFMTS as KVH_ROTFMTS
from fogd.protocols.kvh import TEMP_UNITS as KVH_TEMP_UNITS
from fogd.simulation import profiles
from fogd.simulation.emulator import Emulator, Faults, RunSource, SimSource

UNIT_DEFAULTS = {"rotfmt": "rate", "angle_unit": "rad", "linfmt": "accel", "lin_unit": "m", "temp_unit": "C"}

PROG = "fogd-emu"
DEFAULT_RATE_HZ = 200.0


def parser() -> ArgumentParser:
    p = ArgumentParser(
        prog=PROG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Emulate a fibre-optic gyro on a pseudo-terminal. Prints the pty's path as the first line on\n"
        "stdout (and each new path after an unplug), then streams frames from the simulator (--profile) or a\n"
        "recorded run (--csv t_s,rate_dph,temp_c) until the data, --count or --duration-s ends, or SIGTERM/SIGINT;\n"
        "then waits (at most --drain-s) for the reader to take what was written, and prints a summary on stderr.\n"
        "An IMU (--profile with --imu, or a --csv run with rate_x_dph..accel_z_g columns) streams every channel:\n"
        "kvh-a frames and fogd IMU frames (type 04, temperature in each) carry three gyros and three accelerometers.",
        epilog="protocols: kvh-a = KVH Format A (rate on z in rad/s float32, x = y = 0, whole-degree temperature,\n"
        "status 0x77, seq 0..127; an IMU: all six channels in the unit settings below); fogd = fogd rate frames at the sample rate and temperature frames at\n"
        "--temp-rate-hz, each with its own sequence and device time; ascii = fogd 'I,t_s,rate_dph,temp_c' lines.\n"
        "A reader that is slow (or absent) slows the emulator; nothing is lost or reordered unless --drop-when-full.\n"
        "ledger: one JSON line per frame: index, sample, kind, seq, t_s, faults, sent, valid, rate_dph, rate_ok,\n"
        "temp_c (as carried on the wire), bytes, garbage_bytes; from an IMU also rates_dph and accel_g (x, y, z).",
    )
    add = p.add_argument
    add("--protocol", choices=protocols.names(), default="kvh-a", help="wire protocol (default: kvh-a)")
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--profile", metavar="NAME|FILE.yaml",
                        help=f"simulate a chamber profile: {', '.join(profiles.names())}, or a YAML file")
    source.add_argument("--csv", metavar="RUN.csv", help="play a recorded run (columns t_s,rate_dph,temp_c) at its own rate (see --speed)")
    add("--rate-hz", metavar="HZ", type=positive_float,
        help=f"sample rate for --profile, 1..5000 Hz (default: {DEFAULT_RATE_HZ:g})")
    add("--seed", metavar="N", type=seed, help="simulator seed for --profile (default: 1)")
    add("--imu", action="store_true",
        help="with --profile: simulate a three-axis IMU (three gyros, three accelerometers with gravity on z)")
    add("--temp-rate-hz", metavar="HZ", type=positive_float, default=10.0,
        help="fogd protocol: temperature frames per second, at most the sample rate (default: 10)")
    pacing = p.add_mutually_exclusive_group()
    pacing.add_argument("--speed", metavar="X", type=positive_float, default=1.0,
                        help="play X times faster than real time, still paced (default: 1)")
    pacing.add_argument("--fast", action="store_true", help="no pacing: as fast as the reader takes the frames")
    end = p.add_mutually_exclusive_group()
    end.add_argument("--count", metavar="N", type=positive_int, help="stop after N samples (rate frames)")
    end.add_argument("--duration-s", metavar="S", type=positive_float, help="stop after S seconds of data")
    add("--loop", action="store_true", help="repeat the data at its end (device time keeps counting)")
    add("--link", metavar="PATH", help="make PATH a symlink to the pty (re-pointed after an unplug; removed at exit)")
    add("--wait-reader", action="store_true",
        help="send nothing until a reader has opened the pty (at start and after each unplug)")
    add("--drop-when-full", action="store_true",
        help="drop (and count) frames the pty cannot take instead of waiting for the reader")
    add("--drain-s", metavar="S", type=non_negative_float, default=2.0,
        help="at exit, wait at most S seconds for the reader to take the written bytes (default: 2)")
    add("--ledger", metavar="PATH.jsonl", help="write one JSON line per frame: what was sent and injected")
    unit = p.add_argument_group("kvh-a unit settings (what the emulated unit is set to; its data rate =DR is the "
                                "sample rate)")  # fmt: skip
    unit.add_argument("--rotfmt", choices=KVH_ROTFMTS, default="rate",
                      help="=ROTFMT: gyros as rate (angle/s) or delta (angle per sample) (default: rate)")
    unit.add_argument("--angle-unit", choices=KVH_ANGLE_UNITS, default="rad", help="=ROTUNITS (default: rad)")
    unit.add_argument("--linfmt", choices=KVH_LINFMTS, default="accel",
                      help="=LINFMT: accelerometers as accel (g) or delta (velocity change per sample) (default: accel)")
    unit.add_argument("--lin-unit", choices=KVH_LIN_UNITS, default="m",
                      help="=LINUNITS: delta velocity in m/s or ft/s (default: m)")
    unit.add_argument("--temp-unit", choices=KVH_TEMP_UNITS, default="C", help="=TEMPUNITS (default: C)")
    faults = p.add_argument_group("faults (probabilities per frame, 0..1; all drawn from --fault-seed)")
    fault = faults.add_argument
    fault("--garbage", metavar="P", type=probability, default=0.0, help="1..16 random bytes before a frame (ascii: a non-ASCII line)")
    fault("--bitflip", metavar="P", type=probability, default=0.0, help="flip one bit (a bad CRC)")
    fault("--drop", metavar="P", type=probability, default=0.0, help="drop a frame (a sequence gap)")
    fault("--repeat", metavar="P", type=probability, default=0.0, help="send a frame twice")
    fault("--nan", metavar="P", type=probability, default=0.0, help="NaN rate, with a good CRC")
    fault("--clear-status", metavar="P", type=probability, default=0.0,
          help="clear a gyro-valid status bit (kvh-a: x, y or z; fogd: z)")
    fault("--split", metavar="P", type=probability, default=0.0, help="cut a frame in two writes, 2 ms apart")
    fault("--unplug-every-s", metavar="S", type=positive_float,
          help="after S seconds connected, close the pty (the device vanishes), then open a new one")
    fault("--unplug-for-s", metavar="D", type=non_negative_float, default=1.0,
          help="seconds unplugged; frames due meanwhile are lost (default: 1)")
    fault("--fault-seed", metavar="N", type=seed, default=0, help="seed for every fault (default: 0)")
    return p


def build(args: argparse.Namespace) -> Emulator:
    """The emulator the parsed options describe."""
    if args.csv is not None:
        for option, value in (("--rate-hz", args.rate_hz), ("--seed", args.seed)):
            if value is not None:
                raise UsageError(f"{option} applies to --profile; a --csv run plays at its own rate (use --speed)")
        source = RunSource(read_run(args.csv))
        if args.imu and not source.imu:
            raise UsageError(f"--imu: {args.csv} is a single-axis run (t_s,rate_dph,temp_c); a multi-channel run plays as an IMU by itself")
    else:
        profile = profiles.resolve(args.profile)
        source = SimSource(profile, args.rate_hz or DEFAULT_RATE_HZ, 1 if args.seed is None else args.seed, imu=args.imu)
    unit = {name: getattr(args, name) for name in UNIT_DEFAULTS}
    changed = [f"--{name.replace('_', '-')}" for name, value in unit.items() if value != UNIT_DEFAULTS[name]]
    if changed and args.protocol != "kvh-a":
        raise UsageError(f"{', '.join(changed)} set a KVH unit's output: they apply to --protocol kvh-a only")
    count = args.count
    if args.duration_s is not None:
        count = max(1, math.floor(args.duration_s * source.rate_hz + 0.5))
    faults = Faults(
        garbage=args.garbage, bitflip=args.bitflip, drop=args.drop, repeat=args.repeat, nan=args.nan,
        clear_status=args.clear_status, split=args.split, unplug_every_s=args.unplug_every_s,
        unplug_for_s=args.unplug_for_s, seed=args.fault_seed,
    )
    return Emulator(
        source, args.protocol, speed=None if args.fast else args.speed, count=count, loop=args.loop,
        temp_rate_hz=args.temp_rate_hz,
        faults=faults, link=args.link, ledger=args.ledger, drop_when_full=args.drop_when_full,
        wait_reader=args.wait_reader, drain_timeout_s=args.drain_s, on_replug=lambda path: print(path, flush=True),
        protocol_options=unit if args.protocol == "kvh-a" else None,
    )


def body(argv: Sequence[str] | None) -> int:
    logging.basicConfig(stream=sys.stderr, level=logging.WARNING, format="%(name)s: %(message)s")
    emulator = build(parser().parse_args(argv))
    print(emulator.start(), flush=True)
    stop = lambda signum, frame: emulator.stop()  # noqa: E731
    previous = {signum: signal.signal(signum, stop) for signum in (signal.SIGTERM, signal.SIGINT)}
    try:
        while not emulator.join(0.2):
            pass
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        print(f"{PROG}: {emulator.stats.summary()}", file=sys.stderr)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    return run(PROG, body, argv)


if __name__ == "__main__":
    sys.exit(main())
