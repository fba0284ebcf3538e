"""Optional Prometheus metrics: a stdlib HTTP server on its own thread answering GET /metrics with the
daemon's counters in the text exposition format. Off unless `metrics_port` is set; binds 127.0.0.1 unless
`metrics_address` says otherwise. It only reads a snapshot, so a slow scraper never touches the data path.

Network clients must never cost gyro data: at most MAX_CONNECTIONS are open at once (one thread and one
descriptor each) and a connection that sends nothing for CONNECTION_TIMEOUT_S is closed. A new connection
beyond the limit closes the oldest open one (a scraper asks at once and is answered in milliseconds, so the
oldest is an idle one), so idle clients can exhaust neither threads nor the descriptors the serial port, the
output and the stats file need, and cannot lock a scraper out.
"""

from __future__ import annotations

import logging
import math
import socket
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any, Callable

from fogd.errors import DeviceError

log = logging.getLogger("fogd.metrics")
MAX_CONNECTIONS = 16
CONNECTION_TIMEOUT_S = 5.0


def render(snapshot: dict[str, Any]) -> str:
    """The snapshot as Prometheus text: counters as fogd_*_total, the latest values as gauges."""
    lines: list[str] = []

    def metric(name: str, kind: str, help_text: str, samples: list[tuple[str, Any]]) -> None:
        lines.append(f"# HELP {name} {help_text}")
        lines.append(f"# TYPE {name} {kind}")
        for labels, value in samples:
            number = float(value) if isinstance(value, (int, float)) and value is not None else math.nan
            lines.append(f"{name}{labels} {number!r}".replace("nan", "NaN"))

    counters = snapshot["counters"]
    reader, lexer, writer, loop = counters["reader"], counters["lexer"], counters["writer"], counters["loop"]
    metric("fogd_frames_in_total", "counter", "Frames decoded from the port, by kind.",
           [(f'{{kind="{kind}"}}', count) for kind, count in reader["frames_in"].items()])
    metric("fogd_lexer_total", "counter", "Lexer counters (drops by kind, sequence gaps, ...).",
           [(f'{{counter="{name}"}}', value) for name, value in lexer.items()])
    metric("fogd_frames_out_total", "counter", "Frames written to the output.", [("", writer["frames_written"])])
    metric("fogd_frames_dropped_out_total", "counter", "Output frames dropped, by reason.",
           [(f'{{reason="{name.removeprefix("frames_dropped_")}"}}', value)
            for name, value in writer.items() if name.startswith("frames_dropped_")])  # fmt: skip
    metric("fogd_ring_overruns_total", "counter", "Samples dropped because the ring was full.",
           [("", counters["ring_overruns"])])
    metric("fogd_port_disconnects_total", "counter", "Times the port was lost.", [("", reader["disconnects"])])
    metric("fogd_samples_compensated_total", "counter", "Rate samples compensated.", [("", loop["samples_compensated"])])
    metric("fogd_samples_flagged_total", "counter",
           "Rate samples compensated by the domain guard's linear fallback (out_of_domain) or with an input "
           "clamped to the calibrated range (clamped), or resting on a cold start's equilibrium assumption (warming).",
           [('{flag="out_of_domain"}', loop["samples_out_of_domain"]), ('{flag="clamped"}', loop["samples_clamped"]),
            ('{flag="warming"}', loop.get("samples_warming", 0))])
    shares = snapshot["domain_shares"]
    metric("fogd_samples_flagged_share", "gauge", "Share of the rate samples compensated since start with that flag.",
           [(f'{{flag="{name}"}}', shares[name]) for name in ("out_of_domain", "clamped")])
    metric("fogd_reloads_total", "counter", "Reloads applied (SIGHUP).", [("", loop["reloads"])])
    metric("fogd_connected", "gauge", "1 while the port is open.", [("", int(bool(snapshot["connected"])))])
    latest = snapshot["latest"]
    for key, help_text in (("temp_c", "Temperature used, C."), ("temp_rate_cps", "Temperature rate, C/s."),
                           ("comp_dph", "Current compensation, deg/h."), ("rate_comp_dph", "Compensated rate, deg/h.")):
        metric(f"fogd_{key}", "gauge", help_text, [("", latest[key])])
    metric("fogd_latency_seconds", "gauge", "Read-to-output latency of the newest batch.",
           [("", snapshot["latency_s"]["last"])])
    return "\n".join(lines) + "\n"


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    block_on_close = False
    request_queue_size = 128  # waiting in the kernel costs no descriptor

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self._slots = threading.BoundedSemaphore(MAX_CONNECTIONS)
        self._lock = threading.Lock()
        self._open: dict[Any, float] = {}  # connection -> when it was accepted
        self.evicted = 0
        super().__init__(*args, **kwargs)

    def process_request(self, request: Any, client_address: Any) -> None:
        if not self._slots.acquire(blocking=False):
            self._evict_oldest()
            if not self._slots.acquire(timeout=1.0):
                self.shutdown_request(request)  # still full: closed at once, no thread, no descriptor kept
                return
        with self._lock:
            self._open[request] = time.monotonic()
        try:
            super().process_request(request, client_address)
        except BaseException:
            self._release(request)
            raise

    def process_request_thread(self, request: Any, client_address: Any) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            self._release(request)

    def _release(self, request: Any) -> None:
        with self._lock:
            self._open.pop(request, None)
        self._slots.release()

    def _evict_oldest(self) -> None:
        with self._lock:
            if not self._open:
                return
            oldest = min(self._open, key=self._open.__getitem__)
        self.evicted += 1
        try:
            oldest.shutdown(socket.SHUT_RDWR)  # its handler's read returns at once and the thread ends
        except OSError:
            pass


def serve(snapshot: Callable[[], dict[str, Any]], address: str, port: int) -> ThreadingHTTPServer:
    """Start the endpoint on a daemon thread; DeviceError (one line) if the address cannot be bound."""

    class Handler(BaseHTTPRequestHandler):
        timeout = CONNECTION_TIMEOUT_S  # an idle or slow client is closed, not waited for

        def do_GET(self) -> None:  # noqa: N802 (http.server's name)
            if self.path.split("?")[0] != "/metrics":
                self.send_error(404, "only /metrics here")
                return
            body = render(snapshot()).encode()
            self.send_response(200)
            self.send_header("Content-Type", "text/plain; version=0.0.4; charset=utf-8")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args: Any) -> None:  # scrapes are not worth a journal line each
            pass

    server_class = _Server
    if ":" in address:
        server_class = type("_Server6", (_Server,), {"address_family": socket.AF_INET6})
    try:
        server = server_class((address, port), Handler)
    except OSError as error:
        raise DeviceError(f"metrics: cannot listen on {address} port {port}: {error.strerror or error}") from None
    threading.Thread(target=server.serve_forever, name="fogd-metrics", daemon=True).start()
    log.info("metrics on http://%s:%d/metrics", address if ":" not in address else f"[{address}]", port)
    return server
