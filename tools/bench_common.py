"""Shared pieces of the benchmarks: the machine description, simulated runs in memory, models trained the way
fogd-train trains them, a timer that takes the best of a few repeats, the table printer, and the writer of a
generated results page (docs/results/*.md: a header saying how, when, from which commit and on what machine it was
measured, then what the tool printed; replaced whole, never edited by hand).

Every benchmark reports ratios against a baseline measured in the same process and the same minute: this
machine is shared and noisy, so absolute times move while ratios hold.
"""

from __future__ import annotations

import contextlib
import datetime
import io
import os
import platform
import shlex
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # run as `python tools/bench_x.py` from anywhere

from fogd.calibration.models import FitOptions  # noqa: E402
from fogd.core.atomic import replaced  # noqa: E402
from fogd.calibration.training import TrainConfig, Trained, train  # noqa: E402
from fogd.core.inputs import default_inputs, parse_inputs  # noqa: E402
from fogd.core.runio import Run  # noqa: E402
from fogd.simulation import profiles  # noqa: E402
from fogd.simulation.simulator import Simulation  # noqa: E402


ROOT = Path(__file__).resolve().parent.parent


def cpu_model() -> str:
    """The CPU's model name from /proc/cpuinfo ("unknown CPU" where there is none)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return "unknown CPU"


def machine() -> str:
    """nproc, CPU model, Python and numpy versions: the line every table is printed under."""
    cpu = cpu_model()
    return (
        f"machine: {os.cpu_count()} CPUs ({cpu}), Linux {platform.release()}, Python {platform.python_version()}, "
        f"numpy {np.__version__}"
    )


def sim_run(profile: str, rate_hz: float, seed: int = 1, rows: int | None = None, start_s: float = 0.0) -> Run:
    """A fogd-sim run held in memory as a `Run` (`rows` rows from `start_s` if given)."""
    simulation = Simulation(profiles.builtin(profile), rate_hz, seed)
    start = int(round(start_s * rate_hz))
    columns = simulation.columns(start, None if rows is None else start + rows)
    return Run(
        path=f"<sim {profile} {rate_hz:g} Hz>",
        t_s=columns["t_s"],
        rate_dph=columns["rate_dph"],
        temp_c=columns["temp_c"],
        rate_hz=rate_hz,
        sha256="",
        extra={"true_error_dph": columns["true_error_dph"]},
    )


def trained_model(run: Run, method: str, *, particles: int = 20, iterations: int = 20, fitness: str = "train",
                  trend: bool | str = False, seed: int = 0, inputs: str | None = None) -> Trained:  # fmt: skip
    """A model fitted as fogd-train fits it, on the paper's inputs (temperature and its eq. 16 rate) unless
    `inputs` (the --inputs syntax) says otherwise; pso-svr defaults to the paper's plain SVR with its fitness."""
    options = FitOptions(particles=particles, iterations=iterations, fitness=fitness, trend=trend, seed=seed, progress=False)
    specs = default_inputs() if inputs is None else parse_inputs(inputs)
    return train([run], TrainConfig(method=method, inputs=specs, fit=options, name=f"bench-{method}"))


def best_time(function: Callable[[], object], repeats: int = 3) -> float:
    """Seconds of the fastest of `repeats` calls (the least disturbed by other load)."""
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        best = min(best, time.perf_counter() - start)
    return best


def print_table(title: str, header: list[str], rows: list[list[object]]) -> None:
    """A plain aligned table (markdown pipes, so it pastes into a docs page)."""
    cells = [header] + [[str(cell) for cell in row] for row in rows]
    widths = [max(len(row[i]) for row in cells) for i in range(len(header))]
    print(f"\n{title}")
    for number, row in enumerate(cells):
        print("| " + " | ".join(cell.ljust(width) for cell, width in zip(row, widths)) + " |")
        if number == 0:
            print("|" + "|".join("-" * (width + 2) for width in widths) + "|")
    sys.stdout.flush()


def verdict(ok: bool) -> str:
    return "met" if ok else "MISSED"


def us(seconds: float) -> str:
    return f"{seconds * 1e6:.2f}"


def git_commit() -> str:
    """The checkout's commit, with "+ uncommitted changes" when the working tree differs from it."""
    def git(*args: str) -> str:
        try:
            return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, timeout=30).stdout.strip()
        except (OSError, subprocess.SubprocessError):
            return ""

    commit = git("rev-parse", "--short=12", "HEAD") or "unknown (not a git checkout)"
    dirty = git("status", "--porcelain", "--untracked-files=no")
    return f"{commit} + uncommitted changes" if dirty else commit


def results_header(title: str, command: list[str], settings: str = "") -> str:
    """The header of a generated results page: the command that wrote it, the date (UTC), the commit and the
    machine (CPU model, cores, load), and `settings` (what the run shortened, in words)."""
    now = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    try:
        load = ", load average %.1f / %.1f / %.1f at the start" % os.getloadavg()
    except OSError:
        load = ""
    lines = [
        f"# {title}",
        "",
        "<!-- Generated: do not edit by hand. Re-run the command below; it replaces this page whole. -->",
        "",
        f"- command: `{shlex.join(command)}`",
        f"- date: {now}",
        f"- commit: {git_commit()}",
        f"- machine: {cpu_model()}, {os.cpu_count()} cores{load}; Linux {platform.release()}, "
        f"Python {platform.python_version()}, numpy {np.__version__}",
    ]
    if settings:
        lines.append(f"- settings: {settings}")
    return "\n".join(lines) + "\n"


def write_results_page(path: str | os.PathLike[str], header: str, body: str) -> None:
    """`header` (results_header's) then `body`, replacing `path` whole (temporary file and rename: a failed
    write leaves the old page as it was); fogd.errors.OutputError when it cannot be written."""
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)  # docs/results/ in a fresh checkout
    with replaced(os.fspath(path)) as stream:
        stream.write(header + "\n" + spaced_tables(body).rstrip() + "\n")


def spaced_tables(text: str) -> str:
    """`text` with a blank line before and after each run of table lines (`|...`): a markdown table must not
    touch the paragraph above it, as the tools' printed titles do."""
    out: list[str] = []
    previous = ""
    for line in text.splitlines():
        is_table, was_table = line.startswith("|"), previous.startswith("|")
        if previous.strip() and is_table != was_table:
            out.append("")
        out.append(line)
        previous = line
    return "\n".join(out) + "\n"


class _Tee(io.TextIOBase):
    """Writes to the real stdout and keeps a copy."""

    def __init__(self, out) -> None:
        self.out, self.kept = out, io.StringIO()

    def write(self, text: str) -> int:
        self.kept.write(text)
        return self.out.write(text)

    def flush(self) -> None:
        self.out.flush()


@contextlib.contextmanager
def captured_stdout() -> Iterator[io.StringIO]:
    """What is printed inside the block still goes to stdout, and is kept in the StringIO yielded (read it
    after the block): a tool prints as always and writes the same text into its results page."""
    tee = _Tee(sys.stdout)
    with contextlib.redirect_stdout(tee):
        yield tee.kept
