"""`fogd`: the real-time daemon. Reads a FOG's serial port, compensates one gyro axis for temperature with a
frozen model and writes the result to a sink. This module owns the command line, wiring the parts together and
the signals (SIGTERM/SIGINT stop, SIGHUP reload, SIGUSR1 counters, SIGABRT every thread's stack); settings and
the config file live in fogd.serving.config, the threads in fogd.serving.reader, fogd.serving.daemon and
fogd.serving.outputs.
"""

from __future__ import annotations

import argparse
import faulthandler
import json
import logging
import os
import signal
import sys
import threading
import time
from typing import Any, Sequence

from fogd import protocols
from fogd.cli import demo as demo_mode
from fogd.cli.common import ArgumentParser, run
from fogd.core import modelfile
from fogd.core.channels import ChannelModels
from fogd.core.columns import SINGLE_CHANNEL
from fogd.core.flags import Flag
from fogd.core.frozen import FrozenModel
from fogd.errors import ConfigError, DeviceError
from fogd.protocols.lexer import Lexer
from fogd.serving import autodetect, config, statsfile, unitquery
from fogd.serving.channels import as_models, method
from fogd.serving.channels import plan as channel_plan
from fogd.serving.config import AXES, OPTION_BY_KEY, OPTIONS
from fogd.serving.daemon import RING_CAPACITY, Daemon, Reload
from fogd.serving.outputs import Formatter, Writer, open_sink
from fogd.serving.placement import Placement
from fogd.serving.reader import Reader
from fogd.serving.ring import Ring
from fogd.serving.sdnotify import Notifier
from fogd.serving.serialio import PortOpener, open_port
from fogd.serving.thermalstate import Thermal

PROG = "fogd"
DEMO_MODEL = demo_mode.MODEL
EXIT_NOT_RUNNING = 3  # `fogd --status`: no live daemon (as LSB status actions say)
log = logging.getLogger("fogd.daemon")


def parser() -> ArgumentParser:
    p = ArgumentParser(
        prog=PROG,
        description="Real-time temperature compensation for a fibre-optic gyro or IMU: reads frames from --port, "
        "subtracts the model's thermal error f(T, dT/dt) from one axis (a single-axis model, --axis) or from every "
        "gyro and accelerometer a three-axis model covers, and writes the result to --out. "
        "SIGTERM or SIGINT stop cleanly (output flushed, exit 0); SIGHUP reloads the config and the model; "
        "SIGUSR1 logs the counters; SIGABRT (systemd's watchdog) writes every thread's stack to stderr, then aborts.",
        epilog=f"Config keys: {', '.join(OPTION_BY_KEY)} (see config/fogd.yaml). Without --config, "
        f"{config.CONFIG_DIR}/INSTANCE.yaml or {config.CONFIG_DIR}/fogd.yaml is read when it exists "
        f"(${config.CONFIG_DIR_ENV} moves that directory). Output flags bits: "
        f"{', '.join(f'{flag.name}={int(flag)}' for flag in Flag)}. Exit status: 0 ok, 2 usage, 3 --status: "
        "not running, 65 bad model file, 74 port, output or stats file cannot be opened, 78 bad config (also: "
        "no out set while stdout is not a terminal, or out '-' while stdout is the journal).",
    )
    for option in OPTIONS:
        if option.kind == "flag":
            p.add_argument("--" + option.key.replace("_", "-"), dest=option.key, action=argparse.BooleanOptionalAction,
                           default=argparse.SUPPRESS, help=option.help)  # fmt: skip
            continue
        p.add_argument(
            "--" + option.key.replace("_", "-"),
            dest=option.key,
            type=option.convert,
            choices=option.choices,
            default=argparse.SUPPRESS,
            metavar=option.metavar,
            help=option.help % {"default": option.default},
        )
    p.add_argument("--config", metavar="PATH.yaml", help="YAML file of settings (keys as above, e.g. out_format: csv); "
                   "it must exist")  # fmt: skip
    p.add_argument("--instance", metavar="NAME", default=config.DEFAULT_INSTANCE,
                   help="name of this daemon (e.g. ttyUSB0 for fogd@ttyUSB0): picks NAME.yaml in the config "
                   "directory and the default stats file (default: %(default)s)")  # fmt: skip
    p.add_argument("--status", action="store_true", help="print the running daemon's stats file and exit "
                   "(0 running; 3 not running: no stats file, or a stale one; 74 stats file unreadable)")  # fmt: skip
    p.add_argument("--demo", action="store_true", help="no hardware: compensate the built-in emulator with the bundled model")
    p.add_argument("-v", "--verbose", action="store_true", help="log debug detail")
    p.add_argument("-q", "--quiet", action="store_true", help="log warnings and errors only (no status lines)")
    return p


class Settings:
    """Where the settings come from (config file path, command line), so SIGHUP can read them again."""

    def __init__(self, args: argparse.Namespace) -> None:
        self.demo = args.demo
        self.instance = args.instance
        self.path = args.config if args.config is not None else config.default_config_path(args.instance)
        if args.config is not None and not os.path.exists(args.config):
            raise ConfigError(f"{args.config}: no such config file")
        self.command_line = {key: getattr(args, key) for key in OPTION_BY_KEY if hasattr(args, key)}

    def read(self) -> dict[str, Any]:
        """Defaults < config file < command line, checked; raises ConfigError."""
        from_file = config.load(self.path) if self.path else {}
        settings = config.merge(from_file, self.command_line)
        if self.demo and "model" not in from_file and "model" not in self.command_line:
            settings["model"] = str(DEMO_MODEL)
        config.check(settings, demo=self.demo)
        return settings

    def given(self, key: str) -> bool:
        return key in self.command_line or (self.path is not None and key in config.load(self.path))


def configure_logging(verbose: bool, quiet: bool) -> None:
    level = logging.DEBUG if verbose else logging.WARNING if quiet else logging.INFO
    logging.basicConfig(stream=sys.stderr, level=level, format="%(name)s: %(message)s")


def status(args: argparse.Namespace) -> int:
    """`fogd --status`: print the stats file of the daemon this command line names; no stats file at all is
    "not running" (3, as LSB status actions say), an unreadable one an I/O error (74)."""
    path = statsfile.default_path(getattr(args, "stats_file", "auto"), args.instance)
    if not os.path.exists(path):
        print(f"fogd: not running ({path}: no stats file; start fogd, or give --stats-file or --instance)")
        return EXIT_NOT_RUNNING
    snapshot = statsfile.read_stats(path)
    print(statsfile.describe(snapshot))
    return 0 if statsfile.is_live(snapshot) else EXIT_NOT_RUNNING


def body(argv: Sequence[str] | None) -> int:
    args = parser().parse_args(argv)
    if args.status:
        return status(args)
    sources = Settings(args)
    settings = sources.read()
    configure_logging(args.verbose, args.quiet)
    if settings["protocol"] == "auto" and settings["query_settings"]:
        settings["protocol"] = "kvh-a"  # only a KVH unit answers the settings query
    model = load_model(settings["model"])
    protocol = None if settings["protocol"] == "auto" else make_protocol(settings, model)
    if args.demo:
        return demo_mode.run(settings, protocol, model, serve, out_given=sources.given("out"), verbose=args.verbose)
    return serve(settings, protocol, model, sources=sources)


def stdout_is_journal() -> bool:
    """Whether stdout is systemd's journal stream (systemd sets $JOURNAL_STREAM to its device:inode)."""
    try:
        device, inode = (int(part) for part in os.environ.get("JOURNAL_STREAM", "").split(":"))
        info = os.fstat(sys.stdout.fileno())
    except (ValueError, OSError):
        return False
    return (info.st_dev, info.st_ino) == (device, inode)


def check_output(settings: dict[str, Any], *, out_given: bool) -> None:
    """Refuse an output that makes no sense where fogd runs: stdout by default when it is not a terminal (a
    service's stdout is the journal: binary frames there help nobody), or stdout on purpose into the journal."""
    choices = "a serial port (out: /dev/ttyUSB1), pty:/run/fogd/fog0 for a program on this machine, or a file"
    if settings["out"] != "-":
        return
    if stdout_is_journal():
        raise ConfigError(f"key 'out' is '-' but stdout is the journal; set out: to {choices}")
    if not out_given and not sys.stdout.isatty():
        raise ConfigError(f"key 'out' is not set and stdout is not a terminal; set out: to {choices} "
                          "(or --out - to write to stdout on purpose)")  # fmt: skip


def load_model(path: str) -> FrozenModel | ChannelModels:
    """A single-channel file as its model (today's daemon), a multi-channel file as its models by channel."""
    models = modelfile.load_channels(path)
    return models if models.version == modelfile.CHANNELS_VERSION else models[SINGLE_CHANNEL]


def candidates(settings: dict[str, Any], model: FrozenModel | ChannelModels) -> list[protocols.Protocol]:
    """The protocols `auto` tries: each one that can carry what the model compensates on the axis set."""
    tried = []
    for name in protocols.names():
        if name == "ascii" and settings["axis"] != "z":
            log.debug("protocol auto: not trying ascii (it carries the z axis only; axis is %s)", settings["axis"])
            continue
        try:
            tried.append(make_protocol({**settings, "protocol": name}, model))
        except ConfigError as error:
            log.debug("protocol auto: not trying %s (%s)", name, error)
    if not tried:
        raise ConfigError("key 'protocol': no protocol fogd knows carries this model's channels")
    return tried


def make_protocol(settings: dict[str, Any], model: FrozenModel | ChannelModels | None = None) -> protocols.Protocol:
    """The port's protocol with the unit's settings, re-encoding (`same`) exactly the channels the model
    compensates; ConfigError for a model channel the protocol does not carry."""
    name = settings["protocol"]
    if name == "ascii":
        return protocols.get(name, max_jump_dph=settings.get("max_rate_jump_dph"))
    axis = AXES.index(settings["axis"])
    options: dict[str, Any] = {"comp_axes": (axis,)}
    if model is not None:
        chosen = channel_plan(as_models(model), protocols.get(name), axis)
        options = {"comp_axes": chosen.gyro_axes, "comp_accel_axes": chosen.accel_axes}
    if name == "kvh-a":
        options.update({key: settings[key] for key in ("rotfmt", "angle_unit", "linfmt", "lin_unit", "temp_unit")})
        options["rate_hz"] = settings["rate_hz"]
    return protocols.get(name, **options)


def reloader(sources: Settings, running: dict[str, Any]):
    """SIGHUP's work, run off the data path: read the config again, validate the model, and say which changed
    settings need a restart (those that open the port or the output, or shape the estimator)."""

    def reload() -> Reload:
        settings = sources.read()
        model = load_model(settings["model"])
        for option in OPTIONS:
            if not option.reloadable and settings[option.key] != running[option.key]:
                log.warning("reload: %s changed to %r; restart fogd to apply it", option.key, settings[option.key])
        log.info("reload: model %s (%s) validated", model.name, method(as_models(model)))
        return Reload(model, settings["temp_stale_s"], settings["status_interval_s"])

    return reload


def serve(settings: dict[str, Any], protocol: protocols.Protocol | None, model, *, on_daemon=None,
          sources: Settings | None = None) -> int:  # fmt: skip
    """Open the port and the sink (recognise the protocol first when `protocol` is None: auto), run the daemon
    until a signal or the duration, and shut down cleanly."""
    path, baud = settings["port"], settings["baud"]
    instance = sources.instance if sources is not None else config.DEFAULT_INSTANCE
    stats_path = config.stats_path(settings["stats_file"], instance)
    axis = AXES.index(settings["axis"])
    if protocol is None:  # what can be refused before the protocol is known is refused now, not once it is
        tried = candidates(settings, model)
        for one in as_models(model).values():
            modelfile.check_rate(one, settings["rate_hz"], one.name)
    else:
        channels = channel_plan(as_models(model), protocol, axis)
    port = open_port(path, baud)
    received = bytearray()  # what the settings query or the detection read: frames the reader frames first
    notifier = Notifier()
    try:
        if settings.get("query_settings"):
            unitquery.check_settings(unitquery.query_settings(port, path, received=received), settings, path)
        if sources is not None:  # not the demo, which discards its output unless told otherwise
            check_output(settings, out_given=sources.given("out"))
        sink = open_sink(settings["out"], baud)
    except BaseException:
        port.close()
        raise
    duration_s = settings["duration_s"]
    if protocol is None:
        started_s = time.monotonic()
        stopping = threading.Event()
        for signum in (signal.SIGTERM, signal.SIGINT):
            signal.signal(signum, lambda *_: stopping.set())
        for signum in (signal.SIGHUP, signal.SIGUSR1):  # their default would end fogd; nothing to reload or count yet
            signal.signal(signum, signal.SIG_IGN)
        try:
            detected = autodetect.detect(port, path, tried, stopping=stopping, received=bytes(received), notifier=notifier,
                                         until_s=started_s + duration_s if duration_s else None)  # fmt: skip
        except BaseException:
            port.close()
            sink.close()
            raise
        if detected is None:  # stopped before anything was recognised
            port.close()
            sink.close()
            return 0
        received[:] = detected[1]
        protocol = make_protocol({**settings, "protocol": detected[0].name}, model)
        channels = channel_plan(as_models(model), protocol, axis)
        if duration_s:  # the duration counts from the start, detection included
            duration_s = max(duration_s - (time.monotonic() - started_s), 1e-3)
    reader = Reader(PortOpener(path, baud), Lexer(protocol), Ring(RING_CAPACITY), port=port, received=bytes(received))
    daemon = Daemon(
        reader=reader,
        writer=Writer(sink),
        formatter=Formatter(settings["out_format"], protocol, axis, channels),
        model=model,
        rate_hz=settings["rate_hz"],
        axis=axis,
        channels=channels,
        temp_stale_s=settings["temp_stale_s"],
        status_interval_s=settings["status_interval_s"],
        duration_s=duration_s,
        notifier=notifier,
        reload=reloader(sources, settings) if sources is not None else None,
        stats_path=stats_path,
        info={"instance": instance, "port": path, "protocol": protocol.name, "out": settings["out"]},
        placement=Placement(settings["cpu"]),
        thermal=Thermal([as_models(model)[c] for c in channels.covered], settings["rate_hz"],
                        path=config.state_path(settings["state_file"], instance), device=f"port {path}",
                        warming=settings["warming"], tolerance_dph=settings["warming_tolerance_dph"]),
    )
    if settings["metrics_port"] is not None:
        from fogd.serving import prometheus

        try:
            prometheus.serve(daemon.snapshot, settings["metrics_address"], settings["metrics_port"])
        except DeviceError:
            port.close()
            daemon.writer.sink.close()
            raise
    # A hung daemon says where: systemd's watchdog (WatchdogSignal, SIGABRT by default) or `kill -ABRT` makes
    # faulthandler write every thread's stack to stderr, the journal, before the process dies.
    faulthandler.enable()
    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, lambda *_: daemon.stop())
    signal.signal(signal.SIGHUP, lambda *_: daemon.request_reload())
    signal.signal(signal.SIGUSR1, lambda *_: daemon.request_counters())
    log.info(
        "reading %s (%s, %g Hz), model %s (%s), %s, output %s as %s%s",
        path, protocol.name, settings["rate_hz"], model.name, method(as_models(model)),
        f"axis {settings['axis']}" if channels.single else f"{len(channels.covered)} channels",
        settings["out"], settings["out_format"], f", stats {stats_path}" if stats_path else "",
    )  # fmt: skip
    log.info("model %s %s", model.name, channels.describe())
    if on_daemon is not None:
        on_daemon(daemon)
    daemon.run()
    logging.getLogger("fogd.status").info("counters %s", json.dumps(daemon.counters_dict()))
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    return run(PROG, body, argv)


if __name__ == "__main__":
    sys.exit(main())
