"""The daemon's compensation loop and lifecycle: it pops batches of samples from the ring the reader fills,
holds the latest temperature for each rate sample, runs the shared `Compensator` once per batch on the
configured axis, hands the encoded output to the writer thread, watches both threads, logs a periodic status
line, and on stop drains the ring and flushes the writer.

Temperature may arrive in its own frames at its own rate: each rate sample gets the newest temperature that
arrived before it, flagged TEMP_STALE when that temperature is older (in receive time) than `temp_stale_s`.
Output time is the device time where the protocol carries one, else sample count / `rate_hz`.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import asdict, dataclass

import numpy as np

from fogd.compensator import Compensator
from fogd.flags import describe
from fogd.frozen import FrozenModel
from fogd.outputs import Formatter, OutputBatch, Writer, rate_row_indices
from fogd.reader import Reader
from fogd.ring import Ring

log = logging.getLogger("fogd.daemon")
status_log = logging.getLogger("fogd.status")

RING_CAPACITY = 1 << 15  # samples: 1.6 s at 20 kHz
MAX_BATCH = 4096  # samples per compensation step, which bounds a chunk's size in the writer's queue
IDLE_WAIT_S = 0.05
FLUSH_TIMEOUT_S = 1.5
RESTART_DELAY_S = 0.5


class TemperatureHold:
    """Each record's temperature: the newest one that arrived at or before it, carried across batches, and
    its age in receive time (a rate sample with no temperature since the start ages from the start)."""

    def __init__(self) -> None:
        self.temp_c = np.nan
        self.rx_s = time.monotonic()

    def hold(self, records: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(temperature held for each record, seconds since it arrived)."""
        has_temp = records["has_temp"]
        source = np.where(has_temp, np.arange(has_temp.size), -1)
        np.maximum.accumulate(source, out=source)
        known = source >= 0
        index = np.maximum(source, 0)
        temp_c = np.where(known, records["temp_c"][index], self.temp_c)
        rx_s = np.where(known, records["t_rx_s"][index], self.rx_s)
        if has_temp.any():
            self.temp_c = float(temp_c[-1])
            self.rx_s = float(rx_s[-1])
        return temp_c, records["t_rx_s"] - rx_s


class SampleClock:
    """Sample times: the device's clock where the protocol has one, else the sample count / rate_hz."""

    def __init__(self, rate_hz: float) -> None:
        self.rate_hz = rate_hz
        self.count = 0

    def times(self, device_s: np.ndarray) -> np.ndarray:
        count_s = (self.count + np.arange(device_s.size)) / self.rate_hz
        self.count += device_s.size
        return np.where(np.isnan(device_s), count_s, device_s)


@dataclass
class LoopCounters:
    samples_compensated: int = 0
    reader_deaths: int = 0
    writer_deaths: int = 0


@dataclass
class Latest:
    """The newest compensated sample, for the status line."""

    rate_dph: float = float("nan")
    comp_dph: float = float("nan")
    rate_comp_dph: float = float("nan")
    temp_c: float = float("nan")
    temp_rate_cps: float = float("nan")
    flags: int = 0


class Daemon:
    """Runs reader, compensation loop and writer until `stop()` or `duration_s`; `run()` returns when done."""

    def __init__(
        self,
        *,
        reader: Reader,
        writer: Writer,
        formatter: Formatter,
        model: FrozenModel,
        rate_hz: float,
        axis: int,
        temp_stale_s: float,
        status_interval_s: float,
        duration_s: float | None = None,
    ) -> None:
        self.reader = reader
        self.writer = writer
        self.formatter = formatter
        self.model = model
        self.compensator = Compensator(model, rate_hz)
        self.axis = axis
        self.temp_stale_s = temp_stale_s
        self.status_interval_s = status_interval_s
        self.duration_s = duration_s
        self.counters = LoopCounters()
        self.latest = Latest()
        self._stop = threading.Event()
        self.clock = SampleClock(rate_hz)
        self.temperature = TemperatureHold()

    @property
    def ring(self) -> Ring:
        return self.reader.ring

    def stop(self) -> None:
        """Ask `run()` to finish (safe from a signal handler)."""
        self._stop.set()

    def run(self) -> None:
        started_s = time.monotonic()
        next_status_s = started_s + self.status_interval_s
        self.writer.start(self.formatter.header())
        self.reader.start()
        try:
            while not self._stop.is_set():
                now_s = time.monotonic()
                if self.duration_s is not None and now_s - started_s >= self.duration_s:
                    break
                if now_s >= next_status_s:
                    status_log.info(self.status_line())
                    next_status_s = now_s + self.status_interval_s
                self._watch_threads()
                self.reader.data_ready.wait(IDLE_WAIT_S)
                self.reader.data_ready.clear()
                self._drain()
        finally:
            self.reader.stop()
            self._drain()
            if not self.writer.close(FLUSH_TIMEOUT_S):
                log.warning("output did not take the last frames within %.1f s", FLUSH_TIMEOUT_S)
            status_log.info("final: %s", self.status_line())

    def _drain(self) -> None:
        while True:
            records = self.ring.pop(MAX_BATCH)
            if not len(records):
                return
            self.writer.submit(self.formatter.encode(self.compensate(records)))

    def compensate(self, records: np.ndarray) -> OutputBatch:
        """One Compensator.process call for every rate sample in `records`."""
        rows = rate_row_indices(records)
        temp_c, temp_age_s = self.temperature.hold(records)
        rates = records["rate_dph"][rows, self.axis]
        bit = 1 << self.axis
        usable = (records["axis_valid"][rows] & records["axis_present"][rows] & bit) != 0
        comp = self.compensator.process(
            rates, temp_c[rows], rate_valid=usable, temp_stale=temp_age_s[rows] > self.temp_stale_s
        )
        self.counters.samples_compensated += rows.size
        if rows.size:
            last = -1
            self.latest = Latest(
                float(rates[last]), float(comp.comp_dph[last]), float(comp.rate_comp_dph[last]),
                float(comp.temp_c[last]), float(comp.temp_rate_cps[last]), int(comp.flags[last]),
            )  # fmt: skip
        return OutputBatch(records, rows, self.clock.times(records["t_dev_s"][rows]), comp)

    def _watch_threads(self) -> None:
        """A dead thread is a bug; log it, count it and start it again rather than hang silently."""
        if not self.reader.alive and not self._stop.is_set():
            self.counters.reader_deaths += 1
            log.error("reader thread died (%r); restarting it", self.reader.error)
            time.sleep(RESTART_DELAY_S)
            self.reader.start()
        if not self.writer.alive and not self._stop.is_set():
            self.counters.writer_deaths += 1
            log.error("writer thread died (%r); output stops", self.writer.error)
            self.stop()

    def status_line(self) -> str:
        reader, lexer, writer = self.reader.counters, self.reader.lexer.counters, self.writer.counters
        latest = self.latest
        frames_in = " ".join(f"{kind} {count}" for kind, count in reader.frames_in.items() if count)
        drops = " ".join(
            f"{name} {value}" for name, value in lexer.as_dict().items() if value and name not in ("frames_ok", "other_frames")
        )
        dropped_out = writer.frames_dropped_full + writer.frames_dropped_timeout + writer.frames_dropped_error
        return (
            f"in {frames_in or 0} | out {writer.frames_written} dropped {dropped_out} | drops {drops or 'none'} | "
            f"ring overruns {self.ring.overruns} | reconnects {reader.reconnects} | "
            f"T {latest.temp_c:.2f} C dT/dt {latest.temp_rate_cps:+.5f} C/s comp {latest.comp_dph:+.4f} deg/h "
            f"({describe(latest.flags)}) | model {self.model.name}"
        )

    def counters_dict(self) -> dict:
        """Every counter, for tests and the final log line."""
        return {
            "reader": asdict(self.reader.counters),
            "lexer": self.reader.lexer.counters.as_dict(),
            "ring_overruns": self.ring.overruns,
            "writer": asdict(self.writer.counters),
            "loop": asdict(self.counters),
        }
