"""The layout's rules (docs/architecture.md): import-linter's contracts in pyproject.toml hold, nothing
outside fogd/cli imports the command line, and the repository points to no path outside itself."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LINT_IMPORTS = Path(sys.executable).with_name("lint-imports")


@pytest.mark.skipif(not LINT_IMPORTS.exists(), reason="import-linter is not installed (pip install -e '.[test]')")
def test_import_contracts_hold():
    done = subprocess.run([str(LINT_IMPORTS), "--no-cache", "--config", str(ROOT / "pyproject.toml")],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    assert "0 broken" in done.stdout


def _tracked(*patterns: str) -> list[Path]:
    listed = subprocess.run(["git", "ls-files", *patterns], cwd=ROOT, capture_output=True, text=True)
    if listed.returncode != 0:
        pytest.skip("not a git checkout")
    return [ROOT / name for name in listed.stdout.split()]


def test_only_the_commands_import_the_command_line():
    offenders = [
        f"{path.relative_to(ROOT)}:{number}"
        for path in _tracked("fogd/*.py")
        if path.parent.name != "cli" or path.parent.parent.name != "fogd"
        for number, line in enumerate(path.read_text().splitlines(), 1)
        if re.match(r"\s*(from|import)\s+fogd\.cli\b", line)
    ]
    assert offenders == []


def test_no_path_outside_the_repository_in_code_or_docs():
    outside = re.compile(r"/work/|\.\./shared\b|\bshared/(paper|design\.md|protocols\.md)")
    offenders = [
        f"{path.relative_to(ROOT)}:{number}: {line.strip()}"
        for path in _tracked("*.py", "*.md", "*.toml", "*.yaml", "config/*", ".ci/*")
        if path.is_file()
        for number, line in enumerate(path.read_text(errors="replace").splitlines(), 1)
        if outside.search(line) and path != Path(__file__).resolve()
    ]
    assert offenders == []
