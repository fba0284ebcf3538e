"""Outside the calibrated range: which policy (fogd.core.outside_range) serves held-out runs that leave it best.

Issue 33's real IMU recording was trained on one day of fridge / room cycles and replayed on days that went
beyond them: a third of one replayed period was flagged CLAMPED, and what the model does there decided the result.
This tool makes that situation on simulated physics (fogd-sim's simulator, in memory), where the true thermal
error is known:

- calibration: one run of slow cycles between 10 and 20 C at 5 C/h with 2 h soaks (13 h at 1 Hz, navigation
  noise), seed 1;
- held out (seeds 2-17, each programme twice): the same cycles but leaving the range above (to 20 + m C) or below (to 10 - m C) by
  m = 2, 5 and 10 C at the same 5 C/h; the same range at 20 C/h (the rates leave theirs); and one run inside the
  range (a control: every policy must give the same there);
- for each coil (--thermal lumped, diffusive) and two physics (the sensor on the housing, fogd-sim's default,
  and on a baseplate between the air and the housing, --sensor-on baseplate);
- two models per case: fogd-train's default (the ladder, its swarm small: SWARM) and the ladder's richest rung
  (pso-svr over the lag bank), both fitted once and stored with each policy (`modelfile.from_document`, the file
  the daemon and fogd-replay load);
- each policy scored on each held-out run by its drift (std of 100 s block means after compensation, table 4 of
  `fogd-replay`) as a multiple of the noise floor (the same run with its true thermal error removed), overall
  and on the out-of-range blocks alone (blocks with a CLAMPED sample: their block means' RMS about the run's
  mean, over the floor's on the same blocks).

The verdict compares each policy with the clamp run by run (log of the drift ratio, out-of-range runs only): a
policy replaces the clamp only when its mean gain exceeds its standard error.

    python tools/range_policy.py            # writes docs/results/range.md whole (a few minutes of CPU)
    python tools/range_policy.py --quick    # one case, three held-out runs (smoke test, no page)
    python tools/range_policy.py --calibration day1.csv --held-out day2.csv day3.csv   # recorded runs (no floor)
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from bench_common import results_header, write_results_page

from fogd.calibration.ladder import climb
from fogd.calibration.models import FitOptions
from fogd.calibration.replay import replay, replay_table
from fogd.calibration.training import TrainConfig, train
from fogd.core import modelfile
from fogd.core.flags import Flag
from fogd.core.frozen import FrozenModel
from fogd.core.inputs import DEFAULT_INPUTS_TEXT, parse_inputs
from fogd.core.outside_range import POLICIES
from fogd.core.runio import Run, read_run
from fogd.simulation.profiles import Profile
from fogd.simulation.simulator import params_for, simulate

PAGE = Path(__file__).resolve().parents[1] / "docs" / "results" / "range.md"
RATE_HZ = 1.0
BLOCK_S = 100.0
LOW_C, HIGH_C, MID_C = 10.0, 20.0, 15.0
SLOW_CPH, FAST_CPH = 5.0, 20.0
MARGINS_C = (2.0, 5.0, 10.0)
HELD_OUT_SEEDS = 2  # each held-out programme run with this many seeds
SWARM = dict(particles=8, iterations=10, patience=4)  # the ladder's and pso-svr's swarms, kept small: minutes
PHYSICS = {"sensor on housing": {}, "sensor on baseplate": {"sensor_on": "baseplate"}}
COILS = ("lumped", "diffusive")


def ramp_s(from_c: float, to_c: float, cph: float) -> float:
    return abs(to_c - from_c) / cph * 3600.0


def calibration_profile() -> Profile:
    """13 h of slow cycles inside [LOW_C, HIGH_C]."""
    segments, at = [(600.0, MID_C)], MID_C
    for target in (HIGH_C, LOW_C, HIGH_C, MID_C):
        segments += [(ramp_s(at, target, SLOW_CPH), target), (7200.0, target)]
        at = target
    return Profile("calibration 10-20 C", tuple(segments))


def excursion_profile(peak_c: float, cph: float = SLOW_CPH, name: str = "") -> Profile:
    """From MID_C to `peak_c` and back at `cph`, with soaks: 1 h at the peak, 1.5 h at the end."""
    segments = [(600.0, MID_C), (1800.0, MID_C), (ramp_s(MID_C, peak_c, cph), peak_c), (3600.0, peak_c),
                (ramp_s(peak_c, MID_C, cph), MID_C), (5400.0, MID_C)]  # fmt: skip
    return Profile(name or f"to {peak_c:g} C", tuple(segments))


def fast_profile() -> Profile:
    """The calibrated temperatures at FAST_CPH: the rates leave their range."""
    segments, at = [(600.0, MID_C), (1800.0, MID_C)], MID_C
    for target in (HIGH_C, LOW_C, MID_C):
        segments += [(ramp_s(at, target, FAST_CPH), target), (3600.0, target)]
        at = target
    return Profile(f"10-20 C at {FAST_CPH:g} C/h", tuple(segments))


def held_out_profiles(quick: bool) -> list[tuple[str, Profile]]:
    """(kind, profile): kind 'above', 'below', 'faster' or 'inside'."""
    margins = MARGINS_C[1:2] if quick else MARGINS_C
    runs = [("above", excursion_profile(HIGH_C + m, name=f"above by {m:g} C")) for m in margins]
    runs += [("below", excursion_profile(LOW_C - m, name=f"below by {m:g} C")) for m in margins]
    if not quick:
        runs.append(("faster", fast_profile()))
    runs.append(("inside", excursion_profile(HIGH_C - 1.5, name="inside (to 18.5 C)")))
    return runs


def sim_run(profile: Profile, seed: int, thermal: str, physics: dict) -> Run:
    params = params_for("navigation", thermal, **physics)
    sim = simulate(profile, RATE_HZ, seed, params)
    return Run(f"{profile.name}, seed {seed}", sim.t_s, sim.rate_dph, sim.temp_c, RATE_HZ, "",
               {"true_error_dph": sim.true_error_dph})  # fmt: skip


def fit_options() -> FitOptions:
    return FitOptions(**SWARM, n_jobs=1, progress=False, seed=0)


def trained_documents(run: Run, ladder_only: bool = False) -> dict[str, tuple[str, dict]]:
    """model label -> (what it is, its document with the linear fit stored: policy 'trend')."""
    ladder = climb([run], TrainConfig(fit=fit_options(), outside="trend"))
    if ladder_only:
        return {"default (ladder)": (ladder.chosen.rung.name, ladder.trained.document)}
    svr = train([run], TrainConfig(method="pso-svr", inputs=parse_inputs(DEFAULT_INPUTS_TEXT), fit=fit_options(),
                                   outside="trend"))  # fmt: skip
    return {"default (ladder)": (ladder.chosen.rung.name, ladder.trained.document),
            "lag bank + SVR": ("pso-svr " + DEFAULT_INPUTS_TEXT, svr.document)}  # fmt: skip


def with_policy(document: dict, policy: str) -> modelfile.FrozenModel:
    """The model as the daemon and fogd-replay load it, with `policy` beyond its calibrated range."""
    doc = copy.deepcopy(document)
    stored = doc.pop("outside_range")
    if policy in ("trend", "linear"):
        doc["outside_range"] = {**stored, "policy": policy}
    elif policy != "clamp":
        doc["outside_range"] = {"policy": policy}
    return modelfile.from_document(doc)


REFERENCE = "unclamped"  # the model evaluated beyond its domain as it is: a reference, not a policy


def unclamped(model: FrozenModel) -> FrozenModel:
    d = len(model.inputs)
    return dataclasses.replace(model, domain_min=np.full(d, -np.inf), domain_max=np.full(d, np.inf), outside=None)


@dataclass
class Score:
    overall: float  # drift / floor (or in the run's unit without a floor)
    outside: float  # the same on the out-of-range blocks (NaN when none)
    clamped_share: float
    before: float  # the uncompensated drift, the same way


def scores(models: dict[str, FrozenModel], run: Run) -> dict[str, Score]:
    """Each model's drift on `run` (std of 100 s block means), overall and on the blocks with a CLAMPED sample
    (their block means' RMS about the run's mean), over the noise floor's (the run with its true thermal error
    removed) when the run has one. The blocks are the clamp's (every policy flags the same samples)."""
    results = {name: replay(model, run) for name, model in models.items()}
    flags = results["clamp"].flags
    grid = replay_table(run, results["clamp"], BLOCK_S).grid
    out = grid.means(((flags & Flag.CLAMPED) != 0).astype(np.float64)) > 0
    truth = run.extra.get("true_error_dph")
    best = None if truth is None else grid.means(run.rate_dph - truth)

    def rms(means: np.ndarray, rows: np.ndarray) -> float:
        return float(np.sqrt(np.mean((means[rows] - means.mean()) ** 2))) if rows.any() else math.nan

    every = np.ones(out.size, dtype=bool)
    floor = (1.0, 1.0) if best is None else (rms(best, every), rms(best, out))
    before = grid.means(run.rate_dph)
    share = float(np.mean((flags[grid.rows] & Flag.CLAMPED) != 0))
    return {name: Score(rms(grid.means(result.rate_comp_dph), every) / floor[0],
                        rms(grid.means(result.rate_comp_dph), out) / floor[1], share,
                        rms(before, every) / floor[0])
            for name, result in results.items()}  # fmt: skip


def _mean_error(logs: np.ndarray) -> tuple[float, float]:
    return float(logs.mean()), (float(logs.std(ddof=1) / math.sqrt(len(logs))) if len(logs) > 1 else math.inf)


def verdict(rows: list[dict]) -> tuple[str, list[str]]:
    """The policy chosen and the table's lines. On the runs that leave the range, each policy's log drift ratio
    to the clamp's on the out-of-range blocks; the best policy by its mean; chosen: the first of POLICIES
    (the clamp, then the simpler) whose paired difference to the best is within one standard error, the clamp
    only if no policy beats it by more than its standard error."""
    leaving = [r for r in rows if r["kind"] != "inside" and math.isfinite(r["clamp"].outside)]
    logs = {p: np.array([math.log(r[p].outside / r["clamp"].outside) for r in leaving]) for p in POLICIES}
    best = min(POLICIES, key=lambda p: logs[p].mean())
    lines = ["| policy | runs | mean log(drift / clamp's) | standard error | geometric mean ratio to the clamp "
             "| mean log(drift / best's) | standard error |", "|---|---:|---:|---:|---:|---:|---:|"]  # fmt: skip
    chosen = None
    for policy in POLICIES:
        mean, error = _mean_error(logs[policy])
        to_best, to_best_error = _mean_error(logs[policy] - logs[best]) if policy != best else (0.0, 0.0)
        lines.append(f"| {policy} | {len(leaving)} | {mean:+.3f} | {error:.3f} | {math.exp(mean):.3f} | "
                     f"{to_best:+.3f} | {to_best_error:.3f} |")  # fmt: skip
        if chosen is None and to_best - to_best_error <= 0:
            chosen = policy
    best_mean, best_error = _mean_error(logs[best])
    if best == "clamp" or best_mean + best_error >= 0:
        chosen = "clamp"
    return chosen, lines


def by_kind(rows: list[dict]) -> list[str]:
    """Geometric means by kind of held-out run, overall | out-of-range blocks."""
    names = [*POLICIES, REFERENCE]
    lines = ["| held-out runs | runs | before | " + " | ".join(names) + " |", "|---|---:|---:|" + "---:|" * len(names)]
    for kind in ("above", "below", "faster", "inside", "all"):
        chosen = [r for r in rows if kind in (r["kind"], "all")]
        if not chosen:
            continue
        geo = lambda values: math.exp(np.mean(np.log(values))) if values else math.nan  # noqa: E731
        cell = lambda name: " \\| ".join(  # noqa: E731
            "-" if not math.isfinite(value) else f"{value:.2f}" for value in (
                geo([r[name].overall for r in chosen]),
                geo([r[name].outside for r in chosen if math.isfinite(r[name].outside)])))  # fmt: skip
        before = geo([r["clamp"].before for r in chosen])
        lines.append(f"| {kind} | {len(chosen)} | {before:.2f} | " + " | ".join(cell(name) for name in names) + " |")
    return lines


def recorded(calibration: str, held_out: list[str]) -> int:
    """The policies on recorded runs: the default trained on `calibration`, each held-out run replayed."""
    document = trained_documents(read_run(calibration), ladder_only=True)["default (ladder)"][1]
    models = {policy: with_policy(document, policy) for policy in POLICIES}
    models[REFERENCE] = unclamped(models["clamp"])
    print(f"| held-out run | CLAMPED | before | {' | '.join(models)} |  (drift, std of 100 s block means, overall | "
          "out-of-range blocks, in the run's unit)")  # fmt: skip
    for path in held_out:
        run = read_run(path)
        row = scores(models, run)
        cells = " | ".join(f"{s.overall:.3e} \\| {s.outside:.3e}" for s in row.values())
        print(f"| {path} | {row['clamp'].clamped_share:.0%} | {row['clamp'].before:.3e} | {cells} |", flush=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="one case, three held-out runs; no page")
    parser.add_argument("--calibration", metavar="RUN.csv", help="a recorded calibration run (its primary channel): "
                        "train the default on it and print each policy on the --held-out runs (no page)")
    parser.add_argument("--held-out", nargs="+", default=[], metavar="RUN.csv", help="recorded runs to replay")
    args = parser.parse_args(argv)
    if args.calibration:
        return recorded(args.calibration, args.held_out)
    argv = sys.argv[1:] if argv is None else argv
    header = results_header("Outside the calibrated range (tools/range_policy.py)",
                            ["python", "tools/range_policy.py", *argv],
                            f"1 Hz, navigation noise; swarms {SWARM['particles']} x {SWARM['iterations']}, "
                            f"stopping after {SWARM['patience']} still iterations")  # fmt: skip
    cases = [(coil, name) for coil in COILS for name in PHYSICS]
    if args.quick:
        cases = cases[:1]
    started, cpu_started = time.perf_counter(), time.process_time()
    rows: list[dict] = []
    names = [*POLICIES, REFERENCE]
    body = ["Each cell: held-out drift (std of 100 s block means) / the noise floor (the same run with its true "
            "thermal error removed), overall | on the out-of-range blocks alone (blocks with a CLAMPED sample: "
            "their means' RMS about the run's mean, over the floor's on the same blocks). `CLAMPED`: the share of "
            "the run's samples flagged (every policy flags the same ones); `before`: no compensation; "
            f"`{REFERENCE}`: the model evaluated beyond its domain as it is (a reference: fogd-sim's static error "
            "is the cubic the coil trend fits, a real gyro's need not be).", ""]  # fmt: skip
    for coil, physics_name in cases:
        physics = PHYSICS[physics_name]
        calibration = sim_run(calibration_profile(), 1, coil, physics)
        documents = trained_documents(calibration)
        programmes = held_out_profiles(args.quick)
        held = [(kind, sim_run(profile, 2 + k + len(programmes) * repeat, coil, physics))
                for repeat in range(1 if args.quick else HELD_OUT_SEEDS)
                for k, (kind, profile) in enumerate(programmes)]  # fmt: skip
        for label, (what, document) in documents.items():
            models = {policy: with_policy(document, policy) for policy in POLICIES}
            models[REFERENCE] = unclamped(models["clamp"])
            body += [f"### {coil} coil, {physics_name}: {label} ({what})", "",
                     "| held-out run | CLAMPED | before | " + " | ".join(names) + " |",
                     "|---|---:|---:|" + "---:|" * len(names)]  # fmt: skip
            for kind, run in held:
                row = scores(models, run)
                rows.append({"kind": kind, **row})
                cells = [f"{s.overall:.2f} \\| {s.outside:.2f}" if math.isfinite(s.outside) else f"{s.overall:.2f} \\| -"
                         for s in row.values()]  # fmt: skip
                body.append(f"| {run.path} | {row['clamp'].clamped_share:.0%} | {row['clamp'].before:.2f} | "
                            + " | ".join(cells) + " |")  # fmt: skip
                print(f"{coil}, {physics_name}, {label}, {run.path}: "
                      + ", ".join(f"{p} {s.overall:.2f}/{s.outside:.2f}" for p, s in row.items()), flush=True)
            body.append("")
    chosen, lines = verdict(rows)
    kinds = by_kind(rows)
    elapsed = (f"{time.perf_counter() - started:.0f} s wall, {time.process_time() - cpu_started:.0f} s CPU "
               "(a loaded, shared machine)")  # fmt: skip
    summary = ["## Verdict", "",
               "On the out-of-range blocks of every held-out run that leaves the range (above, below, faster; both "
               "models of every case, paired run by run against the clamp), the chosen policy is "
               f"**{chosen}**: the first of {', '.join(POLICIES)} within one standard error of the best, the clamp "
               f"unless the best beats it by more than its standard error. Measured in {elapsed}.", "",
               *lines, "", "Geometric means by kind of held-out run (drift / noise floor, overall | out-of-range "
               "blocks):", "", *kinds, "", "## Per case", ""]  # fmt: skip
    print("\n".join(lines + [""] + kinds), flush=True)
    print(f"chosen: {chosen}; {elapsed}", flush=True)
    if not args.quick:
        write_results_page(PAGE, header, "\n".join(summary + body))
        print(f"wrote {PAGE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
