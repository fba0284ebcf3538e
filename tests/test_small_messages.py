"""Issue 35.14's small messages: a NUL or non-UTF-8 byte in the YAML config is one line naming the line; a
model refused on load (and so on a reload) prints its value as a plain number, not `np.float64(...)`."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from fogd.core import modelfile
from fogd.core.estimator import EstimatorSettings
from fogd.core.inputs import default_inputs
from fogd.errors import ModelFileError


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        (b"rate_hz: 1000\nport: /dev/tty\x00S0\n", "fogd.yaml:2: a NUL byte; not a fogd config"),
        (b"rate_hz: 1000\n# chamber at 25 \xb0C\nport: /dev/ttyS0\n", "fogd.yaml:2: byte 0xb0 is not UTF-8; save the file as UTF-8"),
    ],
)  # fmt: skip
def test_a_nul_or_non_utf8_byte_in_the_config_is_one_line(tmp_path, content, expected):
    config = tmp_path / "fogd.yaml"
    config.write_bytes(content)
    result = subprocess.run([sys.executable, "-m", "fogd.cli.daemon", "--config", str(config)],
                            capture_output=True, text=True, timeout=120)  # fmt: skip
    assert result.returncode == 78
    assert result.stderr.strip().splitlines() == [f"fogd: {tmp_path}/{expected}"]


def test_a_model_refused_for_its_output_names_a_plain_number(tmp_path):
    doc = modelfile.document(
        name="huge", method="linear", inputs=default_inputs(EstimatorSettings(window_s=0.5, average_s=0.05)),
        x_mean=np.zeros(2), x_scale=np.ones(2), y_mean=0.0, y_scale=1.0,
        domain_min=np.array([-40.0, -5.0]), domain_max=np.array([80.0, 5.0]),
        params={"coef": [-1.5e297, 0.0], "intercept": 0.0}, reference_dph=0.0, training={}, metrics={},
        created_utc="2024-01-01T00:00:00Z",
    )  # fmt: skip
    path = tmp_path / "huge.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(ModelFileError) as raised:
        modelfile.load(path)
    assert "gives 6e+298 deg/h inside its own domain" in str(raised.value)
    assert "np." not in str(raised.value)
