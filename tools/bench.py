"""Every fogd benchmark, one after the other, each in its own process: per-point cost (paper table 5), replay
throughput, the daemon over pty loopback (on a busy machine, and alone on a dedicated, otherwise idle box) and
training. Each prints its table with ratios against baselines
measured in the same run, and 'met' or 'MISSED' against the targets of issue 5.

Usage: python tools/bench.py [--quick] [--only point replay daemon train] [--strict] [--markdown PATH]
  --quick     tiny sizes, seconds in all (a smoke test: the numbers mean little)
  --strict    exit 1 if any benchmark misses a target (or fails)
  --markdown  also write everything printed as a results page (docs/results/performance.md), replaced whole,
              under a header with the command, date, commit and machine (tools/bench_common.py); a benchmark's
              line starting with EXPECT (the dedicated one's: what a user's own box should see) opens the page
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
PAGE_INTRO = """\
Each benchmark measures its baseline in the same run and prints the ratio: on a shared machine absolute times
move, ratios hold. The targets are the project's (issues 5, 10, 12, 13, 37); `met` or `MISSED` says where this run
stands. What each row measures is in the docstring of the tool that printed it (`tools/bench_*.py`).
"""
SECTIONS = {"point": "bench_point.py", "replay": "bench_replay.py", "daemon": "bench_daemon.py",
            "dedicated": "bench_daemon.py --dedicated", "train": "bench_train.py"}  # fmt: skip
EXPECT = "**On a dedicated box**"  # a line the page opens with (tools/bench_dedicated.py prints it)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="tiny sizes (smoke test)")
    parser.add_argument("--strict", action="store_true", help="exit 1 if a target is missed")
    parser.add_argument("--only", nargs="+", choices=tuple(SECTIONS), default=list(SECTIONS))
    parser.add_argument("--markdown", metavar="PATH", help="also write the tables as a results page, replaced whole")
    args = parser.parse_args(argv)
    if not args.markdown:
        return run_all(args, [])
    sys.path.insert(0, str(HERE))
    from bench_common import results_header, write_results_page
    from fogd.errors import FogdError

    header = results_header("Performance", ["python", "tools/bench.py", *(argv if argv is not None else sys.argv[1:])],
                            ("--quick: tiny sizes, a smoke test; " if args.quick else "") + "benchmarks " + ", ".join(args.only))
    body: list[str] = []
    code = run_all(args, body)
    try:
        write_results_page(args.markdown, header, page_body(body))
    except (OSError, FogdError) as error:
        print(f"bench: cannot write {args.markdown}: {error}", file=sys.stderr)
        return 1
    print(f"bench: wrote {args.markdown}", file=sys.stderr)
    return code


def page_body(kept: list[str]) -> str:
    """The results page below its header: the intro, the lines starting with EXPECT (what a user's own box should
    see), then every benchmark's printed lines."""
    expect = "".join(f"\n{line}" for line in kept if line.startswith(EXPECT))
    return PAGE_INTRO + expect + "".join(kept)


def run_all(args, kept: list[str]) -> int:
    """Each benchmark in its own process, its output printed (and its lines appended to `kept`)."""
    failed = []
    for name in args.only:
        script, *options = SECTIONS[name].split()
        command = [sys.executable, "-W", "ignore", str(HERE / script), *options]
        command += ["--quick"] * args.quick + ["--strict"] * args.strict
        print(f"\n== {name}: {' '.join(command[1:])}", flush=True)
        kept.append(f"\n## {name}: `python tools/{SECTIONS[name]}{' --quick' * args.quick}`\n\n")
        start = time.perf_counter()
        with subprocess.Popen(command, stdout=subprocess.PIPE, text=True) as process:
            for line in process.stdout:
                print(line, end="", flush=True)
                kept.append(line)
        code = process.returncode
        done = f"{'ok' if code == 0 else f'exit {code}'} in {time.perf_counter() - start:.0f} s"
        print(f"== {name}: {done}", flush=True)
        kept.append(f"\n{name}: {done}\n")
        if code:
            failed.append(name)
    if failed:
        print(f"\n{'missed targets or failed' if args.strict else 'failed'}: {', '.join(failed)}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
