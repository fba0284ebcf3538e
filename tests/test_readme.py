"""The command blocks of the README and of every page under docs/ run as written after the README's two set-up
commands. Every ```sh block is either run by a test here, in a scratch directory where `.venv` is this checkout's
venv, with options appended for shorter runs (never an edit of the text), or skipped for a reason named in
SKIPPED; a new block that is neither fails. A ```shell block is run by the test RUN_ELSEWHERE names for it (and,
where a later sh block needs its files, here too). Every command in every block calls fogd's tools through a
venv, and the set-up lines are what .ci/run runs."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from fogd import __version__

ROOT = Path(__file__).resolve().parent.parent
VENV = Path(sys.executable).parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
SETUP_DEMO = "python3 -m venv .venv && .venv/bin/pip install -e . && .venv/bin/fogd --demo"
SETUP_TESTS = "python3 -m venv .venv && .venv/bin/pip install -e '.[test]' && .venv/bin/python -m pytest -q"
# a line of the block -> why the block is not run here
SKIPPED = {
    "config/install-service /opt/fogd": "root and systemd; tests/test_service_install.py runs the install staged",
    "fogd-record --port /dev/ttyUSB0": "needs a gyro on a serial port",
    "--calibration cal-fast-cycle --calibration cal-soaks": "minutes of PSO (tools/accuracy_table.py)",
    "tools/accuracy_table.py --quick --imu": "minutes of PSO (tools/accuracy_table.py)",
    "tools/bench.py --markdown": "regenerates the results pages: tens of minutes",
}
# a line of the block -> the test here that runs it
RUN_HERE = {
    "fogd-train quickstart/heat.csv quickstart/cool.csv -o": "test_the_quick_start_shows_the_held_out_drift_removed",
    "fogd-train quickstart/heat.csv quickstart/cool.csv quickstart/cycle.csv": "test_guide_blocks_run_as_written",
    ".venv/bin/fogd --port /tmp/fog0": "test_guide_blocks_run_as_written",
    ".venv/bin/fogd-top --stats-file": "test_guide_blocks_run_as_written",
    ".venv/bin/fogd --port /tmp/imu0": "test_the_three_axis_imu_daemon_block_runs_after_its_training_block",
}
# a command in a run block -> options appended to it: shorter runs, nothing else
APPENDED = {
    ".venv/bin/fogd-train quickstart/": "--particles 4 --iterations 2 -q",
    ".venv/bin/fogd --port /tmp/fog0": "--duration-s 3",
    ".venv/bin/fogd --demo --stats-file": "--duration-s 40",  # outlives fogd-top and --status; then kill %1
    ".venv/bin/fogd-top --stats-file": "--count 6 --ascii",
    ".venv/bin/fogd --port /tmp/imu0": "--rate-hz 2 --duration-s 4",  # the IMU runs below are simulated at 2 Hz
}
# a line of a ```shell block -> the test that runs that block (with shorter runs)
RUN_ELSEWHERE = {
    "fogd-train imu-cal.csv": ("tests/test_cli_channels.py", "test_the_imu_guides_three_axis_block_runs_as_written"),
}
IMU_GUIDE = ROOT / "docs" / "guides" / "imu.md"
IMU_SHORTER = {".venv/bin/fogd-sim": "--rate-hz 2", ".venv/bin/fogd-train": "--particles 4 --iterations 2 -q"}
SEPARATORS = re.compile(r"(\s+#.*$|\s*&&\s*|\s*;\s*|\s+&(?=\s|$)\s*|\s*\|\s*)")
TOOLS = re.compile(r"^(fogd[\w-]*|python3?|pip3?|pytest)(\s|$)")


def sh_blocks(fence: str = "sh", pages: list[Path] | None = None) -> list[str]:
    """The ```FENCE blocks of `pages` (the README, then docs/ in path order)."""
    blocks = []
    for page in pages or PAGES:
        blocks += [m.group(1) for m in re.finditer(rf"^```{fence}\n(.*?)^```", page.read_text(), flags=re.S | re.M)]
    return blocks


def block_with(line: str) -> str:
    """The one sh block that holds `line`."""
    found = [block for block in sh_blocks() if line in block]
    assert len(found) == 1, f"{len(found)} blocks hold {line!r}"
    return found[0]


def append_options(line: str, options: dict[str, str]) -> str:
    """`line` with the options for each command it holds appended to that command (before a `#` comment,
    `&`, `;`, `&&` or `|`)."""
    parts = SEPARATORS.split(line)
    for index in range(0, len(parts), 2):
        for command, extra in options.items():
            if parts[index].startswith(command):
                parts[index] = f"{parts[index]} {extra}"
    return "".join(parts)


def run_block(block: str, cwd: Path, timeout_s: float = 300.0, options: dict[str, str] = APPENDED) -> subprocess.CompletedProcess:
    """The block as a bash script (stopping at the first failure); its background jobs are stopped after."""
    script = "set -e\n" + "\n".join(append_options(line, options) for line in block.splitlines()) + "\n"
    # files, not pipes: a background job (fogd-emu started with '&') holds them open after the script ends
    with open(cwd / "block.stdout", "w+") as stdout, open(cwd / "block.stderr", "w+") as stderr:
        process = subprocess.Popen(["bash", "-c", script], cwd=cwd, stdout=stdout, stderr=stderr, text=True,
                                   start_new_session=True, env={**os.environ, "MPLBACKEND": "Agg"})  # fmt: skip
        try:
            process.wait(timeout_s)
        finally:
            try:
                os.killpg(process.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
            if process.poll() is None:
                process.kill()
                process.wait()
        stdout.seek(0)
        stderr.seek(0)
        return subprocess.CompletedProcess(script, process.returncode, stdout.read(), stderr.read())


def newcomer(where: Path) -> Path:
    """`where` as the repository's root is after the set-up commands, without writing into the checkout:
    .venv is this venv, and the files the blocks read are linked in."""
    (where / ".venv").symlink_to(VENV)
    for name in ("config", "tools", "docs", "README.md", "pyproject.toml"):
        (where / name).symlink_to(ROOT / name)
    return where


@pytest.fixture(scope="module")
def scratch(tmp_path_factory) -> Path:
    return newcomer(tmp_path_factory.mktemp("newcomer"))


def test_every_block_is_run_or_skipped_for_a_reason_and_calls_the_venvs_tools():
    blocks = sh_blocks()
    assert blocks[0].splitlines() == [SETUP_DEMO, SETUP_TESTS]
    for block in blocks:
        for line in block.splitlines():
            for command in SEPARATORS.split(line)[::2]:
                command = command.strip()
                bare = TOOLS.match(command)
                # a bare fogd or python after the set-up is "command not found" or the wrong python
                assert not bare or command.startswith("python3 -m venv "), f"not through a venv: {line!r}"
    for key in SKIPPED:
        assert sum(key in block for block in blocks) == 1, f"SKIPPED {key!r} matches no block, or two: update the test"
    source = Path(__file__).read_text()
    for key, test in RUN_HERE.items():
        assert sum(key in block for block in blocks) == 1, f"RUN_HERE {key!r} matches no block, or two: update the test"
        assert f"def {test}(" in source, test
    for block in blocks[1:]:
        reasons = [key for key in (*SKIPPED, *RUN_HERE) if key in block]
        assert len(reasons) == 1, f"a block no test here runs or skips (name it in RUN_HERE or SKIPPED): {block[:120]!r}"
    for block in sh_blocks("shell"):
        runners = [runner for line, runner in RUN_ELSEWHERE.items() if line in block]
        assert len(runners) == 1, f"a ```shell block no test runs (name it in RUN_ELSEWHERE): {block[:80]!r}"
        path, name = runners[0]
        assert f"def {name}(" in (ROOT / path).read_text(), f"{path} has no test {name}"
        for line in block.splitlines():
            command = line.partition("  #")[0].strip()
            assert command.startswith(".venv/bin/"), f"not through a venv: {line!r}"


def test_pages_link_to_pages_that_exist():
    """Every relative markdown link in the README and docs/ names a file that is there."""
    for page in PAGES:
        for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", page.read_text()):
            if "://" in target:
                continue
            path = (page.parent / target).resolve()
            assert path.exists(), f"{page.relative_to(ROOT)} links to {target}, which is not there"


def test_set_up_lines_are_what_ci_runs():
    ci = (ROOT / ".ci" / "run").read_text().splitlines()[-1]
    assert ci.replace("pip install -q ", "pip install ") == SETUP_TESTS


def test_the_demo_runs_and_says_what_its_columns_mean(scratch):
    demo = SETUP_DEMO.split(" && ")[-1]
    result = run_block(f"{demo} --duration-s 6", scratch, timeout_s=60)
    assert result.returncode == 0, result.stderr
    assert result.stderr.count("drift = the gyro's rate averaged over the last 100 s") == 1
    lines = [line for line in result.stderr.splitlines() if line.startswith("drift raw ")]
    assert lines and "\r" not in result.stderr and "\x1b" not in result.stderr  # stderr is a pipe: plain lines
    temps = [float(re.search(r"\| T +(-?[\d.]+) C ", line).group(1)) for line in lines]
    assert max(temps) > 0.0, result.stderr  # the chamber is already warming the gyro from 0 C


def table4_rmse(output: str) -> dict[str, float]:
    """The held-out table 4 that fogd-train prints: scheme -> its RMSE (deg/h)."""
    table = output[output.index("Table 4: "):].split("\n\n", 1)[0].splitlines()[2:]
    rows = [re.fullmatch(r"(.*?)\s+(\S+)\s+(\S+)", line.strip()) for line in table]
    return {row.group(1): float(row.group(2)) for row in rows}


def quick_start_reduction(result: subprocess.CompletedProcess) -> float:
    """The share of the held-out run's drift the model took off, by fogd-train's table 4."""
    rmse = table4_rmse(result.stdout)
    before = rmse.pop("Before compensation")
    (model,) = [value for scheme, value in rmse.items() if not scheme.startswith("Best possible")]
    return 1.0 - model / before


def test_the_quick_start_shows_the_held_out_drift_removed(tmp_path):
    """The README's quick start exactly as a newcomer runs it (nothing appended: the default ladder trains in
    seconds): the run kept out of training loses at least 90 % of its drift, every file it writes is under
    quickstart/, which git ignores."""
    where = newcomer(tmp_path)
    before = set(os.listdir(where))
    result = run_block(block_with("fogd-train quickstart/heat.csv quickstart/cool.csv -o"), where, timeout_s=1200,
                       options={})  # fmt: skip
    assert result.returncode == 0, result.stderr[-3000:]
    assert quick_start_reduction(result) >= 0.90, result.stdout
    assert set(os.listdir(where)) - before == {"quickstart", "block.stdout", "block.stderr"}
    for name in os.listdir(where / "quickstart"):
        ignored = subprocess.run(["git", "check-ignore", "-q", f"quickstart/{name}"], cwd=ROOT, timeout=30)
        assert ignored.returncode == 0, f"quickstart/{name} would show in git status"


def test_guide_blocks_run_as_written(scratch):
    """The single-axis guide's calibration, then the operating guide's live run on its model and its watch."""
    result = run_block(block_with("quickstart/cycle.csv -o quickstart/model.json"), scratch)
    assert result.returncode == 0, result.stderr[-3000:]
    for name in ("heat.csv", "cool.csv", "cycle.csv", "test.csv", "model.json", "compensated.csv", "report/report.md"):
        assert (scratch / "quickstart" / name).stat().st_size > 0, name
    assert "Table 4: test.csv" in result.stdout
    fit_line = next(line for line in result.stderr.splitlines() if line.startswith("pso-svr: "))
    assert "epsilon_dph=" in fit_line and "epsilon=" not in fit_line, fit_line  # one epsilon, in deg/h

    result = run_block(block_with(".venv/bin/fogd --port /tmp/fog0"), scratch)
    assert result.returncode == 0, result.stderr[-3000:]
    lines = result.stdout.splitlines()  # fogd-emu's pty path, then fogd's CSV
    header = lines.index("t_s,rate_dph,temp_c,temp_rate_cps,comp_dph,rate_comp_dph,flags")
    assert len(lines) - header > 100, result.stderr

    result = run_block(block_with(".venv/bin/fogd-top --stats-file"), scratch)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    frames = result.stdout.split("\n\n")
    assert sum("  running  " in frame for frame in frames) >= 2, result.stdout
    assert f"fogd {__version__} pid " in result.stdout and "running, up" in result.stdout  # fogd --status
    assert "\x1b" not in result.stdout  # a pipe gets plain frames


def test_the_three_axis_imu_daemon_block_runs_after_its_training_block(scratch):
    """The IMU guide's training (```shell, shorter runs as tests/test_cli_channels.py makes them) then its sh
    block: the emulated IMU through fogd, which writes fogd-replay's six-channel columns."""
    training = sh_blocks("shell", [IMU_GUIDE])[0]
    daemon = block_with(".venv/bin/fogd --port /tmp/imu0")
    assert daemon in sh_blocks("sh", [IMU_GUIDE])
    shorter = "\n".join(append_options(line.partition("  #")[0].rstrip(), IMU_SHORTER) for line in training.splitlines())
    result = run_block(shorter, scratch, timeout_s=600)
    assert result.returncode == 0, result.stderr[-3000:]
    result = run_block(daemon, scratch)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "6 channels" in result.stderr and "passes through" not in result.stderr, result.stderr[-3000:]
    live = (scratch / "imu-live.csv").read_text().splitlines()
    assert live[0] == (scratch / "imu-compensated.csv").read_text().split("\n", 1)[0]
    assert len(live) > 100 and sum(name.startswith("flags_") for name in live[0].split(",")) == 6


def fogd_option_table() -> dict[str, str]:
    """The commands reference's fogd option table: option name -> default cell."""
    text = (ROOT / "docs" / "reference" / "commands.md").read_text()
    section = text[text.index("### `fogd` — the real-time daemon"):text.index("### `fogd-emu`")]
    return {match.group(1): match.group(2).strip() for match in re.finditer(r"^\| `--([\w-]+)[^`]*` \| ([^|]*) \|", section, flags=re.M)}


def test_fogd_defaults_agree_in_the_docs_help_and_config():
    from fogd.cli.daemon import parser
    from fogd.serving.config import OPTIONS

    table = fogd_option_table()
    helps = {action.dest: action.help for action in parser()._actions}
    for option in OPTIONS:
        cell = table.get(option.key.replace("_", "-"))
        assert cell is not None, f"--{option.key.replace('_', '-')} is not in docs/reference/commands.md's option table"
        help_text = helps[option.key] % {"default": option.default}
        if option.kind == "flag":  # true/false in the config, --NAME / --no-NAME on the command line
            assert cell == ("on" if option.default else "off") and f"default: {cell}" in help_text, (option.key, cell)
        elif option.default is None:
            assert cell in ("(required)", "none", "off"), (option.key, cell)
            assert "default" not in help_text or re.search(r"default: (off|run until)", help_text) or "required" in help_text
        elif option.key == "out":
            assert cell.startswith("`-` on a terminal") and "'-' when stdout is a terminal" in help_text
        else:
            shown = cell.strip("`")
            assert shown == str(option.default) or float(shown) == option.default, (option.key, cell)
            assert f"default: {option.default}" in help_text, (option.key, help_text)


def exit_codes(sentence: str) -> set[int]:
    return {int(code) for code in re.findall(r"(?<![\w.-])(\d{1,3})(?= )", sentence)}


def test_fogd_exit_statuses_agree_in_the_docs_and_help():
    commands = " ".join((ROOT / "docs" / "reference" / "commands.md").read_text().split())
    sentence = commands[commands.index("Exit status: 0 after SIGTERM/SIGINT"):]
    sentence = sentence[: sentence.index("Every error is one line")]
    helps = subprocess.run([str(VENV / "bin" / "fogd"), "--help"], capture_output=True, text=True, timeout=30).stdout
    epilog = " ".join(helps[helps.index("Exit status:"):].split())
    assert exit_codes(sentence) == exit_codes(epilog) == {0, 2, 3, 65, 74, 78}, (sentence, epilog)
    statuses = (ROOT / "docs" / "reference" / "exit-status.md").read_text()
    general = statuses[statuses.index("| exit | meaning | e.g. |"):statuses.index("## When fogd will not start")]
    assert {int(code) for code in re.findall(r"\| (\d+) \|", general)} == {0, 2, 3, 65, 66, 74, 78, 130}
