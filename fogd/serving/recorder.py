"""Recording a run from the reader's frames: the CSV rows `fogd-record` writes (one axis, or every chosen
channel of an IMU), with the temperature held per frame and the daemon's sample clock, optionally
decimated, plus what its status line shows.
"""

from __future__ import annotations

import os
from typing import IO, Sequence

import numpy as np

from fogd.core.columns import ACCEL_CHANNELS, CHANNELS, GYRO_CHANNELS, RUN_COLUMNS
from fogd.core.estimator import EstimatorSettings, TempRateEstimator
from fogd.errors import UsageError
from fogd.protocols.base import Frame, Protocol
from fogd.serving.channels import source
from fogd.serving.daemon import SampleClock, TemperatureHold


class Recorder:
    """Turns batches of ring frames into CSV rows and keeps what the status line shows."""

    def __init__(self, stream: IO[str], axis: int, rate_hz: float, decimate: int = 1,
                 channels: Sequence[str] | None = None) -> None:  # fmt: skip
        self.stream = stream
        self.decimate = decimate
        self.channels = list(channels) if channels else None
        width = 3 if self.channels is None else 2 + len(self.channels)
        self._pending = tuple(np.empty(0) for _ in range(width))  # samples waiting for a full group of `decimate`
        self.axis = axis
        self._sources = ((False, axis),) if self.channels is None else tuple(source(name) for name in self.channels)
        self.temperature = TemperatureHold()
        self.clock = SampleClock(rate_hz)
        self.temp_rate = TempRateEstimator(EstimatorSettings(), rate_hz / decimate)  # one estimate per row written
        self.rows = 0
        self.skipped_no_temp = 0
        self.temp_c = float("nan")
        self.temp_rate_cps = float("nan")

    def header(self) -> str:
        return ",".join(RUN_COLUMNS if self.channels is None else ("t_s", *self.channels, "temp_c")) + "\n"

    def write(self, batch: tuple[list[Frame], list[float]]) -> None:
        """One row per rate frame with a temperature held for it; a chosen channel a frame lacks or marks
        invalid is NaN (the single axis is written as the wire carried it)."""
        samples = self.temperature.channel_samples(*batch, self._sources)
        temp_c = np.array(samples.temp_c, dtype=np.float64)
        t_s = np.array(self.clock.times(samples.device_s), dtype=np.float64)
        values = np.array(samples.values, dtype=np.float64).reshape(len(self._sources), -1)
        if self.channels is not None:
            values[~np.array(samples.usable, dtype=bool).reshape(values.shape)] = np.nan
        known = ~np.isnan(temp_c)
        self.skipped_no_temp += int((~known).sum())
        if not known.any():
            return
        columns = (t_s[known], *values[:, known], temp_c[known])
        if self.decimate > 1:
            columns = self._averaged(*columns)
            if not columns[0].size:
                return
        # repr keeps every value exactly as decoded, so a replay of this file sees what the wire carried
        rows = zip(*(column.tolist() for column in columns))
        self.stream.write("".join(f"{row[0]:.6f}," + ",".join(map(repr, row[1:])) + "\n" for row in rows))
        temps = columns[-1]
        self.rows += temps.size
        finite = temps[np.isfinite(temps)]
        if finite.size:
            self.temp_rate_cps = float(self.temp_rate.update(finite)[-1])
            self.temp_c = float(finite[-1])

    def _averaged(self, *columns: np.ndarray) -> tuple[np.ndarray, ...]:
        """Means of whole groups of `decimate` samples; the rest waits for the next batch."""
        joined = [np.concatenate((pending, column)) for pending, column in zip(self._pending, columns)]
        whole = joined[0].size // self.decimate * self.decimate
        self._pending = tuple(column[whole:] for column in joined)
        return tuple(column[:whole].reshape(-1, self.decimate).mean(axis=1) for column in joined)


class RowFile:
    """The CSV being recorded, written in whole rows: text is kept until `flush`, which writes it all; a write
    that fails (a full disk, a file-size limit) cuts the file back to the end of the last row that fitted, so
    what is on disk is always a run fogd-replay reads, then raises the OSError."""

    def __init__(self, path: str) -> None:
        self.path = path
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_NOCTTY | os.O_CLOEXEC, 0o666)
        self._pending: list[str] = []
        self.whole_bytes = 0  # on disk, ending at a row's end

    def write(self, text: str) -> None:
        self._pending.append(text)

    def flush(self) -> None:
        data = "".join(self._pending).encode("utf-8")
        self._pending.clear()
        done = 0
        try:
            while done < len(data):
                done += os.write(self._fd, data[done:])
        except OSError:
            self.whole_bytes += data.rfind(b"\n", 0, done) + 1
            try:
                os.ftruncate(self._fd, self.whole_bytes)  # drop the part of a row that fitted
            except OSError:
                pass  # a FIFO or a device: nothing to cut back
            raise
        self.whole_bytes += done

    def close(self) -> None:
        """Flush what is left and close; the descriptor is closed even when the flush fails."""
        try:
            self.flush()
        finally:
            os.close(self._fd)


def chosen_channels(text: str, protocol: Protocol) -> list[str]:
    """--channels: 'all' (what `protocol` can carry) or a comma-separated list, in CHANNELS' order."""
    carried = [name for axis, name in enumerate(GYRO_CHANNELS) if protocol.gyro_axes[axis]]
    carried += [name for axis, name in enumerate(ACCEL_CHANNELS) if protocol.accel_axes[axis]]
    if text.strip() == "all":
        return carried
    names = [name.strip() for name in text.split(",") if name.strip()]
    unknown = [name for name in names if name not in CHANNELS]
    if unknown or not names:
        raise UsageError(f"--channels: unknown channel(s) {', '.join(unknown) or repr(text)}; use 'all' or some of {','.join(CHANNELS)}")
    missing = [name for name in names if name not in carried]
    if missing:
        raise UsageError(f"--channels: {protocol.name} frames do not carry {', '.join(missing)} (they carry {','.join(carried)})")
    return [name for name in CHANNELS if name in names]
