"""Which CPU the daemon's threads run on (setting `cpu`): by default all on one, together.

Why: the reader thread builds each frame's objects and the loop thread uses them microseconds later. Left to
the kernel, the loop wakes on whichever CPU is idle, so at real rates every frame crosses between two CPUs'
caches and lands on a CPU that idled a millisecond and went cold. The GIL runs one of the threads at a time
anyway, so one CPU takes no parallelism away. tools/bench_daemon.py measures both in one run (`fogd` and
`fogd, --cpu any`): on 2026-11-27, 5.8 % of a core against 9.2 % at 1,000 frames/s, 16.2 % against 21.4 % at
5,000/s. The price on that VM is the latency tail: a process on the other CPU wakes an idle CPU for each frame.

- `auto` (the default): the threads stay on the CPU the daemon starts on. Every `CHECK_EVERY_S` it looks at
  how much of that CPU other processes took; above `BUSY_SHARE`, with another allowed CPU at least `MARGIN`
  less busy, the threads move there (logged, counted).
- a CPU number: the threads stay there (it must be one the process may use: systemd's CPUAffinity=, a cpuset).
- `any`: the kernel places each thread as it likes (fogd before this setting existed).

Threads started after `start` inherit its CPU (Linux affinity is per thread and inherited); a move re-pins
every thread still on the old CPU. Where affinity cannot be set (not Linux, a container that refuses it),
`auto` logs once and lets the kernel place the threads.
"""

from __future__ import annotations

import argparse
import logging
import os
from dataclasses import dataclass

log = logging.getLogger("fogd.placement")

AUTO, ANY = "auto", "any"
ANY_WORDS = (ANY, "none", "off")
CHECK_EVERY_S = 5.0
BUSY_SHARE = 0.5  # of the CPU taken by other processes before the threads look for another
MARGIN = 0.25  # how much less busy the other CPU must be: no moving back and forth between two busy ones
_CAN_PIN = hasattr(os, "sched_setaffinity")


def allowed_cpus() -> set[int]:
    """The CPUs the calling thread may run on (systemd's CPUAffinity=, a cpuset); every CPU where unknown.
    Affinity is per thread: asked before pinning, it is the process's."""
    return os.sched_getaffinity(0) if _CAN_PIN else set(range(os.cpu_count() or 1))


def cpu_setting(text: str) -> str | int:
    """The `cpu` setting from text: 'auto', 'any' (also 'none', 'off') or a CPU this process may use."""
    word = text.strip().lower()
    if word == AUTO:
        return AUTO
    if word in ANY_WORDS:
        return ANY
    try:
        cpu = int(word)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text[:40]!r} is not auto, any or a CPU number") from None
    if not _CAN_PIN:
        raise argparse.ArgumentTypeError("keeping threads on a CPU needs Linux (sched_setaffinity); use auto or any")
    allowed = allowed_cpus()
    if cpu not in allowed:
        raise argparse.ArgumentTypeError(f"CPU {cpu} is not one this process may run on (allowed: {_list(allowed)})")
    return cpu


def better_cpu(current: int, others_share: dict[int, float]) -> int | None:
    """Where to move from `current`, given each allowed CPU's share taken by other processes; None: stay."""
    busy = others_share[current]
    if busy <= BUSY_SHARE:
        return None
    best = min(sorted(others_share), key=lambda cpu: others_share[cpu])
    return best if others_share[best] <= busy - MARGIN else None


@dataclass
class Placement:
    """Keeps the calling thread, and the threads it starts, on one CPU as `setting` says."""

    setting: str | int = AUTO
    cpu: int | None = None  # where the threads are kept (None: the kernel places them)
    moves: int = 0
    allowed: frozenset[int] = frozenset()  # the CPUs the process may use (read before pinning)
    _last: tuple[float, dict[int, float], float] | None = None  # (time, busy seconds by CPU, our threads' seconds)
    _next_check_s: float = 0.0

    def start(self) -> None:
        """Pin the calling thread (the daemon's main thread, before it starts the others)."""
        if self.setting == ANY:
            return
        self.allowed = frozenset(allowed_cpus())
        cpu = self.setting if isinstance(self.setting, int) else current_cpu()
        if not _CAN_PIN or cpu is None:
            log.info("cpu %s: cannot tell or set where threads run here; the kernel places them", self.setting)
            return
        try:
            os.sched_setaffinity(0, {cpu})
        except OSError as error:
            log.warning("cannot keep fogd's threads on CPU %d (%s); the kernel places them", cpu, error.strerror)
            return
        self.cpu = cpu
        if self.setting == AUTO and len(self.allowed) > 1:
            log.info("threads kept on CPU %d (cpu: auto: they move when other processes take over %.0f %% of it)",
                     cpu, 100 * BUSY_SHARE)  # fmt: skip
        else:
            log.info("threads kept on CPU %d (cpu: %s)", cpu, self.setting)

    def follow(self, now_s: float) -> None:
        """With `auto`, every CHECK_EVERY_S: move the threads off a CPU that other processes keep busy."""
        if self.setting != AUTO or self.cpu is None or now_s < self._next_check_s:
            return
        self._next_check_s = now_s + CHECK_EVERY_S
        try:
            busy_s, ours_s = cpu_busy_s(self.allowed), threads_cpu_s(self.cpu)
        except (OSError, ValueError, IndexError):
            return  # /proc unreadable now: look again next time
        last, self._last = self._last, (now_s, busy_s, ours_s)
        if last is None or now_s <= last[0]:
            return
        window_s = now_s - last[0]
        others = {cpu: max(0.0, busy_s[cpu] - last[1].get(cpu, busy_s[cpu])) / window_s for cpu in busy_s}
        if self.cpu not in others:
            return
        others[self.cpu] = max(0.0, others[self.cpu] - (ours_s - last[2]) / window_s)
        target = better_cpu(self.cpu, others)
        if target is not None:
            self.move(target, others, window_s)

    def move(self, target: int, others_share: dict[int, float], window_s: float) -> None:
        """Re-pin every thread kept on the current CPU to `target`, and say why (`others_share` over `window_s`)."""
        old = self.cpu
        for tid in threads_on(old):
            try:
                os.sched_setaffinity(tid, {target})
            except OSError:  # a thread that ended meanwhile
                continue
        self.cpu = target
        self.moves += 1
        self._last = None  # the next check starts a fresh window on the new CPU
        log.warning("CPU %s busy: other processes took %.0f %% of it over %.1f s; fogd's threads moved to CPU %d "
                    "(%.0f %% busy)", old, 100 * others_share[old], window_s, target, 100 * others_share[target])  # fmt: skip

    def describe(self) -> dict:
        """For the stats file: the setting, the CPU the threads are on (None: the kernel's choice), moves."""
        return {"setting": self.setting, "on": self.cpu, "moves": self.moves}


def current_cpu() -> int | None:
    """The CPU the calling thread is running on (field 39 of /proc/thread-self/stat), or None."""
    try:
        with open("/proc/thread-self/stat", "rb") as file:
            stat = file.read()
        return int(stat[stat.rindex(b")") + 2 :].split()[36])
    except (OSError, ValueError, IndexError):
        return None


def cpu_busy_s(allowed: frozenset[int]) -> dict[int, float]:
    """Busy seconds since boot of each CPU in `allowed` (/proc/stat: all but idle and iowait)."""
    tick_s = 1.0 / os.sysconf("SC_CLK_TCK")
    busy: dict[int, float] = {}
    with open("/proc/stat") as file:
        for line in file:
            if not line.startswith("cpu") or line[3] == " ":
                continue
            name, *ticks = line.split()
            cpu = int(name[3:])
            if cpu in allowed:
                user, nice, system, _idle, _iowait, irq, softirq, steal = (int(tick) for tick in ticks[:8])
                busy[cpu] = (user + nice + system + irq + softirq + steal) * tick_s
    return busy


def threads_on(cpu: int | None) -> list[int]:
    """This process's threads kept on `cpu` alone."""
    tids = []
    for name in os.listdir("/proc/self/task"):
        try:
            if os.sched_getaffinity(int(name)) == {cpu}:
                tids.append(int(name))
        except OSError:
            continue
    return tids


def threads_cpu_s(cpu: int) -> float:
    """CPU seconds so far of this process's threads kept on `cpu` (the scheduler's count, schedstat)."""
    total_ns = 0
    for tid in threads_on(cpu):
        try:
            with open(f"/proc/self/task/{tid}/schedstat") as file:
                total_ns += int(file.read().split()[0])
        except (OSError, ValueError, IndexError):
            continue
    return total_ns / 1e9


def _list(cpus: set[int]) -> str:
    return ",".join(str(cpu) for cpu in sorted(cpus))
