"""Generated results pages (tools/bench_common.py, tools/accuracy_table.py --markdown, tools/bench.py --markdown):
a header saying how, when, from which commit and on what machine; the page replaced whole, or left as it was."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tools"))

import accuracy_table  # noqa: E402
import bench_common  # noqa: E402

from fogd.errors import OutputError  # noqa: E402


def test_the_header_names_the_command_the_commit_and_the_machine():
    header = bench_common.results_header("Accuracy", ["python", "tools/accuracy_table.py", "--quick"], "seed 1")
    commit = subprocess.run(["git", "rev-parse", "--short=12", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout
    assert header.startswith("# Accuracy\n")
    assert "- command: `python tools/accuracy_table.py --quick`" in header
    assert f"- commit: {commit.strip()}" in header
    assert f", {os.cpu_count()} cores" in header and "- date: " in header and " UTC" in header
    assert "- settings: seed 1" in header


def test_a_page_is_replaced_whole(tmp_path):
    page = tmp_path / "results" / "accuracy.md"
    bench_common.write_results_page(page, "# A\n", "first run\n| a |\n|---|\n")
    bench_common.write_results_page(page, "# B\n", "second run")
    assert page.read_text() == "# B\n\nsecond run\n"
    assert os.listdir(page.parent) == ["accuracy.md"]  # no temporary file left


class _FailingBody(str):
    def splitlines(self, *args):  # the disk fills while the page is being written
        raise OSError(28, "No space left on device")


def test_a_failed_write_leaves_the_old_page(tmp_path):
    page = tmp_path / "performance.md"
    bench_common.write_results_page(page, "# old\n", "old figures")
    with pytest.raises(OutputError, match="No space left on device"):
        bench_common.write_results_page(page, "# new\n", _FailingBody("new figures"))
    assert page.read_text() == "# old\n\nold figures\n"
    assert os.listdir(tmp_path) == ["performance.md"]


def test_printed_tables_become_markdown():
    printed = ("# lumped coil, fine sensor\n#   linear: 0 s\n\nNavigation-grade gyro, seed 1\n"
               "| Scheme | paper-test |\n|---|---:|\n| linear | 13.90 |\nafter\n")  # fmt: skip
    body = bench_common.spaced_tables(accuracy_table.page_body(printed))
    assert "\n## lumped coil, fine sensor\n" in body and "\n- fitted linear: 0 s\n" in body
    assert "Navigation-grade gyro, seed 1\n\n| Scheme | paper-test |\n|---|---:|\n| linear | 13.90 |\n\nafter\n" in body
    assert "\n# " not in body  # no progress line left as a top-level heading
