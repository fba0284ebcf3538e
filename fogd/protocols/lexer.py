"""The one byte-driven, resynchronising framer for every protocol (after gpsd's packet.c): bytes in, checked
frames out, and a counter for every kind of drop.

The rule is gpsd's: find the next header, size the candidate, check it; on a failed check drop ONE byte and
rescan, so a real frame that starts inside a bad candidate (a false header in garbage, a truncated frame) is
still found. A line format drops the whole bad line instead. Input is consumed in slices of a few frames, so
the buffer never holds more than 17 maximum-size frames whatever `feed` is given.
"""

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass

from ..errors import ConfigError
from .base import IMPLAUSIBLE, TIME_BACKWARDS, Frame, FrameError, Protocol

SLICE_FRAMES = 16


@dataclass(slots=True)
class LexerCounters:
    """What the lexer saw, for the operator. Every byte not inside an accepted frame is a garbage byte,
    including the bytes of rejected candidates."""

    frames_ok: int = 0  # accepted frames carrying data (kind imu, rate, temp, comp)
    other_frames: int = 0  # accepted frames carrying nothing fogd uses (KVH BIT replies, unknown fogd types)
    bad_crc: int = 0  # complete candidates whose CRC or checksum failed
    truncated: int = 0  # failed candidates with another header inside (cut short, false header); flush() leftovers
    bad_line: int = 0  # line-format lines that did not parse
    bad_value: int = 0  # frames whose check passed but whose values no device sends (a time beyond 2^53 us)
    implausible: int = 0  # rates the plausibility check flagged invalid (lines without a checksum, if enabled)
    garbage_bytes: int = 0
    frame_bytes: int = 0  # bytes inside accepted frames: bytes fed = frame_bytes + garbage_bytes + buffered
    seq_gaps: int = 0  # jumps in a sequence counter
    # frames lost in those jumps, modulo the counter's wrap: KVH's counter has 7 bits, so a loss of 128 frames
    # in a row counts nothing and a loss of 127 (or 255, ...) reads as a repeat; it cannot tell them apart
    frames_missing: int = 0
    seq_repeats: int = 0  # a sequence number equal to the previous one (on KVH, also a loss of 127 frames)
    frames_repeated: int = 0  # copies of the frame before (fogd: its sequence number, ascii: its time), dropped
    time_backwards: int = 0  # frames whose device time is earlier than the frame's before (flagged, kept)
    invalid_axes: int = 0  # present axes marked invalid by a status bit or carrying NaN/Inf
    invalid_temps: int = 0  # temperatures that are NaN/Inf
    suspect_frames: int = 0  # frames of an unknown type whose sequence number does not follow (a false header
    # that passed the CRC by chance: 1 in 65536 for CRC-16) -- kept as kind 'other', never used as data
    seq_resets: int = 0  # sequence tracking restarted (flush: end of stream or a lost port)

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


class Lexer:
    """Frames from a byte stream of one protocol, or of several binary protocols sharing a link."""

    def __init__(self, protocols: Protocol | Sequence[Protocol]) -> None:
        self.protocols = [protocols] if isinstance(protocols, Protocol) else list(protocols)
        if not self.protocols:
            raise ConfigError("a lexer needs at least one protocol")
        if len(self.protocols) > 1 and any(protocol.line_based for protocol in self.protocols):
            raise ConfigError("a line protocol (ascii) cannot share a link with other protocols")
        self.counters = LexerCounters()
        self.max_frame_len = max(protocol.max_frame_len for protocol in self.protocols)
        self._slice_len = SLICE_FRAMES * self.max_frame_len
        # A header split across reads: keep the bytes that could be the start of a sync pattern.
        self._keep_len = max(0, max(len(protocol.sync) for protocol in self.protocols) - 1)
        self._buf = b""
        self._last_seq: dict[tuple[str, str], int] = {}
        self._last_t_s: dict[tuple[str, str], float] = {}
        # _scan's view of one protocol, looked up once here rather than on every read
        self._single = self.protocols[0] if len(self.protocols) == 1 else None
        self._fast = getattr(self._single, "decode_fast", None)

    @property
    def buffered(self) -> int:
        """Bytes held back waiting for the rest of a frame."""
        return len(self._buf)

    def feed(self, data: bytes) -> list[Frame]:
        """Every frame completed by `data`, in stream order."""
        if not self._buf and self._fast is not None:  # the usual read: one whole frame, nothing held back
            got = self._fast(data, 0)
            if got is not None and got[1] == len(data):  # (as _scan's first step, without its set-up)
                frame = got[0]
                self.counters.frame_bytes += got[1]
                return [frame] if self._account(frame, self._single) else []
        frames: list[Frame] = []
        if len(data) <= self._slice_len:  # a frame or a few, no slicing
            self._buf = self._buf + data if self._buf else bytes(data)
            self._scan(frames)
            return frames
        for offset in range(0, len(data), self._slice_len):
            self._buf += data[offset : offset + self._slice_len]
            self._scan(frames)
        return frames

    def flush(self) -> list[Frame]:
        """End of stream (stop, a lost port): the frames still inside what is buffered, then drop the rest.

        What is held may start with a false header sized beyond the end (a fogd header of unknown type claims
        up to 255 bytes) with whole frames behind it: drop the held candidate's first byte and rescan, as for a
        failed check. An unfinished frame counts as truncated. Sequence tracking restarts: what follows a gap of
        unknown length cannot be compared with what came before it."""
        frames: list[Frame] = []
        counters = self.counters
        buf = self._buf
        if any(protocol.find(buf, 0) == 0 and protocol.frame_length(buf, 0) >= 0 for protocol in self.protocols):
            counters.truncated += 1
        if self.protocols[0].line_based:  # a line without its newline holds no whole line
            counters.garbage_bytes += len(buf)
            self._buf = b""
        while self._buf:
            counters.garbage_bytes += 1
            self._buf = self._buf[1:]
            self._scan(frames)
        if self._last_seq:
            counters.seq_resets += 1
            self._last_seq.clear()
        self._last_t_s.clear()
        return frames

    def _next_candidate(self, buf: bytes, pos: int) -> tuple[int, Protocol | None]:
        best, best_protocol = -1, None
        for protocol in self.protocols:
            start = protocol.find(buf, pos)
            if start >= 0 and (best < 0 or start < best):
                best, best_protocol = start, protocol
        return best, best_protocol

    def _scan(self, frames: list[Frame]) -> None:
        buf = self._buf
        end = len(buf)
        counters, single, fast = self.counters, self._single, self._fast
        find = single.find if single is not None else None
        account, append = self._account, frames.append
        pos = 0
        while True:
            if fast is not None and pos < end:  # the protocol's usual frame right here, checked and decoded at once
                got = fast(buf, pos)
                if got is not None:
                    frame, length = got
                    counters.frame_bytes += length
                    pos += length
                    if account(frame, single):
                        append(frame)
                    if pos == end:  # the read ended on a frame boundary (the usual read): nothing held back
                        break
                    continue
            if find is not None:
                protocol, start = single, find(buf, pos)
            else:
                start, protocol = self._next_candidate(buf, pos)
            if start < 0:
                keep_from = max(pos, end - self._keep_len)
                counters.garbage_bytes += keep_from - pos
                pos = keep_from
                break
            length = protocol.frame_length(buf, start)
            if length < 0:  # not a header after all: skip it as garbage
                counters.garbage_bytes += start - pos - length
                pos = start - length
                continue
            if length == 0 or start + length > end:  # wait for the rest
                counters.garbage_bytes += start - pos
                pos = start
                break
            raw = buf[start : start + length]
            try:
                frame = protocol.decode(raw)
            except FrameError as error:
                if protocol.line_based:
                    skip, reason = length, error.counter
                else:
                    skip = 1
                    reason = "truncated" if _has_inner_header(protocol, raw) else error.counter
                setattr(counters, reason, getattr(counters, reason) + 1)
                counters.garbage_bytes += start + skip - pos
                pos = start + skip
                continue
            if start != pos:
                counters.garbage_bytes += start - pos
            counters.frame_bytes += length
            pos = start + length
            if account(frame, protocol):
                append(frame)
        self._buf = buf[pos:] if pos else buf

    def _account(self, frame: Frame, protocol: Protocol) -> bool:
        """Count the frame; False for a copy of the one before, dropped (counted `frames_repeated`)."""
        counters = self.counters
        t_s = frame.t_s
        if t_s is not None and frame.kind != "other":
            key = (frame.protocol, frame.message)
            previous_t_s = self._last_t_s.get(key)
            self._last_t_s[key] = t_s
            if previous_t_s is not None and t_s <= previous_t_s:
                if t_s == previous_t_s and frame.seq is None:  # a line repeated (ascii lines carry no number)
                    counters.frames_repeated += 1
                    return False
                if t_s < previous_t_s and frame.kind != "comp":  # a clock that went back: flagged, not a step
                    counters.time_backwards += 1
                    frame.flags |= TIME_BACKWARDS
        if frame.kind == "other":
            counters.other_frames += 1
        else:
            counters.frames_ok += 1
        if frame.axis_valid != frame.axis_present:
            counters.invalid_axes += sum(p and not v for p, v in zip(frame.axis_present, frame.axis_valid))
            if frame.flags & IMPLAUSIBLE and frame.kind != "comp":
                counters.implausible += 1
        if frame.temp_c is not None and not math.isfinite(frame.temp_c):
            counters.invalid_temps += 1
        seq = frame.seq
        if seq is None or protocol.seq_modulus is None:
            return True
        key = (frame.protocol, frame.message) if frame.kind != "other" else (frame.protocol, frame.raw[:3])
        previous = self._last_seq.get(key)
        self._last_seq[key] = seq
        if previous is None:
            if frame.kind == "other" and frame.message == "other":  # a first frame of a type fogd does not know
                counters.suspect_frames += 1
            return True
        step = (seq - previous) % protocol.seq_modulus
        if frame.kind == "other" and frame.message == "other" and step != 1:
            counters.suspect_frames += 1
        if step == 0:
            counters.seq_repeats += 1
            if protocol.repeats_are_copies and frame.kind != "other":
                # counted as a repeat, not as a frame: frames_ok stays the count of frames passed on
                counters.frames_ok -= 1
                counters.frames_repeated += 1
                return False
        elif step != 1:
            counters.seq_gaps += 1
            counters.frames_missing += step - 1
        return True


def _has_inner_header(protocol: Protocol, raw: bytes) -> bool:
    """Whether a header of `protocol` starts inside the failed candidate `raw` (after its first byte)."""
    start = protocol.find(raw, 1)
    while start >= 0:
        if protocol.frame_length(raw, start) >= 0:
            return True
        start = protocol.find(raw, start + 1)
    return False
