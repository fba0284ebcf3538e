"""The service install end to end, staged under DESTDIR: config/install-service links every console script of
pyproject.toml into /usr/local/bin, puts the file the units' Documentation= names where it says, never
overwrites an existing config; the installed units pass `systemd-analyze verify` with their installed
ExecStart; and a model installed before the first start is readable by a dynamic user once systemd has done
what StateDirectory= does at start (the directory handed to the user, its mode set), and not before."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from fogd import __version__

ROOT = Path(__file__).resolve().parent.parent
INSTALL = ROOT / "config" / "install-service"
VENV = Path(sys.executable).parent.parent
DEMO_MODEL = ROOT / "fogd" / "data" / "demo-model.json"
DYNAMIC_UID = 61234  # no such user: like systemd's DynamicUser, it owns nothing but what it is handed


def scripts() -> list[str]:
    """The console scripts of pyproject.toml's [project.scripts] (tomllib is 3.11+; fogd runs on 3.10)."""
    section = (ROOT / "pyproject.toml").read_text().split("[project.scripts]\n", 1)[1].split("\n[", 1)[0]
    return re.findall(r"^([\w-]+)\s*=", section, flags=re.M)


def install(destdir: Path) -> subprocess.CompletedProcess:
    return subprocess.run([str(INSTALL), str(VENV)], env={**os.environ, "DESTDIR": str(destdir)},
                          capture_output=True, text=True, timeout=60)  # fmt: skip


@pytest.fixture(scope="module")
def staged(tmp_path_factory) -> Path:
    destdir = tmp_path_factory.mktemp("root")
    result = install(destdir)
    assert result.returncode == 0, result.stderr
    return destdir


def test_every_command_is_on_the_path_with_its_version(staged):
    assert {"fogd", "fogd-record", "fogd-train", "fogd-top"} <= set(scripts())
    for name in scripts():
        link = staged / "usr" / "local" / "bin" / name
        assert link.exists(), name
        result = subprocess.run([str(link), "--version"], capture_output=True, text=True, timeout=60)
        assert result.returncode == 0 and result.stdout.strip() == f"{name} {__version__}", (name, result)


@pytest.mark.parametrize("unit", ["fogd.service", "fogd@.service"])
def test_documentation_named_by_the_units_is_installed(staged, unit):
    text = (staged / "etc" / "systemd" / "system" / unit).read_text()
    documents = re.findall(r"^Documentation=file:(\S+)", text, flags=re.M)
    assert documents
    for document in documents:
        assert (staged / document.lstrip("/")).read_text() == (ROOT / "README.md").read_text()


def test_an_existing_config_is_kept_and_bad_usage_is_64(tmp_path):
    (tmp_path / "etc" / "fogd").mkdir(parents=True)
    (tmp_path / "etc" / "fogd" / "fogd.yaml").write_text("port: /dev/fog0\n")
    assert install(tmp_path).returncode == 0
    assert (tmp_path / "etc" / "fogd" / "fogd.yaml").read_text() == "port: /dev/fog0\n"
    assert subprocess.run([str(INSTALL)], capture_output=True, timeout=10).returncode == 64
    assert subprocess.run([str(INSTALL), str(tmp_path / "no-venv")], capture_output=True, timeout=10).returncode == 66


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze not installed")
@pytest.mark.parametrize("unit", ["fogd.service", "fogd@.service"])
def test_installed_units_verify_with_their_installed_commands(staged, tmp_path, unit):
    text = (staged / "etc" / "systemd" / "system" / unit).read_text()
    assert "ExecStart=/usr/local/bin/fogd " in text
    # verify checks that ExecStart exists: point it at the staged /usr/local/bin, the rest as installed
    (tmp_path / unit).write_text(text.replace("/usr/local/bin/", f"{staged}/usr/local/bin/"))
    target = unit.replace("@.", "@ttyUSB0.")
    if target != unit:
        shutil.copy(tmp_path / unit, tmp_path / target)
    result = subprocess.run(["systemd-analyze", "verify", target], cwd=tmp_path, capture_output=True, text=True,
                            timeout=60, env={"SYSTEMD_UNIT_PATH": f"{tmp_path}:", "PATH": "/usr/bin:/bin"})  # fmt: skip
    complaints = [line for line in (result.stdout + result.stderr).splitlines() if "fogd" in line]
    assert result.returncode == 0 and complaints == [], result.stdout + result.stderr


def run_as_dynamic_user(staged: Path, model: Path, tmp_path: Path) -> subprocess.CompletedProcess:
    """The installed fogd (what the staged link points to: pytest's own directories are closed to other users)
    as an unprivileged uid with no groups, on a pty it may open, for one second."""
    master, slave = os.openpty()
    path = os.ttyname(slave)
    os.close(slave)
    os.chown(path, DYNAMIC_UID, DYNAMIC_UID)
    try:
        command = ["setpriv", f"--reuid={DYNAMIC_UID}", f"--regid={DYNAMIC_UID}", "--clear-groups",
                   os.path.realpath(staged / "usr" / "local" / "bin" / "fogd"), "--port", path, "--model", str(model),
                   "--protocol", "kvh-a", "--out", os.devnull, "--stats-file", "none", "--duration-s", "1"]  # fmt: skip
        return subprocess.run(command, capture_output=True, text=True, timeout=30, cwd=tmp_path)
    finally:
        os.close(master)


@pytest.mark.skipif(os.geteuid() != 0 or shutil.which("setpriv") is None, reason="needs root and setpriv")
def test_a_model_installed_before_first_start_is_readable_by_the_dynamic_user(staged):
    unit = (staged / "etc" / "systemd" / "system" / "fogd.service").read_text()
    mode = int(re.search(r"^StateDirectoryMode=(\d+)", unit, flags=re.M).group(1), 8)
    tmp_path = Path(tempfile.mkdtemp(prefix="fogd-state-"))  # open to other users, unlike pytest's tmp_path
    try:
        check_model_access(tmp_path, staged, mode)
    finally:
        shutil.rmtree(tmp_path)


def check_model_access(tmp_path: Path, staged: Path, mode: int) -> None:
    state = tmp_path / "var" / "lib" / "fogd"
    model = state / "model.json"
    # the README's step, staged: install -D -m 0644 model.json /var/lib/fogd/model.json
    subprocess.run(["install", "-D", "-m", "0644", str(DEMO_MODEL), str(model)], check=True, timeout=10)
    os.chmod(state, mode)
    os.chmod(tmp_path, 0o755)
    before = run_as_dynamic_user(staged, model, tmp_path)
    assert before.returncode == 78 and "permission denied" in before.stderr  # root's 0750 directory: not the user's
    # what systemd does at every start for StateDirectory=: the directory and everything in it handed to the user
    for directory, _, files in os.walk(state):
        os.chown(directory, DYNAMIC_UID, DYNAMIC_UID)
        for name in files:
            os.chown(os.path.join(directory, name), DYNAMIC_UID, DYNAMIC_UID)
    after = run_as_dynamic_user(staged, model, tmp_path)
    assert after.returncode == 0 and "fogd.daemon: reading" in after.stderr, after.stderr
