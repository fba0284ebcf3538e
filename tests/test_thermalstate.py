"""fogd.serving.thermalstate: the state file round trip (atomic, a symlink replaced and never written through),
and every file that cannot be trusted (another device's, an old one, a truncated one, 1 GB, a symlink to
/dev/zero, a FIFO, garbage) giving one warning and a cold start, never a crash or a hang."""

from __future__ import annotations

import json
import logging
import os

import pytest
from thermal_runs import bank_document

from fogd.core import modelfile
from fogd.core.channels import ChannelCompensator
from fogd.serving import thermalstate
from fogd.serving.thermalstate import StateFileError, Thermal

RATE_HZ = 5.0
DEVICE = "port /dev/ttyUSB0"


@pytest.fixture(scope="module")
def model():
    return modelfile.from_document(bank_document())


def thermal(model, path) -> Thermal:
    return Thermal([model], RATE_HZ, path=str(path), device=DEVICE)


def saved_state(model, path, *, seconds: float = 3600.0, end_s: float = 10_000.0) -> None:
    """A daemon that ran `seconds` to `end_s` (device clock) on a ramp, then stopped and saved."""
    first = thermal(model, path)
    first.clock = "device"
    samples = int(seconds * RATE_HZ)
    for i in range(samples):
        t_s = end_s - seconds + i / RATE_HZ
        first.history.add(t_s, 20.0 + 0.003 * (t_s - end_s + seconds))
    first.save(wait=True)


def start(model, path, caplog, *, t_s: float = 10_005.0) -> Thermal:
    """A daemon starting on the same port at `t_s` (device clock): what it did, and its log."""
    caplog.clear()
    second = thermal(model, path)
    with caplog.at_level(logging.WARNING, logger="fogd.thermal"):
        second.start(t_s, True, 30.8, ChannelCompensator({"rate_dph": model}, RATE_HZ))
    return second


def test_a_saved_state_round_trips_and_a_restart_bridges_the_gap(tmp_path, model, caplog):
    path = tmp_path / "fog0-thermal.json"
    saved_state(model, path)
    doc = json.loads(path.read_text())
    assert doc["device"] == DEVICE and doc["clock"] == "device" and doc["last_t_s"] == pytest.approx(9999.8)
    assert len(path.read_bytes()) < 200_000  # an hour of 1 s block means
    second = start(model, path, caplog)
    assert second.bound is None and second.started.startswith("restored (gap 5.2 s)")
    assert [record.getMessage() for record in caplog.records if "a gap of 5.2 s bridged" in record.getMessage()]


def test_a_symlinked_state_file_is_replaced_not_written_through(tmp_path, model):
    target = tmp_path / "elsewhere"
    target.write_text("keep")
    path = tmp_path / "state.json"
    path.symlink_to(target)
    saved_state(model, path)
    assert target.read_text() == "keep" and not path.is_symlink()
    assert not [name for name in os.listdir(tmp_path) if name.endswith(".tmp")]


def hostile(kind: str, path, model) -> None:
    if kind == "another device":
        saved_state(model, path)
        doc = json.loads(path.read_text())
        path.write_text(json.dumps({**doc, "device": "port /dev/ttyUSB1"}))
    elif kind == "old":
        saved_state(model, path, end_s=10_005.0 - 3001.0)  # newest sample beyond the slowest lag's 3,000 s
    elif kind == "truncated":
        saved_state(model, path)
        path.write_bytes(path.read_bytes()[: 5000])
    elif kind == "1 GB":
        with open(path, "wb") as stream:
            stream.truncate(1 << 30)  # sparse: a gigabyte of zeros that costs no disk
    elif kind == "symlink to /dev/zero":
        path.symlink_to("/dev/zero")
    elif kind == "fifo":
        os.mkfifo(path)
    elif kind == "NaN":
        saved_state(model, path)
        path.write_text(path.read_text().replace('"temp_c":[', '"temp_c":[NaN,', 1))
    elif kind == "times that fall":
        saved_state(model, path)
        doc = json.loads(path.read_text())
        doc["t_s"][3] = 0.0
        path.write_text(json.dumps(doc))
    elif kind == "not an object":
        path.write_text("[" * 100_000)


@pytest.mark.parametrize("kind", ["another device", "old", "truncated", "1 GB", "symlink to /dev/zero", "fifo", "NaN",
                                  "times that fall", "not an object"])  # fmt: skip
def test_an_untrustworthy_state_file_is_one_warning_and_a_cold_start(tmp_path, model, caplog, kind):
    path = tmp_path / "fog0-thermal.json"
    hostile(kind, path, model)
    second = start(model, path, caplog)
    warnings = [record.getMessage() for record in caplog.records if record.levelno >= logging.WARNING]
    assert len(warnings) == 1, warnings
    assert "cold start" in warnings[0] and "thermal state" in warnings[0], warnings[0]
    assert second.bound is not None and second.started == "cold"  # WARMING from here on


def test_a_missing_state_file_is_a_cold_start_that_says_so(tmp_path, model, caplog):
    second = start(model, tmp_path / "none-yet.json", caplog)
    assert second.started == "cold" and "no state file" in caplog.records[0].getMessage()


def test_read_bounds_what_it_reads(tmp_path):
    path = tmp_path / "big.json"
    with open(path, "wb") as stream:
        stream.truncate(thermalstate.MAX_STATE_BYTES + 1)
    with pytest.raises(StateFileError, match="more than"):
        thermalstate.read(str(path))
