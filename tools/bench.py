"""Every fogd benchmark, one after the other, each in its own process: per-point cost (paper table 5), replay
throughput, the daemon over pty loopback and training. Each prints its table with ratios against baselines
measured in the same run, and 'met' or 'MISSED' against the targets of issue 5.

Usage: python tools/bench.py [--quick] [--only point replay daemon train] [--strict]
  --quick   tiny sizes, seconds in all (a smoke test: the numbers mean little)
  --strict  exit 1 if any benchmark misses a target (or fails)
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
SECTIONS = {"point": "bench_point.py", "replay": "bench_replay.py", "daemon": "bench_daemon.py", "train": "bench_train.py"}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="tiny sizes (smoke test)")
    parser.add_argument("--strict", action="store_true", help="exit 1 if a target is missed")
    parser.add_argument("--only", nargs="+", choices=tuple(SECTIONS), default=list(SECTIONS))
    args = parser.parse_args(argv)
    failed = []
    for name in args.only:
        command = [sys.executable, "-W", "ignore", str(HERE / SECTIONS[name])]
        command += ["--quick"] * args.quick + ["--strict"] * args.strict
        print(f"\n== {name}: {' '.join(command[1:])}", flush=True)
        start = time.perf_counter()
        code = subprocess.call(command)
        print(f"== {name}: {'ok' if code == 0 else f'exit {code}'} in {time.perf_counter() - start:.0f} s", flush=True)
        if code:
            failed.append(name)
    if failed:
        print(f"\n{'missed targets or failed' if args.strict else 'failed'}: {', '.join(failed)}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
