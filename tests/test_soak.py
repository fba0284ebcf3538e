"""tools/soak.py shortened: every fault at once on the real daemon (emulator faults, unplugs, SIGHUPs, a stalling
consumer, a consumer that goes away and comes back, metrics clients resetting), then the counters add up, the
consumer got whole lines only, and `fogd --out - | head -3` exits. The ten-minute run is the tool's default."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

SOAK = Path(__file__).resolve().parent.parent / "tools" / "soak.py"


def test_a_short_soak_adds_up():
    done = subprocess.run([sys.executable, str(SOAK), "--duration-s", "25", "--hup-every-s", "4", "--unplug-every-s", "9",
                           "--stall-s", "1.5", "--stall-every-s", "7", "--replug-every-s", "6", "--away-s", "1",
                           "--reset-every-s", "2"], capture_output=True, text=True, timeout=600)  # fmt: skip
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-3000:]
    assert "soak: OK" in done.stdout and "adds up" in done.stdout
