"""`fogd-top`: a terminal view of a running fogd, like gpsd's gpsmon. It reads the daemon's stats file (rewritten
every second; the same file `fogd --status` reads) and shows its counters, latency, flags and the last minute
of temperature, temperature rate and compensation as sparklines; a daemon compensating several channels of an
IMU gets a row per channel (its compensation in its own unit and its flags) and the channels it passes
through. Plain text and two ANSI sequences (home, clear) on a terminal, none when stdout is a file or pipe: no
curses, so it works over ssh and under tmux.
"""

from __future__ import annotations

import math
import os
import sys
import time
from typing import Any, Sequence

from fogd.cli.common import ArgumentParser, DefaultsHelpFormatter, run
from fogd.core.columns import SINGLE_CHANNEL, channel_unit
from fogd.core.flags import Flag, describe
from fogd.core.numbers import number_in, whole_number
from fogd.serving import config, statsfile

PROG = "fogd-top"
EXIT_NOT_RUNNING = 3  # as `fogd --status`
UNICODE_BARS = "▁▂▃▄▅▆▇█"
ASCII_BARS = "_.-:=+*#"
HOME_CLEAR = "\x1b[H\x1b[2J"
# one letter per flag in the flags row, the most serious set bit winning
FLAG_LETTERS = {Flag.RATE_INVALID: "R", Flag.TEMP_INVALID: "T", Flag.OUT_OF_DOMAIN: "O", Flag.TEMP_STALE: "S",
                Flag.CLAMPED: "C", Flag.WARMUP: "W", Flag.WARMING: "H",
                Flag.TIME_BACKWARDS: "B"}  # fmt: skip (H: no thermal history; B: the device's clock went back)
LEXER_SHOWN = ("bad_crc", "truncated", "bad_line", "garbage_bytes", "seq_gaps", "frames_missing", "frames_repeated",
               "time_backwards")


def parser() -> ArgumentParser:
    p = ArgumentParser(
        prog=PROG,
        description="Watch a running fogd: counters, latency, flags and the last minute of temperature, "
        "temperature rate and compensation as sparklines, redrawn every second from the daemon's stats file; with an "
        "IMU's model, a row per compensated channel (compensation in its own unit, flags) and the channels passed through. "
        "Plain text (no curses): works over ssh. Ctrl-C quits.",
        epilog=f"Flags row letters: {', '.join(f'{letter} {flag.name}' for flag, letter in FLAG_LETTERS.items())}, "
        ". none. Exit status: 0 (Ctrl-C, or --count frames shown of a running daemon), 2 usage, 3 with --count: "
        "the daemon is not running, 74 the stats file cannot be read.",
        formatter_class=DefaultsHelpFormatter,
    )
    p.add_argument("--instance", metavar="NAME", default=config.DEFAULT_INSTANCE,
                   help=f"the daemon to watch: reads {config.RUNTIME_DIR}/NAME.json")  # fmt: skip
    p.add_argument("--stats-file", metavar="PATH", default=None,
                   help="the daemon's stats file, when it is not the instance's default (fogd --stats-file)")  # fmt: skip
    p.add_argument("--interval-s", metavar="S", type=number_in(0.1, 3600.0, "s"), default=1.0,
                   help="seconds between redraws")  # fmt: skip
    p.add_argument("--count", metavar="N", type=whole_number(1), default=None,
                   help="draw N frames and exit (default: until Ctrl-C)")  # fmt: skip
    p.add_argument("--ascii", action="store_true", help="sparklines in ASCII, for terminals without UTF-8")
    return p


def sparkline(values: Sequence[Any], width: int, bars: str) -> str:
    """The last `width` values as bars scaled to their own min..max; a missing value (null, NaN) is a space."""
    values = list(values)[-width:]
    finite = [v for v in values if isinstance(v, (int, float)) and math.isfinite(v)]
    if not finite:
        return " " * len(values)
    low, high = min(finite), max(finite)
    span = high - low
    out = []
    for value in values:
        if not (isinstance(value, (int, float)) and math.isfinite(value)):
            out.append(" ")
        elif span <= 1e-12 * max(1.0, abs(high)):
            out.append(bars[len(bars) // 2 - 1])  # flat: a middle bar, not a floor that reads as "low"
        else:
            out.append(bars[min(len(bars) - 1, int((value - low) / span * len(bars)))])
    return "".join(out)


def flag_row(values: Sequence[Any], width: int) -> str:
    """One letter per point: the most serious flag set, '.' when none."""
    row = []
    for value in list(values)[-width:]:
        bits = int(value) if isinstance(value, (int, float)) and math.isfinite(value) else 0
        row.append(next((letter for flag, letter in FLAG_LETTERS.items() if bits & flag), "."))
    return "".join(row)


def _number(value: Any, spec: str, unit: str = "") -> str:
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
        return "-"
    return format(value, spec) + (f" {unit}" if unit else "")


def _range(values: Sequence[Any], spec: str, unit: str) -> str:
    finite = [v for v in values if isinstance(v, (int, float)) and math.isfinite(v)]
    if not finite:
        return ""
    return f"({format(min(finite), spec)} .. {format(max(finite), spec)} {unit})"


def _comp(value: Any, channel: str) -> str:
    """A compensation in the channel's unit: deg/h to 4 decimals as a gyro's always was, g to 4 significant digits."""
    unit = channel_unit(channel)
    return _number(value, "+.4f" if unit == "deg/h" else "+.4g", unit)


def compensated_channels(snapshot: dict[str, Any]) -> list[str]:
    """The channels a multi-channel daemon compensates, in frame order; [] for a single-axis model."""
    plan = snapshot.get("channels") if isinstance(snapshot.get("channels"), dict) else {}
    names = [name for name in plan.get("compensated") or [] if isinstance(name, str)]
    return [] if names in ([], [SINGLE_CHANNEL]) else names


def channel_lines(snapshot: dict[str, Any]) -> list[str]:
    """A row per compensated channel (its latest compensation and flags), then the channels passed through."""
    names = compensated_channels(snapshot)
    latest = (snapshot.get("latest") or {}).get("channels")
    latest = latest if isinstance(latest, dict) else {}
    width = max(len("channel"), *(len(name) for name in names))
    lines = [f"{'channel':<{width}}  {'comp':>18}  flags"]
    for name in names:
        one = latest.get(name) if isinstance(latest.get(name), dict) else {}
        flags = one.get("flags")
        flags_text = describe(int(flags)) if isinstance(flags, (int, float)) and math.isfinite(flags) else "-"
        lines.append(f"{name:<{width}}  {_comp(one.get('comp'), name):>18}  {flags_text}")
    passed = (snapshot.get("channels") or {}).get("passed") or []
    if passed:
        lines.append(f"passed through untouched (no model for them): {', '.join(map(str, passed))}")
    return lines


def _rate_text(rate: Any) -> str:
    """'200 Hz (the frames' clock; measured 200 Hz, rate_hz 1000 Hz)', or '-' from a daemon that does not say."""
    if not isinstance(rate, dict):
        return "-"
    measured = rate.get("measured_hz")
    return (f"{_number(rate.get('in_use_hz'), 'g', 'Hz')} ({rate.get('source', '?')}; measured "
            f"{_number(measured, 'g', 'Hz') if measured is not None else '-'}, rate_hz {_number(rate.get('configured_hz'), 'g', 'Hz')})")  # fmt: skip


def render(snapshot: dict[str, Any], path: str, *, width: int = 60, bars: str = UNICODE_BARS) -> list[str]:
    """The screen for one snapshot, as lines of plain text."""
    live = statsfile.is_live(snapshot)
    age_s = time.time() - (snapshot.get("time_unix_s") or 0.0)
    state = "running" if live else f"NOT RUNNING (stats last written {age_s:.0f} s ago)"
    counters = snapshot.get("counters") or {}
    reader, lexer = counters.get("reader") or {}, counters.get("lexer") or {}
    writer, loop = counters.get("writer") or {}, counters.get("loop") or {}
    latest, model = snapshot.get("latest") or {}, snapshot.get("model") or {}
    latency = snapshot.get("latency_s") or {}
    shares = snapshot.get("domain_shares") or {}
    history = snapshot.get("history") or {}
    frames_in = " ".join(f"{kind} {count}" for kind, count in (reader.get("frames_in") or {}).items() if count) or "0"
    dropped_out = sum(writer.get(key, 0) for key in ("frames_dropped_full", "frames_dropped_timeout", "frames_dropped_error",
                                                     "frames_dropped_no_reader"))  # fmt: skip
    lexer_text = "  ".join(f"{name.replace('_', ' ')} {lexer.get(name, 0)}" for name in LEXER_SHOWN)

    def ms(value: Any) -> str:
        return _number(1e3 * value if isinstance(value, (int, float)) else None, ".1f", "ms")

    def share(key: str) -> str:
        return _number(100.0 * shares[key] if isinstance(shares.get(key), (int, float)) else None, ".1f", "%")

    connected = "connected" if snapshot.get("connected") else "LOST (waiting for it)"
    several = compensated_channels(snapshot)
    if several:  # each channel's compensation and flags in the rows below; the shares count a sample once
        comp_now = f"fallback {share('out_of_domain')}  clamped {share('clamped')} (of the samples, any channel)"
    else:
        comp_now = (f"comp {_number(latest.get('comp_dph'), '+.4f', 'deg/h')}  flags {describe(int(latest.get('flags') or 0))}  "
                    f"fallback {share('out_of_domain')}  clamped {share('clamped')}")  # fmt: skip
    lines = [
        f"{PROG}  fogd {snapshot.get('version', '?')}  pid {snapshot.get('pid', '?')}  {state}  "
        f"up {_number(snapshot.get('uptime_s'), '.0f', 's')}  {time.strftime('%H:%M:%S')}",
        f"port     {snapshot.get('port', '?')} ({snapshot.get('protocol', '?')}) {connected}   "
        f"out {snapshot.get('out', '?')}",
        f"model    {model.get('name', '?')} ({model.get('method', '?')})  {statsfile.held_out_text(model)}",
        f"rate     {_rate_text(snapshot.get('rate'))}",
        f"frames   in {frames_in}  out {writer.get('frames_written', 0)}  dropped out {dropped_out}  "
        f"ring overruns {counters.get('ring_overruns', 0)}  reconnects {reader.get('reconnects', 0)}",
        f"lexer    {lexer_text}",
        f"latency  last {ms(latency.get('last'))}  max {ms(latency.get('max_since_status'))}   "
        f"samples {loop.get('samples_compensated', 0)}  reloads {loop.get('reloads', 0)}",
        f"now      T {_number(latest.get('temp_c'), '.2f', 'C')}  dT/dt {_number(latest.get('temp_rate_cps'), '+.5f', 'C/s')}  "
        f"{comp_now}",
    ]
    missing = snapshot.get("missing_channels") or []
    if missing:
        lines.append(f"MISSING  {', '.join(missing)}: the frames carry none ({loop.get('samples_missing_channel', 0)} "
                     "samples passed through uncompensated)")  # fmt: skip
    if several:
        lines += ["", *channel_lines(snapshot)]
    lines += ["", f"last minute, one point a second ({len(history.get('temp_c') or [])} points), oldest on the left:"]
    # the history's compensation and flags are the first compensated channel's (the daemon keeps one series)
    first = several[0] if several else SINGLE_CHANNEL
    of_first = f", {first}" if several else ""
    comp_spec = "+.4f" if channel_unit(first) == "deg/h" else "+.4g"
    rows = (("T", "temp_c", ".2f", "C"), ("dT/dt", "temp_rate_cps", "+.5f", "C/s"),
            ("comp", "comp_dph", comp_spec, f"{channel_unit(first)}{of_first}"))  # fmt: skip
    for label, key, spec, unit in rows:
        values = history.get(key) or []
        lines.append(f"{label:8s} {sparkline(values, width, bars):{width}s}  {_range(values, spec, unit)}")
    lines.append(f"{'flags':8s} {flag_row(history.get('flags') or [], width):{width}s}  (. none{of_first}; see --help)")
    lines.append("")
    lines.append(f"{path}; Ctrl-C quits")
    return lines


def body(argv: Sequence[str] | None) -> int:
    args = parser().parse_args(argv)
    path = statsfile.default_path(args.stats_file, args.instance)
    terminal = sys.stdout.isatty()
    encoding = (getattr(sys.stdout, "encoding", None) or "").lower().replace("-", "")
    bars = ASCII_BARS if args.ascii or "utf8" not in encoding else UNICODE_BARS
    drawn = 0
    live = False
    try:
        while args.count is None or drawn < args.count:
            if drawn:
                time.sleep(args.interval_s)
            if not os.path.exists(path):
                if args.count is not None:
                    print(f"{PROG}: not running ({path}: no stats file; start fogd, or give --stats-file or --instance)")
                    return EXIT_NOT_RUNNING
                lines = [f"{PROG}: waiting for {path} (is fogd running, with a stats file?)"]
                live = False
            else:
                snapshot = statsfile.read_stats(path)
                lines = render(snapshot, path, bars=bars)
                live = statsfile.is_live(snapshot)
            frame = "\n".join(lines)
            # a terminal gets the screen redrawn in place; a file or pipe gets plain frames, one after another
            sys.stdout.write(f"{HOME_CLEAR}{frame}\n" if terminal else f"{frame}\n\n")
            sys.stdout.flush()
            drawn += 1
    except KeyboardInterrupt:
        return 0
    return 0 if live or args.count is None else EXIT_NOT_RUNNING


def main(argv: Sequence[str] | None = None) -> int:
    return run(PROG, body, argv)


if __name__ == "__main__":
    sys.exit(main())
