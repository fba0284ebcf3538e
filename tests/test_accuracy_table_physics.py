"""tools/accuracy_table.py --physics: another simulated gyro from the command line, checked before any work."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pytest

from fogd.simulation.simulator import params_for

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tools"))
import accuracy_table  # noqa: E402


def test_a_setting_takes_its_fields_type() -> None:
    assert accuracy_table.physics_setting("sensor_on=baseplate") == ("sensor_on", "baseplate")
    assert accuracy_table.physics_setting("coil_nodes=3") == ("coil_nodes", 3)
    key, value = accuracy_table.physics_setting("housing_tau_s=3000")
    assert key == "housing_tau_s" and isinstance(value, float) and value == 3000.0


@pytest.mark.parametrize("text", ["bogus=1", "coil_nodes", "thermal=lumped", "sensor_resolution_c=1",
                                  "bias_corr_times_s=1", "coil_nodes=3.5"])  # fmt: skip
def test_what_the_table_sets_itself_or_no_field_is_refused(text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError):
        accuracy_table.physics_setting(text)


def test_the_settings_reach_the_simulated_gyro_beside_the_hysteresis_options() -> None:
    args = argparse.Namespace(hysteresis_dph=0.0, hysteresis_deadband_c=None,
                              physics=[("sensor_on", "baseplate"), ("coil_nodes", 3)])  # fmt: skip
    params = params_for("navigation", "diffusive", **accuracy_table.sim_overrides(args))
    assert (params.sensor_on, params.coil_nodes, params.hysteresis_dph) == ("baseplate", 3, 0.0)


def test_a_value_the_simulator_refuses_is_a_usage_error(capsys, monkeypatch) -> None:
    monkeypatch.setattr(sys, "argv", ["accuracy_table.py", "--physics", "coil_nodes=99", "--quick"])
    with pytest.raises(SystemExit) as raised:
        accuracy_table.main()
    assert raised.value.code == 2 and "coil_nodes must be a whole number" in capsys.readouterr().err
