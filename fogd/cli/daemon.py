"""`fogd`: the real-time daemon. Reads a FOG's serial port, compensates one gyro axis for temperature with a
frozen model and writes the result to a sink; options come from the command line and a YAML config file
(same keys, underscores for dashes; the command line wins). This module owns option parsing, the config
file and wiring the parts together; the threads live in fogd.reader, fogd.daemon and fogd.outputs.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import sys
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import yaml

from fogd import modelfile, profiles, protocols
from fogd.cli.common import ArgumentParser, positive_float, positive_int, run
from fogd.daemon import RING_CAPACITY, Daemon
from fogd.errors import ConfigError, describe_os_error
from fogd.flags import Flag
from fogd.lexer import Lexer
from fogd.outputs import OUT_FORMATS, Formatter, Writer, open_sink
from fogd.reader import Reader
from fogd.ring import Ring
from fogd.serialio import open_port

PROG = "fogd"
DEFAULT_MODEL = "/var/lib/fogd/model.json"
DEMO_MODEL = Path(__file__).resolve().parent.parent / "data" / "demo-model.json"
DEMO_PROFILE = "paper-test"
DEMO_RATE_HZ = 100.0
DEMO_SPEED = 60.0  # three chamber hours in three minutes
AXES = ("x", "y", "z")
MAX_CONFIG_BYTES = 1 << 20


@dataclass(frozen=True)
class Option:
    """One setting: its command-line conversion (text -> value), default, help and, for text, its choices."""

    key: str
    convert: Callable[[str], Any]
    default: Any
    help: str
    metavar: str | None = None
    choices: tuple[str, ...] | None = None

    @property
    def numeric(self) -> bool:
        return self.choices is None and self.convert is not str


OPTIONS = (
    Option("port", str, None, "serial port the FOG is on, e.g. /dev/ttyUSB0 (required unless --demo)", "PATH"),
    Option("baud", positive_int, 921600, "baud rate of the port, and of --out when it is a serial port (default: %(default)s)", "BAUD"),
    Option("protocol", str, "kvh-a", "wire protocol of the port (default: %(default)s)", choices=tuple(protocols.names())),
    Option("model", str, DEFAULT_MODEL, f"model file from fogd-train (default: {DEFAULT_MODEL}; with --demo the bundled demo model)", "PATH"),
    Option("out", str, "-", "where compensated frames go: '-' stdout, a file or serial/pty device path, or pty:PATH "
           "(fogd makes a pty and links PATH to it) (default: %(default)s)", "SINK"),  # fmt: skip
    Option("out_format", str, "same", "output format: 'same' re-encodes the input protocol with the compensated rate "
           "and a fresh CRC; 'fogd' fogd compensated-output frames; 'csv' fogd-replay's columns; 'jsonl' one JSON "
           "object per sample (default: %(default)s)", choices=OUT_FORMATS),  # fmt: skip
    Option("rate_hz", positive_float, 1000.0, "FOG sample rate in Hz, for the temperature-rate estimator and for output "
           "time where the protocol has no timestamp (KVH Format A has none) (default: %(default)s)", "HZ"),  # fmt: skip
    Option("axis", str, "z", "gyro axis the model compensates; the other axes pass through untouched (default: %(default)s)", choices=AXES),
    Option("temp_stale_s", positive_float, 2.0, "flag samples TEMP_STALE when the newest temperature arrived more than "
           "this many seconds ago (default: %(default)s)", "S"),  # fmt: skip
    Option("status_interval_s", positive_float, 10.0, "seconds between status lines on stderr (default: %(default)s)", "S"),
    Option("duration_s", positive_float, None, "stop after this many seconds (default: run until SIGTERM/SIGINT)", "S"),
)
OPTION_BY_KEY = {option.key: option for option in OPTIONS}


def parser() -> ArgumentParser:
    p = ArgumentParser(
        prog=PROG,
        description="Real-time temperature compensation for a fibre-optic gyro: reads frames from --port, "
        "subtracts the model's thermal error f(T, dT/dt) from one axis and writes the result to --out. "
        "SIGTERM or SIGINT stop cleanly (output flushed, exit 0).",
        epilog=f"Config keys (--config): {', '.join(OPTION_BY_KEY)}. Output flags bits: "
        f"{', '.join(f'{flag.name}={int(flag)}' for flag in Flag)}. Exit status: 0 ok, 2 usage, 65 bad model "
        "file, 74 port or output cannot be opened, 78 bad config.",
    )
    for option in OPTIONS:
        p.add_argument(
            "--" + option.key.replace("_", "-"),
            dest=option.key,
            type=option.convert,
            choices=option.choices,
            default=argparse.SUPPRESS,
            metavar=option.metavar,
            help=option.help % {"default": option.default},
        )
    p.add_argument("--config", metavar="PATH.yaml", help="YAML file of settings (keys as above, e.g. out_format: csv)")
    p.add_argument("--demo", action="store_true", help="no hardware: compensate the built-in emulator with the bundled model")
    p.add_argument("-v", "--verbose", action="store_true", help="log debug detail")
    p.add_argument("-q", "--quiet", action="store_true", help="log warnings and errors only (no status lines)")
    return p


def load_config(path: str) -> dict[str, Any]:
    """Settings from a YAML file, each checked like its command-line option; ConfigError names the key."""
    try:
        with open(path, "rb") as stream:
            text = stream.read(MAX_CONFIG_BYTES + 1)
    except OSError as error:
        raise ConfigError(f"cannot read config {describe_os_error(error)}") from None
    if len(text) > MAX_CONFIG_BYTES:
        raise ConfigError(f"{path}: larger than {MAX_CONFIG_BYTES // 1024} KiB; not a fogd config")
    try:
        document = yaml.safe_load(text)
    except yaml.YAMLError as error:
        where = getattr(error, "problem_mark", None)
        line = f":{where.line + 1}" if where is not None else ""
        raise ConfigError(f"{path}{line}: not valid YAML ({getattr(error, 'problem', None) or error})") from None
    if document is None:
        return {}
    if not isinstance(document, dict):
        raise ConfigError(f"{path}: expected a mapping of settings (key: value), found {type(document).__name__}")
    settings = {}
    for key, value in document.items():
        option = OPTION_BY_KEY.get(key) if isinstance(key, str) else None
        if option is None:
            raise ConfigError(f"{path}: unknown key {key!r}; known keys: {', '.join(OPTION_BY_KEY)}")
        settings[key] = _config_value(path, option, value)
    return settings


def _config_value(path: str, option: Option, value: Any) -> Any:
    if value is None and option.default is None:
        return None
    if option.numeric:
        ok_type = isinstance(value, (int, float)) and not isinstance(value, bool)
        expected = "a number"
    else:
        ok_type = isinstance(value, str)
        expected = "a string"
    if not ok_type:
        raise ConfigError(f"{path}: key {option.key!r} must be {expected}, found {value!r:.40}")
    if option.choices is not None and value not in option.choices:
        raise ConfigError(f"{path}: key {option.key!r} is {value!r:.40}; valid values: {', '.join(option.choices)}")
    try:
        return option.convert(str(value))
    except (argparse.ArgumentTypeError, ValueError) as error:
        raise ConfigError(f"{path}: key {option.key!r}: {error}") from None


def settings_from(args: argparse.Namespace) -> dict[str, Any]:
    """Defaults, overridden by the config file, overridden by the command line."""
    settings = {option.key: option.default for option in OPTIONS}
    config = load_config(args.config) if args.config else {}
    command_line = {key: getattr(args, key) for key in OPTION_BY_KEY if hasattr(args, key)}
    settings.update(config)
    settings.update(command_line)
    if args.demo and "model" not in config and "model" not in command_line:
        settings["model"] = str(DEMO_MODEL)
    return settings


def settings_given(args: argparse.Namespace) -> set[str]:
    """The settings named on the command line or in the config file."""
    given = {key for key in OPTION_BY_KEY if hasattr(args, key)}
    return given | (set(load_config(args.config)) if args.config else set())


def demo(settings: dict[str, Any], protocol: protocols.Protocol, model, *, out_given: bool) -> int:
    """The emulator streams a simulated chamber run, compressed in time, onto a pty in this process; fogd
    compensates it and prints a live status line every second. Output is discarded unless --out is given."""
    from fogd.emulator import Emulator, SimSource

    source = SimSource(profiles.builtin(DEMO_PROFILE), DEMO_RATE_HZ, seed=1)
    emulator = Emulator(source, protocol.name, speed=DEMO_SPEED, wait_reader=True, drain_timeout_s=0.0)
    path = emulator.start()
    print(
        f"fogd demo: simulated FOG on {path} ({DEMO_PROFILE} chamber profile at {DEMO_SPEED:g}x real time, "
        f"{DEMO_RATE_HZ:g} Hz), model {model.name}; Ctrl-C to stop",
        file=sys.stderr,
    )
    settings = {**settings, "port": path, "rate_hz": DEMO_RATE_HZ, "out": settings["out"] if out_given else os.devnull}
    finished = threading.Event()

    def live(daemon: Daemon) -> None:
        while not finished.wait(1.0):
            latest, lexer = daemon.latest, daemon.reader.lexer.counters
            drops = lexer.bad_crc + lexer.truncated + lexer.bad_line + daemon.ring.overruns
            print(
                f"\rrate {latest.rate_dph:+9.3f}  comp {latest.comp_dph:+8.3f}  compensated {latest.rate_comp_dph:+9.3f} "
                f"deg/h  T {latest.temp_c:6.2f} C  dT/dt {latest.temp_rate_cps:+.5f} C/s  frames {lexer.frames_ok}  "
                f"drops {drops}\x1b[K",
                end="", file=sys.stderr, flush=True,
            )  # fmt: skip

    def start_live(daemon: Daemon) -> None:
        threading.Thread(target=live, args=(daemon,), name="fogd-demo-status", daemon=True).start()

    try:
        return serve(settings, protocol, model, on_daemon=start_live)
    finally:
        finished.set()
        print(file=sys.stderr)
        emulator.stop()
        emulator.join(1.0)


def configure_logging(verbose: bool, quiet: bool) -> None:
    level = logging.DEBUG if verbose else logging.WARNING if quiet else logging.INFO
    logging.basicConfig(stream=sys.stderr, level=level, format="%(name)s: %(message)s")


def body(argv: Sequence[str] | None) -> int:
    args = parser().parse_args(argv)
    settings = settings_from(args)
    configure_logging(args.verbose, args.quiet)
    if settings["port"] is None and not args.demo:
        raise ConfigError("no port: give --port PATH (or port: in the config), or try --demo")
    axis = AXES.index(settings["axis"])
    protocol_options: dict[str, Any] = {} if settings["protocol"] == "ascii" else {"comp_axes": (axis,)}
    if settings["protocol"] == "ascii" and axis != 2:
        raise ConfigError("protocol ascii carries the z axis only; use --axis z")
    protocol = protocols.get(settings["protocol"], **protocol_options)
    model = modelfile.load(settings["model"])
    if args.demo:
        return demo(settings, protocol, model, out_given="out" in settings_given(args))
    return serve(settings, protocol, model)


def serve(settings: dict[str, Any], protocol: protocols.Protocol, model, *, on_daemon=None) -> int:
    """Open the port and the sink, run the daemon until a signal or the duration, and shut down cleanly."""
    path, baud = settings["port"], settings["baud"]
    port = open_port(path, baud)
    try:
        sink = open_sink(settings["out"], baud)
    except BaseException:
        port.close()
        raise
    reader = Reader(lambda: open_port(path, baud), Lexer(protocol), Ring(RING_CAPACITY), port=port)
    daemon = Daemon(
        reader=reader,
        writer=Writer(sink),
        formatter=Formatter(settings["out_format"], protocol, AXES.index(settings["axis"])),
        model=model,
        rate_hz=settings["rate_hz"],
        axis=AXES.index(settings["axis"]),
        temp_stale_s=settings["temp_stale_s"],
        status_interval_s=settings["status_interval_s"],
        duration_s=settings["duration_s"],
    )
    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, lambda *_: daemon.stop())
    logging.getLogger("fogd.daemon").info(
        "reading %s (%s, %g Hz), model %s (%s), axis %s, output %s as %s",
        path, protocol.name, settings["rate_hz"], model.name, model.method, settings["axis"], settings["out"],
        settings["out_format"],
    )  # fmt: skip
    if on_daemon is not None:
        on_daemon(daemon)
    daemon.run()
    logging.getLogger("fogd.status").info("counters %s", json.dumps(daemon.counters_dict()))
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    return run(PROG, body, argv)


if __name__ == "__main__":
    sys.exit(main())
