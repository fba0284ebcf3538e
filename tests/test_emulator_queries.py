"""fogd-emu's KVH unit answers its setting queries as the unit would (fogd.protocols.kvh.settings_reply), among
its frames, and streams on after `=CONFIG,0` with no frame lost; the daemon's query at start reads the same
replies back into the emulator's settings."""

from __future__ import annotations

import os
import time

import serial

from fogd.protocols import kvh
from fogd.protocols.lexer import Lexer
from fogd.serving.unitquery import query_settings
from fogd.simulation import profiles
from fogd.simulation.emulator import Emulator, SimSource

RATE_HZ = 250.0


def emulator(count: int, **units) -> Emulator:
    source = SimSource(profiles.builtin("fast-ramp"), RATE_HZ, 2, imu=True)
    return Emulator(source, "kvh-a", speed=None, count=count, wait_reader=True, protocol_options=units)


def read_until(fd: int, wanted: bytes, timeout_s: float = 20.0) -> bytes:
    data = b""
    deadline = time.monotonic() + timeout_s
    while wanted not in data:
        assert time.monotonic() < deadline, f"no {wanted!r} in {len(data)} bytes"
        try:
            data += os.read(fd, 4096)
        except BlockingIOError:
            time.sleep(0.01)
    return data


def test_each_query_is_answered_in_the_units_words_and_no_frame_is_lost():
    with emulator(2000, rotfmt="delta", angle_unit="deg", temp_unit="F") as emu:
        fd = os.open(emu.path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        try:
            os.write(fd, b"=CONFIG,1\r\n" + b"".join(kvh.query(name) for name in kvh.SETTING_QUERIES))
            data = read_until(fd, b"DR,250\r\n")
            os.write(fd, b"=CONFIG,0\r\n")
            while not emu.join(0.01):
                try:
                    data += os.read(fd, 4096)
                except BlockingIOError:
                    pass
            try:
                data += os.read(fd, 1 << 20)
            except BlockingIOError:
                pass
        finally:
            os.close(fd)
    for reply in (b"ROTFMT,DELTA\r\n", b"ROTUNITS,DEG\r\n", b"LINFMT,ACCEL\r\n", b"LINUNITS,METERS\r\n",
                  b"TEMPUNITS,F\r\n", b"DR,250\r\n"):  # fmt: skip
        assert data.count(reply) == 1, reply
    lexer = Lexer(kvh.KvhProtocol(rotfmt="delta", rate_hz=RATE_HZ, angle_unit="deg", temp_unit="F"))
    frames = lexer.feed(data) + lexer.flush()
    assert len(frames) == 2000 and lexer.counters.bad_crc == 0 and lexer.counters.seq_gaps == 0


def test_the_daemons_query_reads_the_emulators_settings():
    with emulator(None, rotfmt="delta", linfmt="delta", lin_unit="ft") as emu:
        port = serial.Serial(emu.path, 921600, timeout=0.1)
        try:
            settings = query_settings(port, emu.path)
        finally:
            port.close()
            emu.stop()
    assert settings == {"rotfmt": "delta", "angle_unit": "rad", "linfmt": "delta", "lin_unit": "ft",
                        "temp_unit": "C", "rate_hz": RATE_HZ}  # fmt: skip
