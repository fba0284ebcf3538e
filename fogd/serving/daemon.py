"""The daemon's compensation loop and lifecycle: it pops batches of samples from the ring the reader fills,
holds the latest temperature for each rate sample, runs the shared channel compensator once per batch on the
covered channels (a batch of a few frames, the usual one at real rates, row by row through its pre-bound
`process_row`), hands the encoded output to the writer thread, watches both threads, logs a periodic status
line, and on stop drains the ring and flushes the writer.

One wake-up per frame: on a box idle between frames, waking a halted CPU costs more than a frame's Python,
and reader -> loop -> writer was a wake-up each. So the reader thread hands a read's few frames on itself
(`take_inline`: compensate, encode, one non-blocking write when the writer thread is idle) when nothing waits
in the ring before them and the loop is not busy; else they go through the ring as before (a large read, a
batch the loop is compensating, the loop's duties running). `_handing_on` is the lock that makes the two
paths take turns, so frames keep their order and the compensator has one user at a time; the reader only
ever tries it, never waits for it, so it never waits on the loop or the consumer. And the Python a frame
runs is cut to what it needs: every call on a box idle between frames runs cold, so a read's one frame on a
one-gyro model (the usual read at real rates) goes from the lexer's frame to the writer in one call,
`_hand_on_one`, held equal to the batch path by tests/test_one_row.py.

Temperature may arrive in its own frames at its own rate: each rate sample gets the newest temperature that
arrived before it, flagged TEMP_STALE when that temperature is older (in receive time) than `temp_stale_s`.
Output time is the device time where the protocol carries one, else sample count / `rate_hz`.

Service duties live here too, all on the loop's own thread so nothing races the compensator: signals only set
flags (`stop`, `request_reload`, `request_counters`); a reload is prepared (config read, model validated) on a
helper thread and swapped in between two batches, so no frame is lost or compensated twice. The estimator
state survives a swap when the new model has the same inputs (same estimator settings), else it restarts
with a warm-up (logged). systemd is told READY=1, a STATUS= summary, and WATCHDOG=1 only while the reader
thread is alive and coming round its loop and the output takes frames: a hung reader, or an output whose
every write has failed for longer than WatchdogSec, stops the pings and systemd restarts fogd. stdout's
reader closing the pipe (EPIPE) ends the run, exit 0, as it ends any Unix filter.
"""

from __future__ import annotations

import gc
import json
import logging
import math
import os
import sys
import threading
import time
from collections import deque
from dataclasses import asdict, dataclass, replace
from typing import Callable

import numpy as np

from fogd import __version__
from fogd.core.channels import ChannelCompensator, ChannelModels
from fogd.core.compensator import TEMP_VALID_C, Compensated
from fogd.core.estimator import SCALAR_CHUNK
from fogd.core.flags import Flag, describe
from fogd.core.frozen import FrozenModel
from fogd.core.modelfile import check_rate, held_out, printable
from fogd.errors import ConfigError, FogdError
from fogd.protocols.base import TIME_BACKWARDS, Frame
from fogd.serving.channels import ChannelPlan, as_models, method, plan
from fogd.serving.clock import DeviceRate
from fogd.serving.missing import MissingChannels
from fogd.serving.outputs import Chunk, Formatter, OutputBatch, Writer, split_batch
from fogd.serving.placement import ANY, Placement
from fogd.serving.reader import Reader
from fogd.serving.ring import RATE_KINDS, TEMP_KINDS, Ring
from fogd.serving.sdnotify import Notifier
from fogd.serving.statsfile import write_stats
from fogd.serving.thermalstate import SAVE_EVERY_S, Thermal

log = logging.getLogger("fogd.daemon")
status_log = logging.getLogger("fogd.status")

RING_CAPACITY = 1 << 14  # frames: 0.8 s at 20 kHz, 3.3 s at a 1775's 5 kHz (about 400 bytes each as Python objects)
MAX_BATCH = 1024  # samples per compensation step, which bounds a chunk's size in the writer's queue
INLINE_MAX = SCALAR_CHUNK  # frames the reader hands on itself (the row path's batches); larger reads go via the ring
IDLE_WAIT_S = 0.05
# How long a thread that wants the GIL waits for the one computing (Python's default is 5 ms): the reader
# must get it back within the time a pty's or UART's buffer takes to fill at full rate (4 KB at 80,000
# frames/s is 1.4 ms), or the sender is throttled and frames pile up; between frames at real rates no thread
# computes, so nothing changes there.
SWITCH_INTERVAL_S = 0.0005
DUTIES_S = 0.01  # status, signals, reloads, thread watch, watchdog: checked at most this often
FLUSH_TIMEOUT_S = 1.5
RESTART_DELAY_S = 0.5
NOTIFY_STATUS_S = 2.0  # how often systemd's STATUS= line is refreshed
STATS_EVERY_S = 1.0
HISTORY_POINTS = 60  # the stats file's history: the latest sample at each of the last 60 stats writes (a minute)
RELOAD_TIMEOUT_S = 10.0  # a reload still preparing after this long is stuck (a FIFO, a hung filesystem)
READER_STALL_S = 2.0  # a reader that has not come round its loop for this long is hung (its waits are <= 0.2 s)
HISTORY_FIELDS = ("uptime_s", "temp_c", "temp_rate_cps", "comp_dph", "flags")
NOT_DROPS = ("frames_ok", "other_frames", "frame_bytes", "seq_resets")  # lexer counters that count no loss
_OUT_OF_DOMAIN, _CLAMPED = int(Flag.OUT_OF_DOMAIN), int(Flag.CLAMPED)
_TIME_BACKWARDS = int(Flag.TIME_BACKWARDS)


@dataclass
class ChannelSamples:
    """The rate frames of a batch for the channel compensator: per channel its values and usability (lists,
    one entry per rate frame), and the columns every channel shares."""

    rows: list[int]  # index of each rate frame in the batch
    values: list[list[float]]  # per compensated channel
    usable: list[list[bool]]  # per compensated channel: present and valid in the frame
    device_s: list[float | None]  # the device's time, if the protocol has one
    temp_c: list[float]  # the newest temperature received at or before the frame (NaN: none yet)
    temp_age_s: list[float]  # how long before the frame that temperature arrived


_NAN = float("nan")


class TemperatureHold:
    """Each rate frame's temperature: the newest one that arrived at or before it, carried across batches, and
    its age in receive time (a rate sample with no temperature since the start ages from the start)."""

    def __init__(self) -> None:
        self.temp_c = math.nan
        self.rx_s = time.monotonic()

    def channel_samples(self, frames: list[Frame], t_rx_s: list[float], sources: tuple[tuple[bool, int], ...]) -> ChannelSamples:
        """The frames that carry a rate, as columns for the compensator, each with the temperature held for it:
        `sources` says where each channel is in a frame ((accelerometer?, axis)); an accelerometer a frame lacks
        (a fogd rate frame) is NaN and unusable."""
        rows: list[int] = []
        device_s: list[float | None] = []
        temps_c: list[float] = []
        ages_s: list[float] = []
        held_c, held_rx_s = self.temp_c, self.rx_s
        rated: list[Frame] = []
        for index, frame in enumerate(frames):
            kind = frame.kind
            if kind in TEMP_KINDS and frame.temp_c is not None:
                held_c, held_rx_s = frame.temp_c, t_rx_s[index]
            if kind in RATE_KINDS:
                rows.append(index)
                rated.append(frame)
                device_s.append(frame.t_s)
                temps_c.append(held_c)
                ages_s.append(t_rx_s[index] - held_rx_s)
        # then each channel's column in one pass over the rate frames (a batch of a busy IMU: six channels)
        values: list[list[float]] = []
        usable: list[list[bool]] = []
        for accel, axis in sources:
            if not accel:
                values.append([frame.rate_dph[axis] for frame in rated])
                usable.append([frame.axis_valid[axis] and frame.axis_present[axis] for frame in rated])
            else:
                values.append([_NAN if frame.accel_g is None else frame.accel_g[axis] for frame in rated])
                usable.append([frame.accel_g is not None and frame.accel_valid[axis] and frame.accel_present[axis]
                               for frame in rated])  # fmt: skip
        samples = ChannelSamples(rows, values, usable, device_s, temps_c, ages_s)
        self.temp_c, self.rx_s = held_c, held_rx_s
        return samples


class SampleClock:
    """Sample times: the device's clock where the protocol has one, else the sample count / rate_hz."""

    def __init__(self, rate_hz: float) -> None:
        self.rate_hz = rate_hz
        self.count = 0

    def times(self, device_s: list[float | None]) -> list[float]:
        first, rate_hz = self.count, self.rate_hz
        self.count += len(device_s)
        if len(device_s) == 1:  # the usual batch at real rates: no comprehension to set up
            t_s = device_s[0]
            return [first / rate_hz if t_s is None or t_s != t_s else t_s]
        return [(first + i) / rate_hz if t_s is None or t_s != t_s else t_s for i, t_s in enumerate(device_s)]


@dataclass
class LoopCounters:
    samples_compensated: int = 0
    samples_out_of_domain: int = 0  # compensated by the domain guard's linear fallback (OUT_OF_DOMAIN)
    samples_clamped: int = 0  # with an input clamped to the calibrated range (CLAMPED)
    samples_warming: int = 0  # a cold start's inputs rest on the equilibrium assumption (WARMING; serving.thermalstate)
    reader_deaths: int = 0
    writer_deaths: int = 0
    reloads: int = 0
    reloads_refused: int = 0
    reloads_stuck: int = 0  # a reload that did not finish within RELOAD_TIMEOUT_S (abandoned, later ones run)
    records_popped: int = 0  # ring records compensated and encoded (or counted unencodable)
    frames_unencodable: int = 0  # frames whose values no output encoding could carry (or the model failed on)
    samples_missing_channel: int = 0  # rate samples lacking a channel the model compensates (passed through)


@dataclass(frozen=True)
class Reload:
    """What a SIGHUP may change without a restart (validated before the daemon sees it)."""

    model: FrozenModel | ChannelModels
    temp_stale_s: float
    status_interval_s: float
    compensator: ChannelCompensator | None = None  # built by the reload thread, so a swap allocates nothing


@dataclass
class Latency:
    """Seconds from the read that completed a frame to its compensated output being queued for the writer."""

    last_s: float = float("nan")
    max_s: float = 0.0  # since the last status line


@dataclass
class Latest:
    """The newest compensated sample, for the status line."""

    rate_dph: float = float("nan")
    comp_dph: float = float("nan")
    rate_comp_dph: float = float("nan")
    temp_c: float = float("nan")
    temp_rate_cps: float = float("nan")
    flags: int = 0
    channels: dict[str, dict[str, float]] | None = None  # a multi-channel model: each channel's comp and flags


class Daemon:
    """Runs reader, compensation loop and writer until `stop()` or `duration_s`; `run()` returns when done."""

    def __init__(
        self,
        *,
        reader: Reader,
        writer: Writer,
        formatter: Formatter,
        model: FrozenModel | ChannelModels,
        rate_hz: float,
        axis: int,
        channels: ChannelPlan | None = None,
        temp_stale_s: float,
        status_interval_s: float,
        duration_s: float | None = None,
        notifier: Notifier | None = None,
        reload: Callable[[], Reload] | None = None,
        stats_path: str | None = None,
        info: dict | None = None,
        placement: Placement | None = None,
        thermal: Thermal | None = None,
    ) -> None:
        self.reader = reader
        self.writer = writer
        self.formatter = formatter
        models = as_models(model)
        self.plan = channels or plan(models, formatter.protocol, axis)
        self.model = model
        self.models = models
        self.compensator = self._compensator(models, rate_hz)
        self.rate_hz = rate_hz
        self.axis = axis
        self._names = self.plan.covered
        sources = self.plan.sources  # one gyro channel (the usual daemon): its axis, for the row path
        self._one_axis = sources[0][1] if len(sources) == 1 and not sources[0][0] else None
        self._one_row = self._one_axis is not None and self.plan.single  # a read's one frame: `_hand_on_one`
        self.temp_stale_s = temp_stale_s
        self.status_interval_s = status_interval_s
        self.duration_s = duration_s
        self.counters = LoopCounters()
        self._latest = Latest()
        self._newest: tuple | None = None  # (readings, first channel's, every channel's) of the newest batch
        self._latest_of: tuple | None = None  # the `_newest` that `_latest` was made from
        self._handing_on = threading.Lock()  # held while frames are compensated and handed on, and for duties
        self.latency = Latency()
        self._stop = threading.Event()
        self.clock = SampleClock(rate_hz)
        self.temperature = TemperatureHold()
        self.notifier = notifier or Notifier({})
        self._reload = reload
        self.stats_path = stats_path
        self.info = info or {}  # static facts for the stats file (port, protocol, instance)
        self.placement = placement or Placement(ANY)  # in-process users (tests, tools) keep their own threads' CPUs
        self.started_s = time.monotonic()
        self._reload_requested = threading.Event()
        self._counters_requested = threading.Event()
        self._reload_thread: threading.Thread | None = None
        self._reload_ready: Reload | None = None
        self._stall_logged = False
        self._output_logged = False
        self._encode_error_logged = False
        self._reload_started_s = 0.0
        self.history: deque[tuple[float, ...]] = deque(maxlen=HISTORY_POINTS)
        self.thermal = thermal  # the temperature history kept across reloads and restarts, and WARMING
        self.rate = DeviceRate(rate_hz, self.info.get("rate_source", "the config"))
        self.channels_seen = MissingChannels(self.plan)

    def _compensator(self, models: ChannelModels, rate_hz: float) -> ChannelCompensator:
        """The one compensator of every covered channel, as fogd-replay builds it; each model's window is
        checked against the rate before its buffers are allocated."""
        for channel in self.plan.covered:
            check_rate(models[channel], rate_hz, models[channel].name)
        return ChannelCompensator({channel: models[channel] for channel in self.plan.covered}, rate_hz)

    @property
    def ring(self) -> Ring:
        return self.reader.ring

    def stop(self) -> None:
        """Ask `run()` to finish (safe from a signal handler)."""
        self._stop.set()
        self.ring.wake()

    def request_reload(self) -> None:
        """Ask for the config and model to be read again (safe from a signal handler)."""
        self._reload_requested.set()
        self.ring.wake()

    def request_counters(self) -> None:
        """Ask for the counters to be logged (safe from a signal handler)."""
        self._counters_requested.set()
        self.ring.wake()

    def run(self) -> None:
        started_s = self.started_s = time.monotonic()
        next_status_s = started_s + self.status_interval_s
        next_notify_s = next_stats_s = next_pet_s = next_save_s = started_s
        pet_every_s = self.notifier.watchdog_interval_s
        switch_interval_s = sys.getswitchinterval()
        sys.setswitchinterval(SWITCH_INTERVAL_S)
        # What is loaded by now (modules, model, buffers) lives as long as the daemon: out of the collector's
        # sight, a full collection does not walk it (tens of ms, a latency spike) while frames flow.
        gc.freeze()
        self.placement.start()  # before the threads start: they inherit this thread's CPU
        self.writer.start(self.formatter.header())
        self.reader.inline = self.take_inline
        self.reader.start()
        self.notifier.send("READY=1", f"STATUS={self.short_status()}")
        next_duties_s = started_s
        try:
            while not self._stop.is_set():
                # frames are waited for and compensated at once; the duties below run every DUTIES_S at most
                if self.ring.wait(IDLE_WAIT_S):
                    with self._handing_on:
                        self._drain()
                now_s = time.monotonic()
                if now_s < next_duties_s:
                    continue
                next_duties_s = now_s + DUTIES_S
                with self._handing_on:  # the duties and the compensation never run at once
                    if self.duration_s is not None and now_s - started_s >= self.duration_s:
                        break
                    if self.writer.consumer_gone:  # stdout's reader closed the pipe: end as a Unix filter does
                        log.warning("output %s closed by its reader (broken pipe); stopping", self.writer.sink.name)
                        break
                    if now_s >= next_status_s:
                        status_log.info(self.status_line())
                        self.latency.max_s = 0.0
                        next_status_s = now_s + self.status_interval_s
                    if self._counters_requested.is_set():
                        self._counters_requested.clear()
                        status_log.info("%s | counters %s", self.status_line(), json.dumps(self.counters_dict()))
                    self._handle_reload()
                    self._follow_rate(now_s)
                    self.channels_seen.check(now_s)
                    self._watch_threads()
                    self.placement.follow(now_s)
                    if pet_every_s is not None and now_s >= next_pet_s and self.healthy(now_s):
                        self.notifier.send("WATCHDOG=1")
                        next_pet_s = now_s + pet_every_s
                    if now_s >= next_notify_s:
                        self.notifier.send(f"STATUS={self.short_status()}")
                        next_notify_s = now_s + NOTIFY_STATUS_S
                    if self.stats_path is not None and now_s >= next_stats_s:
                        latest = self.latest
                        self.history.append((now_s - self.started_s, latest.temp_c, latest.temp_rate_cps,
                                             latest.comp_dph, float(latest.flags)))  # fmt: skip
                        write_stats(self.stats_path, self.snapshot())
                        next_stats_s = now_s + STATS_EVERY_S
                    if self.thermal is not None and now_s >= next_save_s:
                        self.thermal.save()
                        next_save_s = now_s + SAVE_EVERY_S
        finally:
            self.notifier.send("STOPPING=1")
            self.reader.stop()
            with self._handing_on:  # (a reader that did not stop in time may still be handing frames on)
                self._drain()
            if not self.writer.close(FLUSH_TIMEOUT_S):
                log.warning("output did not take the last frames within %.1f s", FLUSH_TIMEOUT_S)
            status_log.info("final: %s", self.status_line())
            if self.thermal is not None:
                self.thermal.save(wait=True)
            if self.stats_path is not None:
                write_stats(self.stats_path, {**self.snapshot(), "running": False})
            sys.setswitchinterval(switch_interval_s)
            gc.unfreeze()

    def healthy(self, now_s: float) -> bool:
        """Whether the data path works: the reader thread alive and coming round its loop (reading, or
        waiting for a lost port to return), and the writer alive. Decides the systemd watchdog ping."""
        stalled_s = now_s - self.reader.heartbeat_s
        if stalled_s > READER_STALL_S and self.reader.alive:
            if not self._stall_logged:
                log.error("reader thread stuck for %.1f s; no watchdog ping (systemd will restart fogd)", stalled_s)
                self._stall_logged = True
            return False
        self._stall_logged = False
        # an output that has taken nothing for longer than the watchdog's own interval (twice the ping's): a
        # daemon alive but useless, for systemd to restart
        watchdog_s = 2.0 * (self.notifier.watchdog_interval_s or math.inf)
        failing_s = self.writer.failing_s(now_s)
        if failing_s > watchdog_s:
            if not self._output_logged:
                log.error("output %s has taken nothing for %.1f s; no watchdog ping (systemd will restart fogd)",
                          self.writer.sink.name, failing_s)  # fmt: skip
                self._output_logged = True
            return False
        self._output_logged = False
        return self.reader.alive and self.writer.alive

    def _follow_rate(self, now_s: float) -> None:
        """Use the rate the frames' own clock says once it has disagreed with the one in use (clock.py)."""
        rate_hz = self.rate.check(now_s)
        if rate_hz is None:
            return
        try:
            compensator = self._compensator(self.models, rate_hz)
        except (ValueError, FogdError) as error:  # a window the measured rate cannot hold
            log.error("rate: cannot run the model at %g Hz (%s); keeping %g Hz", rate_hz, printable(str(error)),
                      self.rate_hz)  # fmt: skip
            self.rate.keep()
            return
        self._drain()  # what arrived so far at the old rate
        self.compensator, self.rate_hz = compensator, rate_hz
        self.rate.use(rate_hz)

    def _handle_reload(self) -> None:
        """Start preparing a requested reload on a helper thread; swap in a prepared one (between batches)."""
        if self._reload_requested.is_set() and self._reload_thread is None:
            self._reload_requested.clear()
            if self._reload is None:
                log.warning("SIGHUP: nothing to reload")
                return
            self.notifier.send("RELOADING=1", f"MONOTONIC_USEC={time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000}")
            self._reload_ready = None
            self._reload_started_s = time.monotonic()
            self._reload_thread = threading.Thread(target=self._prepare_reload, name="fogd-reload", daemon=True)
            self._reload_thread.start()
        thread = self._reload_thread
        if thread is not None and thread.is_alive() and time.monotonic() - self._reload_started_s > RELOAD_TIMEOUT_S:
            # a read blocked in the kernel cannot be interrupted: abandon the thread (its result is never used)
            self.counters.reloads_stuck += 1
            log.error("reload stuck for %.0f s (a FIFO or a hung filesystem?); abandoned, keeping model %s",
                      RELOAD_TIMEOUT_S, printable(self.model.name))  # fmt: skip
            self._reload_thread = None
            self.notifier.send("READY=1", f"STATUS={self.short_status()}")
        elif thread is not None and not thread.is_alive():
            self._reload_thread = None
            prepared, self._reload_ready = self._reload_ready, None
            if prepared is not None:
                self._drain()  # the batches already received are compensated with the model they arrived under
                try:
                    self.apply(prepared)
                except Exception as error:  # a reload must never take the running daemon down
                    self.counters.reloads_refused += 1
                    log.error("reload failed (%s); keeping model %s", printable(repr(error))[:200], printable(self.model.name))
            self.notifier.send("READY=1", f"STATUS={self.short_status()}")

    def _prepare_reload(self) -> None:
        me = threading.current_thread()
        try:
            prepared = self._reload()
            models = as_models(prepared.model)
            if plan(models, self.formatter.protocol, self.axis).covered != self.plan.covered:
                raise ConfigError(f"model {models.name} compensates {', '.join(models)}, the running one "
                                  f"{', '.join(self.plan.covered)}; restart fogd to change channels")  # fmt: skip
            compensator = self._compensator(models, self.rate_hz)  # allocated here, off the data path
        except FogdError as error:
            self.counters.reloads_refused += 1
            log.error("reload refused: %s; keeping model %s", printable(str(error)), printable(self.model.name))
            return
        except Exception as error:  # a bug must not take the running daemon down with it
            self.counters.reloads_refused += 1
            log.error("reload failed (%s); keeping model %s", printable(repr(error))[:200], printable(self.model.name))
            return
        if self._reload_thread is me:  # not abandoned as stuck meanwhile
            self._reload_ready = replace(prepared, compensator=compensator)

    def apply(self, reload: Reload) -> None:
        """Use a validated reload from the next batch on."""
        self.temp_stale_s = reload.temp_stale_s
        self.status_interval_s = reload.status_interval_s
        model, models = reload.model, as_models(reload.model)
        new = reload.compensator or self._compensator(models, self.rate_hz)
        kept = new.carry_state_from(self.compensator)
        state = "kept (same inputs)" if kept else "reset (inputs differ): warm-up again"
        if self.thermal is not None:  # the history primes new inputs (serving.thermalstate)
            state = self.thermal.reloaded([models[c] for c in self.plan.covered], new, prime=not kept)
        self.compensator, self.model, self.models = new, model, models
        self.counters.reloads += 1
        log.warning("reloaded: model %s (%s); estimator state %s", printable(model.name), method(models), state)

    def take_inline(self, frames: list[Frame], t_rx_s: float) -> bool:
        """The reader's offer of one read's frames: hand them on here, on its thread, when they are few, none
        wait in the ring before them and the loop is not busy; False: they go into the ring."""
        ring = self.reader.ring  # (its counters, not len(): two calls a frame fewer on the reader's path)
        if len(frames) > INLINE_MAX or ring.pushed != ring.popped or not self._handing_on.acquire(False):
            return False
        try:  # (only the reader pushes into the ring: it is still empty)
            if len(frames) == 1 and self._one_row:
                self._hand_on_one(frames[0], t_rx_s)
            else:
                self._hand_on(frames, [t_rx_s] * len(frames))
        finally:
            self._handing_on.release()
        return True

    def _drain(self) -> None:
        """Compensate and hand on every batch in the ring (the caller holds `_handing_on`)."""
        while True:
            frames, t_rx_s = self.ring.pop(MAX_BATCH)
            if not frames:
                return
            self._hand_on(frames, t_rx_s)
            if len(frames) < MAX_BATCH:  # a short pop emptied the ring: no second pop to find it empty
                return

    def _hand_on(self, frames: list[Frame], t_rx_s: list[float]) -> None:
        """Compensate, encode and submit to the writer one batch (the caller holds `_handing_on`)."""
        self.counters.records_popped += len(frames)
        try:
            batch = self.compensate(frames, t_rx_s)
        except Exception as error:  # a bug must cost the batch (counted), never the daemon
            self._count_unencodable(len(frames), error)
            return
        try:
            chunk = self.formatter.encode(batch)
        except Exception as error:  # a value the output format cannot carry: drop that frame alone
            chunk = self._encode_each(batch, error)
        self.writer.submit(chunk)

    def _hand_on_one(self, frame: Frame, t_rx_s: float) -> None:
        """`_hand_on` of a read's one frame on a one-gyro model (the usual read at real rates), in one call: the
        same floats, flags, counters and bytes as `_hand_on`'s path (tests/test_one_row.py holds them equal), without
        its batch lists and the layers between (on a box idle between frames every call a frame makes runs cold)."""
        thermal = self.thermal
        kind = frame.kind
        if kind not in RATE_KINDS or (thermal is not None and thermal.pending):
            self._hand_on([frame], [t_rx_s])
            return
        counters = self.counters
        counters.records_popped += 1
        try:
            hold, axis = self.temperature, self._one_axis
            if kind in TEMP_KINDS and frame.temp_c is not None:
                hold.temp_c, hold.rx_s = frame.temp_c, t_rx_s
            reading, present = frame.rate_dph[axis], frame.axis_present[axis]
            held_c, temp_rate_cps, comp_dph, rate_comp_dph, flags = self.compensator.sample_one(
                reading, hold.temp_c, frame.axis_valid[axis] and present, t_rx_s - hold.rx_s > self.temp_stale_s)
            if flags & _OUT_OF_DOMAIN:
                counters.samples_out_of_domain += 1
            if flags & _CLAMPED:
                counters.samples_clamped += 1
            counters.samples_compensated += 1
            latency = self.latency
            latency.last_s = latency_s = time.monotonic() - t_rx_s
            if latency_s > latency.max_s:
                latency.max_s = latency_s
            seen = self.channels_seen  # (MissingChannels.add of one gyro)
            if seen.first_s is None:
                seen.first_s = t_rx_s
            if present:
                seen.seen[0] = True
            else:
                counters.samples_missing_channel += 1
            if frame.flags & TIME_BACKWARDS:
                flags |= _TIME_BACKWARDS
            device_s, clock = frame.t_s, self.clock
            if device_s is not None:
                self.rate.add([device_s])
            t_s = clock.count / clock.rate_hz if device_s is None or device_s != device_s else device_s  # (SampleClock.times)
            clock.count += 1
            comp = Compensated([held_c], [temp_rate_cps], [comp_dph], [rate_comp_dph], [flags])  # type: ignore[arg-type]
            self._newest = ([reading], comp, None)
            if thermal is not None:
                counters.samples_warming += thermal.observe([t_s], comp, None)
            chunk = self.formatter.encode_one(frame, t_s, comp)
        except Exception as error:  # as in `_hand_on`: the frame is counted, the daemon goes on
            self._count_unencodable(1, error)
            return
        self.writer.submit(chunk)

    def _encode_each(self, batch: OutputBatch, error: Exception) -> Chunk:
        """The batch encoded frame by frame, leaving out (and counting) the frames that cannot be encoded."""
        data, ends = [], []
        total = 0
        for one in split_batch(batch):
            try:
                chunk = self.formatter.encode(one)
            except Exception as one_error:
                self._count_unencodable(len(one.frames), one_error)
                continue
            data.append(chunk.data)
            ends.extend(total + end for end in chunk.frame_ends)
            total += len(chunk.data)
        return Chunk(b"".join(data), ends)

    def _count_unencodable(self, frames: int, error: Exception) -> None:
        self.counters.frames_unencodable += frames
        if not self._encode_error_logged:
            log.error("dropped %d frame(s) that cannot be compensated or encoded (%s: %s); counted as "
                      "frames_unencodable", frames, type(error).__name__, printable(str(error))[:200])  # fmt: skip
            self._encode_error_logged = True

    def compensate(self, frames: list[Frame], t_rx_s: list[float]) -> OutputBatch:
        """One channel-compensator call for every rate sample in `frames` (received at `t_rx_s`), every
        covered channel at once; a few frames (a batch at real rates is one) go row by row through the
        compensator's pre-bound `process_row`, in plain Python."""
        if self.thermal is not None and self.thermal.pending:
            self._thermal_start(frames)
        if len(frames) <= SCALAR_CHUNK:
            return self._compensate_rows(frames, t_rx_s)
        samples = self.temperature.channel_samples(frames, t_rx_s, self.plan.sources)
        rows, temp_c, names = samples.rows, samples.temp_c, self._names
        stale_s = self.temp_stale_s
        stale = [age_s > stale_s for age_s in samples.temp_age_s]
        comps = self.compensator.process(
            {name: np.array(values, dtype=np.float64) for name, values in zip(names, samples.values)},
            np.array(temp_c, dtype=np.float64),
            rate_valid={name: np.array(ok, dtype=bool) for name, ok in zip(names, samples.usable)},
            temp_stale=np.array(stale, dtype=bool),
        )  # fmt: skip
        comp = comps[names[0]]
        self._count_domain(comp.flags if len(names) == 1 else _any_flags(comps.values()))
        return self._batch(frames, t_rx_s, rows, samples.device_s, samples.values[0], comp, comps)

    def _thermal_start(self, frames: list[Frame]) -> None:
        """At the first valid temperature: restore the thermal state (or start cold) before it is compensated."""
        low_c, high_c = TEMP_VALID_C
        for frame in frames:
            if frame.kind in TEMP_KINDS and frame.temp_c is not None and low_c <= frame.temp_c <= high_c:
                device = frame.t_s is not None and frame.t_s == frame.t_s
                t_s = frame.t_s if device else self.clock.count / self.rate_hz
                self.thermal.start(t_s, device, frame.temp_c, self.compensator)
                return

    def _compensate_rows(self, frames: list[Frame], t_rx_s: list[float]) -> OutputBatch:
        """`compensate` of a few frames, one `process_row` per rate frame; the same floats and flags."""
        hold = self.temperature
        held_c, held_rx_s = hold.temp_c, hold.rx_s
        stale_s, row, read = self.temp_stale_s, self.compensator.process_row, self._read
        axis = self._one_axis
        sample_one = self.compensator.sample_one if axis is not None else None
        rows, device_s, results = [], [], []
        out_of_domain = clamped = 0
        for index, frame in enumerate(frames):
            kind = frame.kind
            if kind in TEMP_KINDS and frame.temp_c is not None:
                held_c, held_rx_s = frame.temp_c, t_rx_s[index]
            if kind not in RATE_KINDS:
                continue
            stale = t_rx_s[index] - held_rx_s > stale_s
            if sample_one is not None:  # process_row's own sample, without _read's and its lists on the way
                reading = frame.rate_dph[axis]
                held, temp_rate, comp, out, flags = sample_one(reading, held_c, frame.axis_valid[axis] and frame.axis_present[axis],
                                                              stale)  # fmt: skip
                result = (held, temp_rate, [comp], [out], [flags])
            else:
                values, usable = read(frame)
                reading, result = values[0], row(values, usable, held_c, stale)
            rows.append(index)
            device_s.append(frame.t_s)
            results.append((reading, result))
            any_flags = 0
            for flags in result[4]:
                any_flags |= flags
            if any_flags:
                out_of_domain += bool(any_flags & _OUT_OF_DOMAIN)
                clamped += bool(any_flags & _CLAMPED)
        hold.temp_c, hold.rx_s = held_c, held_rx_s
        if out_of_domain or clamped:
            self.counters.samples_out_of_domain += out_of_domain
            self.counters.samples_clamped += clamped
        # every channel's temperature columns are the first channel's (what every output format reports)
        if len(results) == 1 and self.plan.single:  # the usual batch at real rates: process_row's own lists
            (reading, (temp, temp_rate, comps, outs, flags)), = results
            comp = Compensated([temp], [temp_rate], comps, outs, flags)  # type: ignore[arg-type]
            return self._batch(frames, t_rx_s, rows, device_s, [reading], comp, None)
        readings = [reading for reading, _ in results]
        temps = [result[0] for _, result in results]
        temp_rates = [result[1] for _, result in results]
        columns = {name: Compensated(temps, temp_rates, [result[2][k] for _, result in results],  # type: ignore[arg-type]
                                     [result[3][k] for _, result in results], [result[4][k] for _, result in results])
                   for k, name in enumerate(self._names)}  # fmt: skip
        return self._batch(frames, t_rx_s, rows, device_s, readings, columns[self._names[0]], columns)

    def _read(self, frame: Frame) -> tuple[list[float], list[bool]]:
        """A rate frame's reading and usability of every covered channel (an accelerometer a frame lacks is NaN
        and unusable)."""
        values, usable = [], []
        for accel, axis in self.plan.sources:
            if not accel:
                values.append(frame.rate_dph[axis])
                usable.append(frame.axis_valid[axis] and frame.axis_present[axis])
            elif frame.accel_g is None:
                values.append(_NAN)
                usable.append(False)
            else:
                values.append(frame.accel_g[axis])
                usable.append(frame.accel_valid[axis] and frame.accel_present[axis])
        return values, usable

    def _batch(self, frames: list[Frame], t_rx_s: list[float], rows: list[int], device_s: list[float | None],
               readings: list[float], comp: Compensated, comps: dict[str, Compensated] | None) -> OutputBatch:  # fmt: skip
        """The compensated batch for the formatter; counters, latency and the newest sample noted. `comps`:
        every channel's columns (None: one channel, `comp`)."""
        self.counters.samples_compensated += len(rows)
        if frames:
            latency_s = time.monotonic() - t_rx_s[0]  # the oldest frame waited longest
            self.latency.last_s = latency_s
            if latency_s > self.latency.max_s:
                self.latency.max_s = latency_s
        if rows:
            self._newest = (readings, comp, comps)  # made into `latest` only when someone reads it
            if device_s[0] is not None:
                self.rate.add(device_s)
            lacking = self.channels_seen.add(frames, rows, t_rx_s[0])
            if lacking:
                self.counters.samples_missing_channel += lacking
            for j, row in enumerate(rows):
                if frames[row].flags & TIME_BACKWARDS:  # the lexer's mark, in the sample's own flags
                    for one in (comps.values() if comps else (comp,)):
                        one.flags[j] |= _TIME_BACKWARDS
        times = self.clock.times(device_s)
        if self.thermal is not None:
            self.counters.samples_warming += self.thermal.observe(times, comp, comps)
        t_s = times if len(frames) <= SCALAR_CHUNK else np.array(times, dtype=np.float64)
        return OutputBatch(frames, rows, t_s, comp, None if self.plan.single else comps)

    @property
    def latest(self) -> Latest:
        """The newest compensated sample (for the status line, systemd and the stats file)."""
        newest = self._newest  # set by whichever thread hands frames on: read once, never cleared
        if newest is not None and newest is not self._latest_of:
            readings, comp, comps = newest
            self._latest = Latest(
                float(readings[-1]), float(comp.comp_dph[-1]), float(comp.rate_comp_dph[-1]), float(comp.temp_c[-1]),
                float(comp.temp_rate_cps[-1]), int(comp.flags[-1]),
                None if self.plan.single else {name: {"comp": float(one.comp_dph[-1]), "flags": int(one.flags[-1])}
                                               for name, one in comps.items()},
            )  # fmt: skip
            self._latest_of = newest
        return self._latest

    def _count_domain(self, flags: np.ndarray | list[int]) -> None:
        """Running counts of the samples flagged OUT_OF_DOMAIN and CLAMPED."""
        if isinstance(flags, list):  # a frame or two: Python ints cost less than two numpy calls
            for value in flags:
                if value & _OUT_OF_DOMAIN:
                    self.counters.samples_out_of_domain += 1
                if value & _CLAMPED:
                    self.counters.samples_clamped += 1
        else:
            self.counters.samples_out_of_domain += int(np.count_nonzero(flags & _OUT_OF_DOMAIN))
            self.counters.samples_clamped += int(np.count_nonzero(flags & _CLAMPED))

    def domain_shares(self) -> dict[str, float]:
        """Fractions of the samples compensated since start that took the fallback, or were clamped (NaN
        before the first sample)."""
        total = self.counters.samples_compensated
        if not total:
            return {"out_of_domain": float("nan"), "clamped": float("nan")}
        counters = self.counters
        return {"out_of_domain": counters.samples_out_of_domain / total, "clamped": counters.samples_clamped / total}

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
            f"{name} {value}" for name, value in lexer.as_dict().items() if value and name not in NOT_DROPS
        )
        dropped_out = (
            writer.frames_dropped_full + writer.frames_dropped_timeout + writer.frames_dropped_error
            + writer.frames_dropped_exit + writer.frames_cut + writer.frames_dropped_no_reader
        )
        return (
            f"in {frames_in or 0} | out {writer.frames_written} dropped {dropped_out} | drops {drops or 'none'} | "
            f"ring overruns {self.ring.overruns} | reconnects {reader.reconnects}"
            f"{f' (about {reader.disconnected_s * self.rate_hz:.0f} frames lost unplugged)' if reader.disconnects else ''} | "
            f"rate {self.rate.describe()} | {self._missing_text()}"
            f"latency {1e3 * self.latency.last_s:.1f} ms (max {1e3 * self.latency.max_s:.1f}) | "
            f"T {latest.temp_c:.2f} C dT/dt {latest.temp_rate_cps:+.5f} C/s {self._comp_text()} | "
            f"{_shares_text(self.domain_shares())} | model {printable(self.model.name)} | fogd {__version__}"
        )

    def _missing_text(self) -> str:
        """'MISSING rate_x_dph (1234 samples) | ' for compensated channels the frames never carried, else ''."""
        missing = self.channels_seen.missing
        if not missing:
            return ""
        return f"MISSING {', '.join(missing)} ({self.counters.samples_missing_channel} samples) | "

    def _comp_text(self) -> str:
        """'comp +0.0123 deg/h (flags)', or with a multi-channel model each channel's, and those passed through."""
        latest = self.latest
        if latest.channels is None:
            if not self.plan.single:  # nothing compensated yet
                return f"comp - ({', '.join(self.plan.covered)}{self._passed_text()})"
            return f"comp {latest.comp_dph:+.4f} deg/h ({describe(latest.flags)})"
        parts = [f"{name} {one['comp']:+.6g} ({describe(int(one['flags']))})" for name, one in latest.channels.items()]
        return f"comp {' '.join(parts)}{self._passed_text()}"

    def _passed_text(self) -> str:
        return f"; passed through: {', '.join(self.plan.passed)}" if self.plan.passed else ""

    def short_status(self) -> str:
        """One short line for systemd's STATUS= (shown by systemctl status)."""
        latest = self.latest
        link = "" if getattr(self.reader, "connected", True) else "port lost, waiting | "
        return (
            f"{link}{self.counters.samples_compensated} samples | T {latest.temp_c:.2f} C | "
            f"comp {latest.comp_dph:+.4f} deg/h | model {printable(self.model.name)}"
        )

    def snapshot(self) -> dict:
        """Everything an operator reads from the stats file, `fogd --status` or the metrics endpoint."""
        now_s = time.monotonic()
        return {
            **self.info,
            "version": __version__,
            "pid": os.getpid(),
            "running": not self._stop.is_set(),
            "time_unix_s": time.time(),
            "uptime_s": now_s - self.started_s,
            "connected": bool(getattr(self.reader, "connected", True)),
            "model": {"name": self.model.name, "method": method(self.models), "held_out": held_out(self.models)},
            "channels": {"compensated": list(self.plan.covered), "passed": list(self.plan.passed)},
            "missing_channels": self.channels_seen.missing,  # compensated, but no frame has carried them
            "rate": self.rate.as_dict(),
            "cpu": self.placement.describe(),
            "latest": asdict(self.latest),
            "latency_s": {"last": self.latency.last_s, "max_since_status": self.latency.max_s},
            "counters": self.counters_dict(),
            "domain_shares": self.domain_shares(),
            "thermal": self.thermal.status() if self.thermal is not None else None,
            "history": {name: [point[i] for point in list(self.history)] for i, name in enumerate(HISTORY_FIELDS)},
            "status": self.status_line(),
        }

    def counters_dict(self) -> dict:
        """Every counter, for tests and the final log line."""
        return {
            "reader": asdict(self.reader.counters),
            "lexer": self.reader.lexer.counters.as_dict(),
            "ring_overruns": self.ring.overruns,
            "writer": asdict(self.writer.counters),
            "loop": asdict(self.counters),
            "balance": self.balance(),
        }

    def balance(self) -> dict:
        """Where every decoded frame went: in = out + used_as_input + sum(dropped) + sum(pending). Frames used
        as input are the temperature (and other) frames an output format without them consumes; at a clean
        stop nothing is pending."""
        lexer, writer, loop = self.reader.lexer.counters, self.writer.counters, self.counters
        settled = (
            writer.frames_written + writer.frames_dropped_full + writer.frames_dropped_timeout
            + writer.frames_dropped_error + writer.frames_dropped_exit + writer.frames_cut
            + writer.frames_dropped_no_reader
        )  # fmt: skip
        dropped = {
            "ring_overrun": self.ring.overruns,
            "unencodable": loop.frames_unencodable,
            "output_queue_full": writer.frames_dropped_full,
            "output_timeout": writer.frames_dropped_timeout,
            "output_error": writer.frames_dropped_error,
            "output_at_exit": writer.frames_dropped_exit,
            "output_cut": writer.frames_cut,
            "output_no_reader": writer.frames_dropped_no_reader,
        }
        pending = {
            "ring": len(self.ring),
            "writer": writer.frames_submitted - settled,
            "reader": lexer.frames_ok + lexer.other_frames - sum(self.reader.counters.frames_in.values()),
        }
        frames_in = lexer.frames_ok + lexer.other_frames
        used = loop.records_popped - loop.frames_unencodable - writer.frames_submitted
        return {
            "in": frames_in, "out": writer.frames_written, "used_as_input": used, "dropped": dropped,
            "pending": pending, "adds_up": frames_in == writer.frames_written + used + sum(dropped.values()) + sum(pending.values()),
        }  # fmt: skip


def _any_flags(comps) -> list[int] | np.ndarray:
    """Each sample's flags of every channel together (a sample is out of domain if any channel is)."""
    columns = [comp.flags for comp in comps]
    if isinstance(columns[0], list):
        return [_or(values) for values in zip(*columns)]
    return np.bitwise_or.reduce(np.stack(columns), axis=0)


def _or(values: tuple[int, ...]) -> int:
    result = 0
    for value in values:
        result |= value
    return result


def _shares_text(shares: dict[str, float]) -> str:
    """'fallback 0.4 % clamped 1.2 %' (no share before the first sample)."""
    fallback, clamped = shares["out_of_domain"], shares["clamped"]
    if fallback != fallback:
        return "fallback - clamped -"
    return f"fallback {100.0 * fallback:.1f} % clamped {100.0 * clamped:.1f} %"
