"""How well can any causal compensator do with a whole-degree temperature? A lower bound on the held-out runs.

After a soak the chamber starts to move and the gyro's thermal error follows the housing at once, but a sensor
that reports whole degrees shows nothing until its element has moved half a degree. For each start of a ramp
after a soak this tool simulates three histories of the same held-out run with the same seed (so the same gyro
and sensor noise draws): the programme as it is (`up`, whichever way it goes), the same programme mirrored about
the soak's temperature from that point on (`down`: every later target t becomes 2 x soak - t), and the soak held
to the end (`soak`). All three start soaked at a whole degree and read the same until one of them changes its
reading; a compensator that sees only the readings (and its own past) gives them the same output for as long as
their readings agree. On the built-in held-out runs, both coils, `up` and `down` change their readings within a
few seconds of each other (the sensor's noise draws are the same, so not exactly together) and the soak not at
all: the tool prints both blind spans.

The minimax estimate. At each instant t after the ramp's start, let m_h(t) be how far history h's true error
has moved since the start, over the histories h whose readings so far are the actual run's. A compensator gives
one estimate c(t) for all of them; its worst error over them is max_h |c(t) - m_h(t)|, smallest at the midpoint
of the extremes, c = (max_h m_h + min_h m_h) / 2, where it is half their spread. The soak's error does not
move (m = 0), and the mirrored ramp moves it by the opposite amount to within the static curve's curvature over
half a degree (the tool prints both moves and how far from opposite they are: under 0.1 % on the built-in
runs). So while all three agree c is about 0 and the error left on the actual run is about m_up(t): the WHOLE
move, not half. (Hedging between `soak` and `up` alone, as this tool once did, puts c at m/2 and halves the
error; on the mirrored history, which reads the same, that guess errs by 3m/2.) Once the mirrored run's
reading has changed and the actual's not yet, `down` is ruled out and c is m/2 until the actual reading changes;
after that no other history is left and the ideal is exact. The tool uses c as computed from the three
simulated histories, row by row.

The bound is the accuracy table's metric (std of 100 s block means after 600 s, over the noise floor: the same
run with its true error removed) for an ideal compensator that is exact everywhere except in the blind windows,
where it gives the minimax estimate. It is a floor in the minimax sense instant by instant: a compensator that
does better in a window on the actual run does worse there on the mirrored one, which it cannot tell apart.
Two things keep it from being a strict per-run bound on the score: the run's own gyro noise in the window's
blocks can add to the move or cancel part of it, and after the window the ideal is exact, which no compensator
is (it learns the direction from the first change but not the pace); the second makes the bound kinder, not
harsher.

    python tools/quantisation_bound.py                   # whole degrees at 1 Hz, both coil structures
    python tools/quantisation_bound.py --resolution-c 0.0625 --sensor-hz 4   # a fine sensor, for contrast
    python tools/quantisation_bound.py --physics sensor_on=baseplate          # another simulated gyro
    python tools/quantisation_bound.py --hindsight       # and the default fitted on the held-out runs too

`--hindsight` separates the two gaps between the default and the bound: fogd-train's default trained on the
calibration runs and on the held-out runs themselves shows what its inputs can carry when the fit has seen
every history; what is left above the bound then is the inputs' (the dequantised estimate's), not the fit's.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass

import numpy as np

from fogd.calibration.replay import block_grid
from fogd.core.columns import BLOCK_S, TRUE_ERROR_COLUMN
from fogd.core.errorstats import detrended_stats
from fogd.core.runio import Run
from fogd.simulation.profiles import Profile, builtin
from fogd.simulation.simulator import SimRun, params_for, simulate

CALIBRATION = ("paper-train", "cooling", "cycle")  # as accuracy_table.py
HELD_OUT = ("paper-test", "cool-40-to-0", "fast-ramp", "soak-after-ramp", "fast-cycle")
THERMALS = ("lumped", "diffusive")


def ramp_starts(profile: Profile) -> list[tuple[int, float]]:
    """(index of the ramp's segment, its start time in s) for each time the setpoint starts to move after holding still."""
    targets = [profile.start_c] + [target for _, target in profile.segments]
    knots_s = np.cumsum([0.0] + [duration for duration, _ in profile.segments])
    return [(k, float(knots_s[k])) for k in range(1, len(targets) - 1)
            if targets[k] == targets[k - 1] and targets[k + 1] != targets[k]]  # fmt: skip


def mirrored(profile: Profile, segment: int) -> Profile:
    """`profile` with every target from segment `segment` on mirrored about the soak before it: the same
    programme going the other way."""
    soak_c = profile.segments[segment - 1][1]
    later = tuple((duration, 2.0 * soak_c - target) for duration, target in profile.segments[segment:])
    return Profile(f"{profile.name}-mirrored", profile.segments[:segment] + later)


def soak_held(profile: Profile, segment: int) -> Profile:
    """`profile` whose soak before segment `segment` goes on to the end of the run."""
    rest_s = sum(duration for duration, _ in profile.segments[segment:])
    return Profile(f"{profile.name}-soak-held", profile.segments[:segment] + ((rest_s, profile.segments[segment - 1][1]),))


@dataclass(frozen=True)
class BlindWindow:
    """One blind window of a run: where it starts and ends (rows), each history's first change of reading, and
    the minimax estimate's error on the actual run."""

    start: int
    stop: int  # first row at which no other history reads as the actual one does
    up_blind_s: float  # the actual run's reading first changes this long after the start
    down_blind_s: float  # the mirrored run's
    up_moved_dph: float  # the true error's move at the window's last row, actual run
    down_moved_dph: float  # the same, mirrored run
    asymmetry: float  # max |m_up + m_down| over the window / max |m_up|: 0 when the moves are exactly opposite
    residual_dph: np.ndarray  # m_up - c over the window: what the minimax estimate leaves on the actual run


def first_change(temp_c: np.ndarray, start: int) -> int:
    """First row at or after `start` whose reading differs from the reading at `start` (the run's end if none)."""
    changed = np.flatnonzero(temp_c[start:] != temp_c[start])
    return start + int(changed[0]) if changed.size else temp_c.size


def blind_window(up: SimRun, down: SimRun, soak: SimRun, start: int) -> BlindWindow:
    """The window from row `start` over which another history still reads as the actual one (`up`) does, and the
    minimax estimate in it: at each row, over the histories whose readings so far are the actual run's."""
    same_before = np.array_equal(up.temp_c[:start], down.temp_c[:start]) and np.array_equal(up.temp_c[:start], soak.temp_c[:start])
    if not same_before:
        raise AssertionError("the three histories differ before their ramp: the simulator's draws depend on the programme")
    others = (down, soak)
    # a history stays possible up to (not including) the first row at which its reading is not the actual one's
    possible_until = [first_difference(up.temp_c, other.temp_c, start) for other in others]
    stop = max(possible_until)
    moves = np.array([run.true_error_dph[start:stop] - run.true_error_dph[start] for run in (up, *others)])
    rows = np.arange(start, stop)
    possible = np.array([np.ones(rows.size, dtype=bool)] + [rows < until for until in possible_until])
    highest = np.where(possible, moves, -np.inf).max(axis=0)
    lowest = np.where(possible, moves, np.inf).min(axis=0)
    minimax = (highest + lowest) / 2.0  # the midpoint of the extremes, at each instant
    up_moved, down_moved = moves[0], moves[1]
    largest = float(np.max(np.abs(up_moved))) if stop > start else 0.0
    rate_hz = up.rate_hz
    return BlindWindow(
        start, stop, (first_change(up.temp_c, start) - start) / rate_hz, (first_change(down.temp_c, start) - start) / rate_hz,
        float(up_moved[-1]) if stop > start else 0.0, float(down_moved[-1]) if stop > start else 0.0,
        float(np.max(np.abs(up_moved + down_moved))) / largest if largest > 0 else 0.0, up_moved - minimax,
    )  # fmt: skip


def first_difference(temp_c: np.ndarray, other_c: np.ndarray, start: int) -> int:
    """First row at or after `start` where two histories' readings differ (the run's end if none)."""
    differ = np.flatnonzero(temp_c[start:] != other_c[start:])
    return start + int(differ[0]) if differ.size else temp_c.size


def run_bounds(thermal: str, resolution_c: float, sensor_hz: float, rate_hz: float, seed: int,
               rows: list[str] | None = None, **overrides: float) -> list[float]:
    """The bound (drift / noise floor of the ideal compensator) on each of HELD_OUT, simulated as
    `tools/accuracy_table.py` simulates them; a table row per blind window is appended to `rows` if given."""
    params = params_for("navigation", thermal, sensor_resolution_c=resolution_c, sensor_rate_hz=sensor_hz, **overrides)
    return [profile_bound(builtin(name), rate_hz, seed + 100 + number, params, rows, thermal)
            for number, name in enumerate(HELD_OUT)]  # fmt: skip


def profile_bound(profile: Profile, rate_hz: float, seed: int, params, rows: list[str] | None = None,
                  label: str = "") -> float:
    """The bound on one run: the accuracy table's metric of the ideal compensator over the run's noise floor."""
    run = simulate(profile, rate_hz, seed, params)
    # the accuracy table's metric on its grid: 100 s block means after the settling, about their mean
    grid = block_grid(Run(profile.name, run.t_s, run.rate_dph, run.temp_c, rate_hz, "", {}),
                      np.zeros(run.t_s.size, dtype=np.uint16), BLOCK_S)  # fmt: skip

    def drift(values: np.ndarray) -> float:
        return detrended_stats(grid.means(values)).rmse_dph

    floor = drift(run.rate_dph - run.true_error_dph)
    residual_dph = np.zeros(run.t_s.size)  # what the ideal compensator leaves: nothing outside the blind windows
    for segment, start_s in ramp_starts(profile):
        start = int(round(start_s * rate_hz))
        down = simulate(mirrored(profile, segment), rate_hz, seed, params)
        soak = simulate(soak_held(profile, segment), rate_hz, seed, params)
        window = blind_window(run, down, soak, start)
        residual_dph[window.start : window.stop] = window.residual_dph
        if rows is not None:
            worst = float(np.max(np.abs(window.residual_dph))) if window.residual_dph.size else 0.0
            rows.append(f"| {label} | {profile.name} | {start_s:.0f} s | {window.up_blind_s:.0f} s | "
                        f"{window.down_blind_s:.0f} s | {window.up_moved_dph * 1e3:+.2f} | {window.down_moved_dph * 1e3:+.2f} | "
                        f"{window.asymmetry * 100:.2f} % | {worst / floor:.1f} |")  # fmt: skip
    return drift(run.rate_dph - run.true_error_dph + residual_dph) / floor


def hindsight_fit(thermal: str, resolution_c: float, sensor_hz: float, rate_hz: float, seed: int) -> list[float]:
    """fogd-train's default (its inputs dequantised for a coarse sensor, PSO 10 x 10) trained on the accuracy
    table's calibration runs and on the held-out runs themselves, then replayed on the held-out runs: what the
    default's inputs can carry of the error when the fit has seen every history. Where it stays far above the
    bound, the inputs (the dequantised estimate), not the choice of calibration runs, hold the run there."""
    from fogd.calibration.models import FitOptions
    from fogd.calibration.replay import replay, replay_table
    from fogd.calibration.training import TrainConfig, train

    params = params_for("navigation", thermal, sensor_resolution_c=resolution_c, sensor_rate_hz=sensor_hz)
    named = [(name, seed + i) for i, name in enumerate(CALIBRATION)] + [(name, seed + 100 + i) for i, name in enumerate(HELD_OUT)]
    runs = []
    for name, run_seed in named:
        sim = simulate(builtin(name), rate_hz, run_seed, params)
        runs.append(Run(f"{name}.csv", sim.t_s, sim.rate_dph, sim.temp_c, rate_hz, f"{name}-{run_seed}",
                        {TRUE_ERROR_COLUMN: sim.true_error_dph}))  # fmt: skip
    options = FitOptions(particles=10, iterations=10, n_jobs=1, seed=seed, progress=False)
    trained = train(runs, TrainConfig(fit=options))
    tables = [replay_table(run, replay(trained.model, run), BLOCK_S) for run in runs[len(CALIBRATION):]]
    return [table.after.rmse_dph / table.best.rmse_dph for table in tables]


def physics_setting(text: str) -> tuple[str, float | int | str]:
    """--physics KEY=VALUE, parsed as tools/accuracy_table.py parses it."""
    from accuracy_table import physics_setting as parse  # tools/, beside this file

    return parse(text)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--resolution-c", type=float, default=1.0, help="sensor resolution, C (default 1: a KVH)")
    parser.add_argument("--sensor-hz", type=float, default=1.0, help="sensor report rate, Hz (default 1)")
    parser.add_argument("--rate-hz", type=float, default=10.0, help="simulated gyro rate, Hz (default 10)")
    parser.add_argument("--seed", type=int, default=1, help="seed of the first held-out run, +100 as accuracy_table.py")
    parser.add_argument("--hindsight", action="store_true",
                        help="also fogd-train's default fitted on the held-out runs themselves (hindsight_fit; ~1 min)")
    parser.add_argument("--physics", type=physics_setting, action="append", metavar="KEY=VALUE",
                        help="another simulated gyro, as tools/accuracy_table.py's --physics (repeatable)")
    args = parser.parse_args()
    overrides = dict(args.physics or [])
    shown = "".join(f", {key} {value}" for key, value in overrides.items())
    print(f"# sensor {args.resolution_c:g} C at {args.sensor_hz:g} Hz; navigation-grade gyro, {args.rate_hz:g} Hz, "
          f"seed {args.seed}{shown}\n")  # fmt: skip
    rows: list[str] = []
    bounds = {thermal: run_bounds(thermal, args.resolution_c, args.sensor_hz, args.rate_hz, args.seed, rows, **overrides)
              for thermal in THERMALS}  # fmt: skip
    print("Blind windows: the actual run (up) and its mirror (down) read the same as the soak held until the first\n"
          "change; the true error's move at the window's end (mdeg/h), how far from opposite the two moves are, and\n"
          "the largest error the minimax estimate leaves in the window, over the noise floor.\n")
    print("| coil | run | ramp starts at | up blind for | down blind for | up moved | down moved | "
          "not opposite by | left x noise floor |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|")
    print("\n".join(rows))
    print("\nLower bound on held-out drift / noise floor (" + ", ".join(HELD_OUT) + "):")
    for thermal, values in bounds.items():
        print(f"  {thermal:9s} " + " / ".join(f"{value:.2f}" for value in values) + f"   (worst {max(values):.2f})")
    if args.hindsight:
        print("\nfogd-train's default fitted with hindsight (calibration and held-out runs), on the held-out runs:")
        for thermal in THERMALS:
            values = hindsight_fit(thermal, args.resolution_c, args.sensor_hz, args.rate_hz, args.seed)
            print(f"  {thermal:9s} " + " / ".join(f"{value:.2f}" for value in values) + f"   [hindsight worst {max(values):.2f}]",
                  flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
