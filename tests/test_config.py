"""fogd.serving.config: every bad key, type, range and a missing model is one line naming the key (exit 78 from the
real process); the shipped config/fogd.yaml loads and documents every key; the default config directory is
read when --config is not given."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from fogd.errors import ConfigError
from fogd.serving import config

ROOT = Path(__file__).resolve().parent.parent
FOGD = [sys.executable, "-m", "fogd.cli.daemon"]


@pytest.mark.parametrize(
    "text, message",
    [
        ("bogus: 1\n", "unknown key 'bogus'"),
        ("baud: fast\n", "key 'baud' must be a number"),
        ("baud: 10\n", "key 'baud'"),
        ("rate_hz: -1\n", "key 'rate_hz'"),
        ("rate_hz: true\n", "key 'rate_hz' must be a number"),
        ("temp_stale_s: 99999\n", "key 'temp_stale_s'"),
        ("status_interval_s: 0\n", "key 'status_interval_s'"),
        ("axis: w\n", "key 'axis' is 'w'"),
        ("model: [a, b]\n", "key 'model' must be a string"),
        ("metrics_port: 70000\n", "key 'metrics_port'"),
        ("metrics_address: localhost\n", "key 'metrics_address'"),
        ("protocol: null\n", "key 'protocol' needs a value"),
        ("- a list\n", "expected a mapping"),
        ("a: [\n", "not valid YAML"),
    ],
)
def test_bad_config_names_the_key(tmp_path, text, message):
    path = tmp_path / "fogd.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as caught:
        config.load(str(path))
    assert message in str(caught.value) and "\n" not in str(caught.value)


def test_numbers_as_yaml_writes_them_are_accepted(tmp_path):
    path = tmp_path / "fogd.yaml"
    path.write_text("rate_hz: 1e3\nbaud: 115200\nmetrics_port: 9108\nstats_file: none\n")
    assert config.load(str(path)) == {"rate_hz": 1000.0, "baud": 115200, "metrics_port": 9108, "stats_file": None}


def test_shipped_config_loads_and_documents_every_key():
    path = ROOT / "config" / "fogd.yaml"
    loaded = config.load(str(path))
    text = path.read_text()
    for option in config.OPTIONS:
        assert f"{option.key}:" in text, option.key
        if option.key not in ("port", "out"):  # out: required under systemd, so commented out
            assert option.key in loaded
            assert loaded[option.key] == option.default, option.key
    assert text.count("Default:") >= len(config.OPTIONS) - 1


def test_default_config_path_prefers_the_instance_file(tmp_path, monkeypatch):
    monkeypatch.setenv(config.CONFIG_DIR_ENV, str(tmp_path))
    assert config.default_config_path("ttyUSB0") is None
    (tmp_path / "fogd.yaml").write_text("")
    assert config.default_config_path("ttyUSB0") == str(tmp_path / "fogd.yaml")
    (tmp_path / "ttyUSB0.yaml").write_text("")
    assert config.default_config_path("ttyUSB0") == str(tmp_path / "ttyUSB0.yaml")
    monkeypatch.delenv(config.CONFIG_DIR_ENV)
    assert config.config_dir() == "/etc/fogd"


def run_fogd(tmp_path: Path, *args: str, env: dict | None = None) -> tuple[int, str]:
    result = subprocess.run([*FOGD, *args], capture_output=True, text=True, timeout=30, cwd=tmp_path,
                            env={**os.environ, config.CONFIG_DIR_ENV: str(tmp_path / "etc"), **(env or {})})  # fmt: skip
    assert "Traceback" not in result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("fogd: "), result.stderr
    return result.returncode, lines[0]


def test_process_refuses_bad_configs_with_exit_78(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("port: /dev/null\nrate_hz: 0\n")
    assert run_fogd(tmp_path, "--config", str(bad))[0] == 78
    status, line = run_fogd(tmp_path, "--port", "/dev/null", "--model", str(tmp_path / "nope.json"))
    assert status == 78 and "key 'model'" in line and "nope.json" in line
    status, line = run_fogd(tmp_path, "--config", str(tmp_path / "absent.yaml"))
    assert status == 78 and "absent.yaml" in line


def test_default_config_directory_is_read_and_the_command_line_wins(tmp_path):
    (tmp_path / "etc").mkdir()
    (tmp_path / "etc" / "fogd.yaml").write_text(f"port: {tmp_path / 'ttyFROMCONFIG'}\nmodel: {tmp_path / 'm.json'}\n")
    status, line = run_fogd(tmp_path)
    assert status == 78 and "m.json" in line  # the model named in the default config file
    (tmp_path / "etc" / "fogd.yaml").write_text(f"port: {tmp_path / 'ttyFROMCONFIG'}\nbogus: 1\n")
    status, line = run_fogd(tmp_path)
    assert status == 78 and "unknown key 'bogus'" in line and "fogd.yaml" in line
    (tmp_path / "etc" / "fogd.yaml").write_text(f"port: {tmp_path / 'ttyFROMCONFIG'}\nrate_hz: 500\n")
    demo_model = ROOT / "fogd" / "data" / "demo-model.json"
    status, line = run_fogd(tmp_path, "--model", str(demo_model))
    assert status == 74 and "ttyFROMCONFIG" in line  # port from the file, model from the command line
    status, line = run_fogd(tmp_path, "--model", str(demo_model), "--port", str(tmp_path / "ttyCLI"))
    assert status == 74 and "ttyCLI" in line
