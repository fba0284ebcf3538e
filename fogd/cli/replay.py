"""`fogd-replay`: run a recorded CSV through the daemon's compensator and print the paper's table 4."""

from __future__ import annotations

import argparse
from dataclasses import replace
import os
import sys
from typing import Sequence

import numpy as np

from fogd.calibration.allan import plot, summary_lines
from fogd.calibration.replay import (
    SETTLE_S,
    ReplayTable,
    allan_curves,
    replay,
    replay_channels,
    replay_table,
)
from fogd.calibration.tables import error_table
from fogd.cli.common import ArgumentParser, DefaultsHelpFormatter, run
from fogd.core import modelfile
from fogd.core.atomic import check_output
from fogd.core.compensator import Compensated, Compensator
from fogd.core.warming import MODES, TOLERANCE_DPH, WarmingBound, mark_cold, replay_rules
from fogd.core.channels import ChannelModels, output_columns
from fogd.core.columns import BLOCK_S, OUTPUT_FORMATS, SINGLE_CHANNEL, channel_unit
from fogd.core.flags import Flag
from fogd.core.numbers import non_negative_float, positive_float
from fogd.core.runio import Run, read_run, write_csv
from fogd.errors import InputError, ModelFileError, NoModelFileError, UsageError

PROG = "fogd-replay"


def parser() -> ArgumentParser:
    p = ArgumentParser(
        prog=PROG,
        description="Compensate a recorded run (CSV t_s,rate_dph,temp_c) with a fogd model, exactly as the "
        "daemon would, and write t_s,rate_dph,temp_c,temp_rate_cps,comp_dph,rate_comp_dph,flags: one row per "
        "input row, in order. Prints the paper's table 4 (block-mean error before and after). An IMU run with a "
        "multi-channel model: t_s,temp_c and each channel, followed for each channel the model covers by "
        "comp_<channel>, its compensated reading (rate_x_comp_dph, accel_z_comp_g) and flags_<channel>; table 4 "
        "per channel; --allan-plot writes one figure per channel (NAME-<channel>.png).",
        epilog=f"flags bits: {', '.join(f'{flag.name}={int(flag)}' for flag in Flag)}",
        formatter_class=DefaultsHelpFormatter,
    )
    p.add_argument("model", metavar="MODEL.json", help="model file written by fogd-train")
    p.add_argument("run", metavar="RUN.csv", help="recorded run to compensate")
    p.add_argument("-o", "--output", metavar="OUT.csv", help="compensated CSV to write ('-' for stdout)")
    p.add_argument("--block-s", type=positive_float, default=BLOCK_S, help="block length for table 4, in seconds")
    p.add_argument(
        "--settle-s", type=non_negative_float, default=SETTLE_S,
        help="thermal settling at the start of the run that table 4 skips, in seconds (0 when the run is too "
        "short for one block after it)",
    )  # fmt: skip
    p.add_argument(
        "--allan-plot", metavar="PNG",
        help="write a log-log figure of the overlapping Allan deviation before and after compensation",
    )  # fmt: skip
    p.add_argument("--no-allan", action="store_true", help="skip the Allan deviation summary (long runs: a few seconds)")
    p.add_argument(
        "--from", dest="from_s", metavar="T", type=float,
        help="compensate from the first row at or after t_s = T as a daemon restarted there would: the rows before "
        "it are the thermal history it finds in its state file (docs/reference/thermal-state.md); without it the "
        "run starts cold and its first samples are flagged WARMING, as the daemon's",
    )  # fmt: skip
    p.add_argument("--warming", choices=MODES, default=MODES[0], help="what WARMING samples get (fogd's warming key)")
    p.add_argument("--warming-tolerance-dph", type=positive_float, default=TOLERANCE_DPH, metavar="DPH",
                   help="fogd's warming_tolerance_dph")
    return p


def body(argv: Sequence[str] | None) -> int:
    args = parser().parse_args(argv)
    if args.allan_plot and os.path.isdir(args.allan_plot):
        raise UsageError(f"--allan-plot {args.allan_plot}: a directory; give a file name such as allan.png")
    for output in (args.output, args.allan_plot):
        if output:
            check_output(output, [args.model, args.run])  # before the replay, not after it
    models = load_model(args.model, args.run)
    recorded = read_run(args.run)
    if models.version == modelfile.CHANNELS_VERSION:
        return _replay_channels(args, models, recorded)
    model = models[SINGLE_CHANNEL]
    recorded, result = _replay_one(args, model, recorded)
    if args.output:
        write_csv(
            args.output,
            {
                # + 0.0 turns -0.0 into 0.0: "-0" in a CSV reads as a sign where there is none
                "t_s": recorded.t_s,
                "rate_dph": recorded.rate_dph + 0.0,
                "temp_c": recorded.temp_c + 0.0,
                "temp_rate_cps": np.asarray(result.temp_rate_cps) + 0.0,
                "comp_dph": np.asarray(result.comp_dph) + 0.0,
                "rate_comp_dph": np.asarray(result.rate_comp_dph) + 0.0,
                "flags": result.flags,
            },
            OUTPUT_FORMATS,
            inputs=[args.model, args.run],
        )
    table = replay_table(recorded, result, args.block_s, settle_s=args.settle_s)
    report = sys.stderr if args.output == "-" else sys.stdout
    print(
        f"Table 4: {recorded.name} with {model.name} ({model.method}), {table.blocks} blocks of {args.block_s:g} s "
        f"{_settling(table, args.settle_s)}", file=report,
    )  # fmt: skip
    rows = [("Before compensation", table.before), (model.method, table.after)]
    if table.best is not None:
        rows.append(("Best possible (true error removed)", table.best))
    print(error_table(rows), file=report)
    print(_domain_shares(table, model.meta.get("domain_guard") is not None), file=report)
    print(_flag_counts(result.flags), file=report)
    if not args.no_allan or args.allan_plot:
        curves = allan_curves(recorded, result)
        print("", file=report)
        for line in summary_lines(curves):
            print(line, file=report)
        if args.allan_plot:
            plot(args.allan_plot, curves, f"{recorded.name}: overlapping Allan deviation ({model.method})")
            print(f"wrote {args.allan_plot}", file=sys.stderr)
    return 0


def _replay_channels(args: argparse.Namespace, models: ChannelModels, recorded: Run) -> int:
    """An IMU run with a multi-channel model: every channel the model covers compensated, the others passed
    through (and said so); table 4 of each compensated channel."""
    if tuple(recorded.channels) == (SINGLE_CHANNEL,):
        raise InputError(f"{args.model} compensates the channels {', '.join(models)} of an IMU; {args.run} is a "
                         "single-axis run (t_s,rate_dph,temp_c): replay it with a single-axis model")  # fmt: skip
    covered, passed = models.split(recorded.channels)
    if args.from_s is not None:
        raise UsageError("--from replays a single-channel model; a multi-channel run starts cold")
    results = replay_channels({channel: models[channel] for channel in models}, recorded)
    first = models[covered[0]] if covered else next(iter(models.values()))
    mark_cold(WarmingBound(first, recorded.rate_hz, tolerance_dph=args.warming_tolerance_dph), recorded.t_s,
              recorded.temp_c, [results[channel] for channel in (*covered, *[c for c in results if c not in covered])],
              args.warming)  # fmt: skip
    if args.output:
        columns: dict[str, np.ndarray] = {"t_s": recorded.t_s, "temp_c": recorded.temp_c + 0.0}
        formats = {"t_s": OUTPUT_FORMATS["t_s"], "temp_c": OUTPUT_FORMATS["temp_c"]}
        for channel, values in recorded.channels.items():
            columns[channel] = values + 0.0
            if channel in results:
                comp, compensated, flags = output_columns(channel)
                columns[comp] = np.asarray(results[channel].comp_dph) + 0.0
                columns[compensated] = np.asarray(results[channel].rate_comp_dph) + 0.0
                columns[flags] = results[channel].flags
                formats[flags] = OUTPUT_FORMATS["flags"]
        write_csv(args.output, columns, formats, inputs=[args.model, args.run])
    report = sys.stderr if args.output == "-" else sys.stdout
    print(f"{recorded.name} with {models.name}: compensated {', '.join(covered)}", file=report)
    if passed:
        print(f"passed through unchanged (no model for them in the file): {', '.join(passed)}", file=report)
    for channel in covered:
        model, result, view = models[channel], results[channel], recorded.channel(channel)
        table = replay_table(view, result, args.block_s, settle_s=args.settle_s)
        print(f"\nTable 4: {recorded.name}, {channel} with {model.name} ({model.method}), {table.blocks} blocks of "
              f"{args.block_s:g} s {_settling(table, args.settle_s)}", file=report)  # fmt: skip
        rows = [("Before compensation", table.before), (model.method, table.after)]
        if table.best is not None:
            rows.append(("Best possible (true error removed)", table.best))
        print(error_table(rows, unit=channel_unit(channel)), file=report)
        print(_domain_shares(table, model.meta.get("domain_guard") is not None), file=report)
        print(_flag_counts(result.flags), file=report)
        if not args.no_allan or args.allan_plot:
            curves = allan_curves(view, result)
            for line in summary_lines(curves, channel_unit(channel)):
                print(line, file=report)
            if args.allan_plot:
                stem, suffix = os.path.splitext(args.allan_plot)
                path = f"{stem}-{channel}{suffix or '.png'}"
                plot(path, curves, f"{recorded.name}, {channel}: overlapping Allan deviation ({model.method})",
                     channel_unit(channel))  # fmt: skip
                print(f"wrote {path}", file=sys.stderr)
    return 0


def _replay_one(args: argparse.Namespace, model, recorded: Run) -> tuple[Run, Compensated]:
    """The run (from --from on) and its compensation under the daemon's thermal rules (fogd.core.warming)."""
    start = 0 if args.from_s is None else int(np.searchsorted(recorded.t_s, args.from_s))
    if start >= recorded.rows:
        raise InputError(f"{args.run}: no row at or after t_s = {args.from_s:g} s (--from)")
    compensator = Compensator(model, recorded.rate_hz)
    if start == 0 and recorded.rows <= compensator.bank.warmup:
        replay(model, recorded)  # its one-line error: shorter than the estimator window
    result = replay_rules(compensator, recorded.t_s, recorded.rate_dph, recorded.temp_c, start,
                          mode=args.warming, tolerance_dph=args.warming_tolerance_dph)  # fmt: skip
    if start:
        rows = slice(start, None)
        recorded = replace(recorded, t_s=recorded.t_s[rows], rate_dph=recorded.rate_dph[rows],
                           temp_c=recorded.temp_c[rows], extra={k: v[rows] for k, v in recorded.extra.items()},
                           channels={k: v[rows] for k, v in recorded.channels.items()})  # fmt: skip
    return recorded, result


def load_model(path: str, run_path: str) -> ChannelModels:
    """The model file's models by channel (a single-channel file: the one channel rate_dph); when it will not
    load and the arguments look swapped (a CSV first, a .json second), the one-line error says so and gives
    the usage."""
    try:
        return modelfile.load_channels(path)
    except ModelFileError as error:
        if isinstance(error, NoModelFileError) or not run_path.lower().endswith(".json"):
            raise
        raise UsageError(f"{error}; the arguments look swapped: usage {PROG} MODEL.json RUN.csv") from None


def _settling(table: ReplayTable, settle_s: float) -> str:
    if table.settle_fallback:
        return f"from the first row (too short for one block after {settle_s:g} s of settling)"
    return f"from {table.settle_s:g} s after the first row"


def _domain_shares(table: ReplayTable, guarded: bool) -> str:
    clamped = f"{_percent(table.clamped_share)} were clamped"
    if not guarded:
        return f"domain: no guard in this model; {clamped}"
    return f"domain guard: {_percent(table.fallback_share)} of samples took the linear fallback; {clamped}"


def _percent(share: float) -> str:
    return "-" if share != share else f"{100.0 * share:.1f} %"  # NaN: no block in the table


def _flag_counts(flags) -> str:
    counts = [f"{flag.name} {int(((flags & flag) != 0).sum())}" for flag in Flag if ((flags & flag) != 0).any()]
    return f"{flags.size} rows; flagged: {', '.join(counts) if counts else 'none'}"


def main(argv: Sequence[str] | None = None) -> int:
    return run(PROG, body, argv)


if __name__ == "__main__":
    sys.exit(main())
