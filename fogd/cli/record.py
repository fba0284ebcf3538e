"""`fogd-record`: record a run (CSV t_s,rate_dph,temp_c, what fogd-train reads) from a FOG's serial port.

It runs the daemon's reader thread (same lexer, same reconnect after an unplug) and writes one row per rate
sample of the chosen axis with the temperature held per frame; rate samples before the first temperature
are skipped. With --channels it writes every chosen channel of an IMU instead
(t_s,rate_x_dph,...,accel_z_g,temp_c, the channels the protocol carries; NaN where a frame marks one invalid). Time is the device's clock where the protocol has one, else the sample count / --rate-hz. With
--decimate N each row is the mean of N consecutive samples (time, rate and temperature): a 1 kHz gyro makes
about 700 MB in 5 hours, and fogd-train averages over 100 s blocks anyway. A
live status line shows frames, temperature, temperature rate (eq. 16 with the default window) and drops;
the file is flushed every second, and SIGINT/SIGTERM stop cleanly.
"""

from __future__ import annotations

import logging
import signal
import sys
import threading
import time
from typing import Sequence

from fogd import protocols
from fogd.cli.common import ArgumentParser, DefaultsHelpFormatter, run
from fogd.core.atomic import output_kind
from fogd.core.columns import CHANNELS
from fogd.core.numbers import positive_float, positive_int
from fogd.errors import DeviceError, UsageError
from fogd.protocols.kvh import ANGLE_UNITS, LIN_UNITS, LINFMTS, ROTFMTS, TEMP_UNITS
from fogd.protocols.lexer import Lexer
from fogd.serving.daemon import RING_CAPACITY
from fogd.serving.reader import Reader
from fogd.serving.recorder import Recorder, RowFile, chosen_channels
from fogd.serving.ring import Ring
from fogd.serving.serialio import open_port

PROG = "fogd-record"
AXES = ("x", "y", "z")
FLUSH_INTERVAL_S = 1.0
LIVE_INTERVAL_S = 0.5
IDLE_WAIT_S = 0.1
UNIT_DEFAULTS = {"rotfmt": "rate", "angle_unit": "rad", "linfmt": "accel", "lin_unit": "m", "temp_unit": "C"}

log = logging.getLogger("fogd.record")


def parser() -> ArgumentParser:
    p = ArgumentParser(
        prog=PROG,
        description="Record a FOG run from a serial port as CSV t_s,rate_dph,temp_c (the input of fogd-train). "
        "Bad frames are counted and dropped; an unplugged port is reopened and recording continues. "
        "Stop with Ctrl-C or SIGTERM. By default one gyro axis is recorded (--axis), for every protocol; "
        "a KVH IMU's frames carry three gyros and three accelerometers: --channels all records them all in one "
        "run (t_s,rate_x_dph,rate_y_dph,rate_z_dph,accel_x_g,accel_y_g,accel_z_g,temp_c; also from fogd IMU "
        "frames; ascii: z only). Whatever the unit's output settings, the file holds deg/h, g and C.",
        formatter_class=DefaultsHelpFormatter,
    )
    p.add_argument("--port", required=True, metavar="PATH", help="serial port the FOG is on")
    p.add_argument("--protocol", default="kvh-a", choices=protocols.names(), help="wire protocol of the port")
    p.add_argument("--baud", type=positive_int, default=921600, help="baud rate")
    p.add_argument("-o", "--output", required=True, metavar="RUN.csv", help="CSV file to write (replaced)")
    p.add_argument("--rate-hz", type=positive_float, default=1000.0,
                   help="FOG sample rate in Hz (a KVH's =DR): the time step where the protocol has no timestamp, and "
                   "the sample period of delta output")  # fmt: skip
    p.add_argument("--axis", default=None, choices=AXES, help="gyro axis to record, as rate_dph (default: z)")
    p.add_argument("--channels", metavar="all|LIST", default=None,
                   help="record these channels instead of one axis: 'all' (every channel the protocol carries) or a "
                   f"comma-separated list of {','.join(CHANNELS)}")  # fmt: skip
    unit = p.add_argument_group("kvh-a unit settings (what the unit is set to; decoded to deg/h and g)")
    unit.add_argument("--rotfmt", choices=ROTFMTS, default="rate", help="=ROTFMT: rate or delta angle per sample")
    unit.add_argument("--angle-unit", choices=ANGLE_UNITS, default="rad", help="=ROTUNITS")
    unit.add_argument("--linfmt", choices=LINFMTS, default="accel",
                      help="=LINFMT: accelerometers in g, or delta velocity per sample")  # fmt: skip
    unit.add_argument("--lin-unit", choices=LIN_UNITS, default="m", help="=LINUNITS: delta velocity in m/s or ft/s")
    unit.add_argument("--temp-unit", choices=TEMP_UNITS, default="C", help="=TEMPUNITS")
    p.add_argument("--duration-s", type=positive_float, default=None, help="stop after this many seconds")
    p.add_argument("--decimate", metavar="N", type=positive_int, default=1,
                   help="write the mean of every N samples as one row (N times smaller file; at 1 kHz, 10 gives "
                   "100 rows/s); a last incomplete group is not written")  # fmt: skip
    p.add_argument("--status-interval-s", type=positive_float, default=10.0,
                   help="seconds between status lines when stderr is not a terminal (a terminal gets a live line)")  # fmt: skip
    p.add_argument("-q", "--quiet", action="store_true", help="no status line")
    return p


def status_line(recorder: Recorder, reader: Reader, ring: Ring) -> str:
    lexer = reader.lexer.counters
    drops = lexer.bad_crc + lexer.truncated + lexer.bad_line + ring.overruns
    return (
        f"rows {recorder.rows}  frames {lexer.frames_ok}  T {recorder.temp_c:.2f} C  "
        f"dT/dt {recorder.temp_rate_cps:+.5f} C/s  drops {drops} (crc {lexer.bad_crc}, truncated {lexer.truncated}, "
        f"lines {lexer.bad_line}, overruns {ring.overruns})  missing {lexer.frames_missing}  "
        f"reconnects {reader.counters.reconnects}"
    )


def body(argv: Sequence[str] | None) -> int:
    args = parser().parse_args(argv)
    logging.basicConfig(stream=sys.stderr, level=logging.WARNING if args.quiet else logging.INFO, format="%(name)s: %(message)s")
    if args.channels is not None and args.axis is not None:
        raise UsageError("--axis records one gyro axis as rate_dph, --channels several: give one of them")
    axis = AXES.index(args.axis or "z")
    unit = {name: getattr(args, name) for name in UNIT_DEFAULTS}
    changed = [f"--{name.replace('_', '-')}" for name, value in unit.items() if value != UNIT_DEFAULTS[name]]
    if changed and args.protocol != "kvh-a":
        raise UsageError(f"{', '.join(changed)} describe a KVH unit's output: they apply to --protocol kvh-a only")
    options = {**unit, "rate_hz": args.rate_hz} if args.protocol == "kvh-a" else {}
    protocol = protocols.get(args.protocol, **options)
    channels = None if args.channels is None else chosen_channels(args.channels, protocol)
    try:
        output_kind(args.output)  # a directory, block device or socket, or a missing directory: refused
    except OSError as error:
        raise DeviceError(f"cannot write {args.output}: {error.strerror}") from None
    port = open_port(args.port, args.baud)
    try:
        stream = RowFile(args.output)
    except OSError as error:
        port.close()
        raise DeviceError(f"cannot write {args.output}: {error.strerror or error}") from None
    ring = Ring(RING_CAPACITY)
    reader = Reader(lambda: open_port(args.port, args.baud), Lexer(protocol), ring, port=port)
    recorder = Recorder(stream, axis, args.rate_hz, args.decimate, channels)
    stop = threading.Event()
    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, lambda *_: stop.set())
    live = sys.stderr.isatty() and not args.quiet
    status_every_s = LIVE_INTERVAL_S if live else args.status_interval_s
    stream.write(recorder.header())
    started_s = time.monotonic()
    next_flush_s = next_status_s = started_s + min(FLUSH_INTERVAL_S, status_every_s)
    reader.start()
    failed: OSError | None = None
    try:
        while not stop.is_set():
            now_s = time.monotonic()
            if args.duration_s is not None and now_s - started_s >= args.duration_s:
                break
            if not reader.alive:
                log.error("reader thread died (%r); restarting it", reader.error)
                reader.start()
            ring.wait(IDLE_WAIT_S)
            recorder.write(ring.pop())
            if now_s >= next_flush_s:
                try:
                    stream.flush()
                except OSError as error:
                    failed = error
                    break
                next_flush_s = now_s + FLUSH_INTERVAL_S
            if now_s >= next_status_s and not args.quiet:
                line = status_line(recorder, reader, ring)
                print(f"\r{line}\x1b[K" if live else line, end="" if live else "\n", file=sys.stderr, flush=True)
                next_status_s = now_s + status_every_s
    finally:
        reader.stop()
        if failed is None:
            recorder.write(ring.pop())
        try:
            stream.close()
        except OSError as error:
            failed = failed or error
    if live:
        print(file=sys.stderr)
    if failed is not None:  # a full disk: the file holds every row up to its last whole one
        raise DeviceError(f"cannot write {args.output}: {failed.strerror or failed}; stopped, the file ends at its "
                          "last whole row")  # fmt: skip
    log.info("%s: %s", args.output, status_line(recorder, reader, ring))
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    return run(PROG, body, argv)


if __name__ == "__main__":
    sys.exit(main())
