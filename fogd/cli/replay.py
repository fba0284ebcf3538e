"""`fogd-replay`: run a recorded CSV through the daemon's compensator and print the paper's table 4."""

from __future__ import annotations

import sys
from typing import Sequence

from fogd import modelfile
from fogd.cli.common import ArgumentParser, DefaultsHelpFormatter, positive_float, run
from fogd.flags import Flag
from fogd.allan import plot, summary_lines
from fogd.replay import allan_curves, replay, replay_table
from fogd.runio import read_run, write_csv
from fogd.tables import error_table

PROG = "fogd-replay"
OUTPUT_FORMATS = {
    "t_s": "%.6f",
    "rate_dph": "%.9g",
    "temp_c": "%.9g",
    "temp_rate_cps": "%.9g",
    "comp_dph": "%.9g",
    "rate_comp_dph": "%.9g",
    "flags": "%d",
}


def parser() -> ArgumentParser:
    p = ArgumentParser(
        prog=PROG,
        description="Compensate a recorded run (CSV t_s,rate_dph,temp_c) with a fogd model, exactly as the "
        "daemon would, and write t_s,rate_dph,temp_c,temp_rate_cps,comp_dph,rate_comp_dph,flags: one row per "
        "input row, in order. Prints the paper's table 4 (block-mean error before and after).",
        epilog=f"flags bits: {', '.join(f'{flag.name}={int(flag)}' for flag in Flag)}",
        formatter_class=DefaultsHelpFormatter,
    )
    p.add_argument("model", metavar="MODEL.json", help="model file written by fogd-train")
    p.add_argument("run", metavar="RUN.csv", help="recorded run to compensate")
    p.add_argument("-o", "--output", metavar="OUT.csv", help="compensated CSV to write ('-' for stdout)")
    p.add_argument("--block-s", type=positive_float, default=100.0, help="block length for table 4, in seconds")
    p.add_argument(
        "--allan-plot", metavar="PNG",
        help="write a log-log figure of the overlapping Allan deviation before and after compensation",
    )  # fmt: skip
    p.add_argument("--no-allan", action="store_true", help="skip the Allan deviation summary (long runs: a few seconds)")
    return p


def body(argv: Sequence[str] | None) -> int:
    args = parser().parse_args(argv)
    model = modelfile.load(args.model)
    recorded = read_run(args.run)
    result = replay(model, recorded)
    if args.output:
        write_csv(
            args.output,
            {
                "t_s": recorded.t_s,
                "rate_dph": recorded.rate_dph,
                "temp_c": recorded.temp_c,
                "temp_rate_cps": result.temp_rate_cps,
                "comp_dph": result.comp_dph,
                "rate_comp_dph": result.rate_comp_dph,
                "flags": result.flags,
            },
            OUTPUT_FORMATS,
        )
    table = replay_table(recorded, result, args.block_s)
    report = sys.stderr if args.output == "-" else sys.stdout
    print(f"Table 4: {recorded.name} with {model.name} ({model.method}), {table.blocks} blocks of {args.block_s:g} s", file=report)
    rows = [("Before compensation", table.before), (model.method, table.after)]
    if table.best is not None:
        rows.append(("Best possible (true error removed)", table.best))
    print(error_table(rows), file=report)
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


def _flag_counts(flags) -> str:
    counts = [f"{flag.name} {int(((flags & flag) != 0).sum())}" for flag in Flag if ((flags & flag) != 0).any()]
    return f"{flags.size} rows; flagged: {', '.join(counts) if counts else 'none'}"


def main(argv: Sequence[str] | None = None) -> int:
    return run(PROG, body, argv)


if __name__ == "__main__":
    sys.exit(main())
