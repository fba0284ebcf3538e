"""Issue 35 item 13: metrics clients that reset their connections are counted, never a traceback on stderr."""

from __future__ import annotations

import socket
import struct
import subprocess
import sys
import time
import urllib.request

SERVER = r"""
import logging, sys, time
from fogd.serving import prometheus
logging.basicConfig(level=logging.DEBUG, stream=sys.stderr)
snapshot = lambda: {"counters": {"reader": {"frames_in": {}, "disconnects": 0}, "lexer": {}, "ring_overruns": 0,
    "writer": {"frames_written": 0}, "loop": {"samples_compensated": 0, "samples_out_of_domain": 0,
    "samples_clamped": 0, "reloads": 0}}, "domain_shares": {"out_of_domain": 0.0, "clamped": 0.0},
    "connected": True, "latest": {"temp_c": 0.0, "temp_rate_cps": 0.0, "comp_dph": 0.0, "rate_comp_dph": 0.0},
    "latency_s": {"last": 0.0}}
server = prometheus.serve(snapshot, "127.0.0.1", 0)
print(server.server_address[1], flush=True)
sys.stdin.read()
"""


def reset(port: int, request: bytes) -> None:
    """Connect, send part of a request and close with a RST (SO_LINGER 0)."""
    client = socket.create_connection(("127.0.0.1", port))
    client.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    client.sendall(request)
    client.close()


def test_resetting_clients_are_counted_without_a_traceback():
    server = subprocess.Popen([sys.executable, "-c", SERVER], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        port = int(server.stdout.readline())
        for i in range(50):
            # half a request (the handler is reading when the RST comes), or a whole one never read back
            reset(port, b"GET /metrics HTTP/1.1\r\nHost: x\r\n" if i % 2 else b"GET /metrics HTTP/1.1\r\n\r\n" * 40)
        errors = 0
        for _ in range(200):  # the handler threads see their resets a moment later: wait on the count
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=10) as response:
                text = response.read().decode()
            errors = float(text.split("\nfogd_metrics_client_errors_total ")[1].split()[0])
            if errors >= 25:
                break
            time.sleep(0.05)
        assert errors >= 25
    finally:
        _, stderr = server.communicate("", timeout=30)
    assert "Traceback" not in stderr
    assert stderr.count("DEBUG:fogd.metrics") <= 1
