"""`fogd-train`: fit a temperature-error model from thermal-chamber runs and write the model file."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Sequence

from fogd.calibration.channels import (
    ChannelFit,
    ChannelJob,
    Settings,
    channel_jobs,
    fit_channels,
    unit_document,
)
from fogd.calibration.ladder import RUNGS
from fogd.calibration.models import FITNESSES, METHODS, FitOptions
from fogd.calibration.models.coil import MIXES, PRIORS, SIGNED_MIX_GAIN
from fogd.calibration.models.least_squares import POLY_TERMS
from fogd.calibration.models.svr import TRENDS
from fogd.calibration.runcheck import check_calibration_run
from fogd.calibration.selection import (
    AUTO_ITERATIONS,
    AUTO_PARTICLES,
    DEFAULT_INPUT_SETS,
    input_sets,
)
from fogd.calibration.training import TrainConfig
from fogd.calibration.units import Unit, read_manifest
from fogd.cli.common import ArgumentParser, DefaultsHelpFormatter, run
from fogd.core import modelfile
from fogd.core.atomic import check_output, check_output_directory
from fogd.core.columns import BLOCK_S, CHANNELS, FIT_BLOCK_S, channel_unit
from fogd.core.estimator import EstimatorSettings
from fogd.core.inputs import (
    DEFAULT_INPUTS_TEXT,
    INPUTS_SYNTAX,
    default_inputs,
    parse_inputs,
    warmup_samples,
)
from fogd.core.numbers import non_negative_float, positive_float, positive_int
from fogd.core.outside_range import DEFAULT_POLICY as DEFAULT_OUTSIDE_POLICY
from fogd.core.outside_range import POLICIES as OUTSIDE_POLICIES
from fogd.core.runio import read_run
from fogd.errors import (
    FogdError,
    InputError,
    UsageError,
)

PROG = "fogd-train"
LADDER_PARTICLES = 20  # the ladder's swarms (one per held-out fold, and the final fit's if the SVR is chosen)
EARLY_STOP = 10  # iterations without improvement; bench_train.py measures what it costs against the paper's swarm


def parser() -> ArgumentParser:
    p = ArgumentParser(
        prog=PROG,
        description="Fit a FOG temperature-error model f(T, dT/dt) from thermal-chamber runs "
        "(CSV t_s,rate_dph,temp_c) and write it as a JSON model file for fogd and fogd-replay. Runs of an IMU "
        f"(t_s, any of {','.join(CHANNELS)}, temp_c) give a model per channel, fitted in parallel (--jobs), in "
        "one model file.",
        epilog="Examples: fogd-train cal_heat.csv cal_cool.csv -o model.json --report report/; "
        "fogd-train --manifest units.yaml --jobs 4 (a production line: units: [{name, runs, channels?, holdout?, "
        "out?}, ...], one model file per unit)",
        formatter_class=DefaultsHelpFormatter,
    )
    p.add_argument("runs", nargs="*", metavar="RUN.csv", help="calibration runs; blocks never straddle two runs")
    p.add_argument("-o", "--output", metavar="MODEL.json",
                   help="model file to write (required unless --compare); with --manifest, the directory for the "
                   "units' <name>.json (default: beside the manifest)")  # fmt: skip
    p.add_argument("--channels", metavar="LIST",
                   help="IMU runs: the channels to fit, comma-separated (default: every channel the runs have; "
                   "the others are passed through by fogd-replay and fogd)")  # fmt: skip
    p.add_argument("--manifest", metavar="UNITS.yaml",
                   help="train every unit of a manifest, each into its own model file, in parallel (--jobs): "
                   "units: a list of {name, runs, channels (optional), holdout (optional), out (optional)}, "
                   "paths relative to the manifest")  # fmt: skip
    p.add_argument(
        "--method", choices=("ladder", *METHODS, "auto"), default=None,
        help="model family (default: ladder; pso-svr when --inputs or --compare is given); ladder: the simplest of no compensation, linear [temp,rate@50] (IEEE 952), its "
        "static curve, the coil trend over the lag bank and that trend under PSO-SVR that improves on every simpler "
        "one and whose held-out drift is within one standard error of the best's, compared fold by fold by their ratio (no compensation only when it is "
        "the best: a channel no model improves is passed through, with a warning when nothing is compensated) (leave-one-run-out with three runs or more, else --folds time folds of every run, a lag "
        "apart; it says "
        "what it chose and why in one line, and the model file keeps the estimate); auto: choose the family and the input set by nested held-out error (leave-one-run-out, "
        "or blocked time folds for one run; each family tuned without the fold it is scored on) among linear, "
        "ls-poly, rbf-nn, pso-svr on the --auto-inputs sets",
    )  # fmt: skip
    p.add_argument(
        "--inputs", metavar="LIST", default=None,
        help=f"model inputs (default {DEFAULT_INPUTS_TEXT}: the sensor temperature, a bank of lags spanning the "
        "thermal range and the play operator for the gyro's hysteresis; from a coarse sensor's dequantised "
        "temperature; 'paper' is "
        f"the paper's temp,rate@WINDOW_S): {INPUTS_SYNTAX}",
    )  # fmt: skip
    p.add_argument(
        "--auto-inputs", metavar="LIST", action="append",
        help="an input set for --method auto (repeat the option for several; default: "
        + " | ".join(DEFAULT_INPUT_SETS) + ")",
    )  # fmt: skip
    p.add_argument(
        "--domain-guard", action=argparse.BooleanOptionalAction, default=False,
        help="store a domain guard: samples outside the calibration data are flagged OUT_OF_DOMAIN and "
        "compensated by a linear fallback. With a lag bank or a play input it guards the calibrated range "
        "(temperatures beyond the calibration runs' by more than a margin); with the paper's inputs, the "
        "joint space of temperature and rates (samples far from every calibration block). Off by default: "
        "a sample outside the calibration data gets --outside-range's policy",
    )  # fmt: skip
    p.add_argument(
        "--outside-range", choices=OUTSIDE_POLICIES, default=DEFAULT_OUTSIDE_POLICY,
        help="what the model gives for inputs beyond the calibrated range (stored in the model file, so the daemon "
        "and fogd-replay do the same; the sample is flagged CLAMPED whatever the policy): 'trend' (the model at "
        "the range's edge continued along the slope of the linear fit to the same runs), 'clamp' (the model at "
        "the edge), 'linear' (the linear fit itself), 'edge' (the model at the edge continued along its own "
        f"slope there) (default: {DEFAULT_OUTSIDE_POLICY}, measured in docs/results/range.md)",
    )  # fmt: skip
    p.add_argument(
        "--force", action="store_true",
        help="write a --method model even when its held-out error exceeds the uncompensated drift",
    )  # fmt: skip
    p.add_argument(
        "--fitness", choices=FITNESSES, default="cv",
        help="PSO fitness: cv = RMSE on held-out folds (leave-one-run-out, or blocked in time for one run); "
        "train = the paper's RMSE on the training data",
    )  # fmt: skip
    p.add_argument(
        "--trend", choices=TRENDS, default="coil",
        help="pso-svr: fit the SVR on top of a least-squares trend with one offset per run: 'coil' (every input "
        "linear plus powers up to 3 of one coil temperature, a fitted weighted mean of the temperature inputs: "
        "the static nonlinearity), 'poly' (powers up to 3 of each temperature that follows the coil), "
        "'linear' (IEEE 952), or 'none' for the paper's plain SVR (default coil)",
    )  # fmt: skip
    p.add_argument(
        "--coil-mix", choices=MIXES, default="auto",
        help="the coil trend's coil temperature over the temperature inputs: 'mean' (a weighted mean: a layer "
        "that follows the sensor through one lag), 'signed' (weights of either sign summing to 1: a layer deep in "
        "the coil, behind a chain of lags), or 'auto' (the signed mix where it leaves "
        f"{SIGNED_MIX_GAIN * 100:g} %% less residual on the calibration blocks, else the mean)",
    )  # fmt: skip
    p.add_argument(
        "--rate-prior", choices=PRIORS, default="smooth",
        help="the coil trend's lag coefficients: 'smooth' (a prior that they vary smoothly along the bank as "
        "rates, its strength the calibration blocks' most likely) or 'none' (plain least squares)",
    )  # fmt: skip
    p.add_argument("--particles", type=positive_int, default=None,
                   help=f"PSO population (default {LADDER_PARTICLES} in the ladder, 60 as the paper with --method pso-svr, "
                   f"{AUTO_PARTICLES} inside --method auto)")  # fmt: skip
    p.add_argument("--iterations", type=positive_int, default=None,
                   help=f"PSO iterations at most (default 100 as the paper; {AUTO_ITERATIONS} inside --method auto)")
    p.add_argument("--early-stop", type=int, default=EARLY_STOP, metavar="N",
                   help="stop a swarm when its best fitness has not improved by 0.1 %% for N iterations; 0: never (the "
                   "paper's swarm: --particles 60 --iterations 100 --early-stop 0)")  # fmt: skip
    p.add_argument("--c1", type=non_negative_float, default=2.0, help="PSO cognitive learning factor")
    p.add_argument("--c2", type=non_negative_float, default=2.0, help="PSO social learning factor")
    p.add_argument("--folds", type=positive_int, default=5, help="blocked time folds for cv with a single run")
    p.add_argument("--jobs", type=int, default=1,
                   help="joblib workers (-1: all cores): one per channel or unit when there are several (the active "
                   "joblib backend, e.g. Dask), else evaluating one swarm's particles")  # fmt: skip
    p.add_argument("--seed", type=int, default=0, help="random seed (PSO, k-means)")
    p.add_argument("--degree", type=positive_int, default=5, help="ls-poly order (paper: 5)")
    p.add_argument(
        "--poly-terms", choices=POLY_TERMS, default="full",
        help="ls-poly terms: 'full' every monomial up to --degree (the paper's); 'temp' powers of each temperature "
             "input (temp, lag@) up to --degree and the rate inputs linear, no cross terms (IEEE 952's model with "
             "a polynomial static term)",
    )  # fmt: skip
    p.add_argument("--window-s", type=positive_float, default=50.0, help="eq. 16 window N, in seconds, of --inputs paper")
    p.add_argument("--average-s", type=positive_float, default=0.5, help="eq. 16 averaging window m, in seconds")
    p.add_argument("--step-s", type=non_negative_float, default=0.0, help="eq. 16 step l, in seconds (0: every sample)")
    p.add_argument("--block-s", type=positive_float, default=FIT_BLOCK_S,
                   help=f"block length of the fit's targets, in seconds (the held-out tables' blocks are {BLOCK_S:g} s)")
    p.add_argument(
        "--reference", default="mean",
        help="rate subtracted to get the error: 'mean' of the training blocks, or a value in deg/h",
    )  # fmt: skip
    p.add_argument(
        "--sensor-resolution-c", type=non_negative_float, default=None, metavar="C",
        help="the temperature sensor's resolution (default: seen in the runs); from 0.5 C (a KVH's whole degrees) "
             "the inputs are computed from a dequantised temperature, which the model file keeps; 0: never",
    )  # fmt: skip
    p.add_argument(
        "--sensor-noise-c", type=non_negative_float, default=None, metavar="C",
        help="a fine sensor's own noise (standard deviation, C) for its undithered temperature (fogd.core.undither: "
             "the flicker of its readings between two steps tells where between them the temperature is), the "
             "inputs of a lag bank computed from it (default: chosen on the runs, or the readings if no noise "
             "leaves 1 %% less residual); 0: the readings as they are",
    )  # fmt: skip
    p.add_argument(
        "--fit-temperature", choices=("smoothed", "causal"), default="smoothed",
        help="a dequantised temperature's inputs are fitted from its offline estimate, forwards and backwards in "
             "time (smoothed: the causal estimate's lag behind a ramp is not learnt as physics) or as the daemon "
             "computes them (causal); the daemon always computes them causally",
    )  # fmt: skip
    p.add_argument("--name", help="model name recorded in the file and in the daemon's status")
    p.add_argument("--compare", action="store_true", help="fit every method and print the paper's table 3")
    p.add_argument("--holdout", nargs="+", default=[], metavar="RUN.csv", help="runs not used for training: table 4 each")
    p.add_argument("--report", metavar="DIR", help="write figures (PNG) and a markdown summary to DIR")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    return p


def body(argv: Sequence[str] | None) -> int:
    args = parser().parse_args(argv)
    args.method = args.method or ("pso-svr" if args.inputs or args.compare else "ladder")
    units = _units(args)
    for unit in units:  # before minutes of fitting, not after
        if unit.out:
            check_output(unit.out, [*unit.runs, *unit.holdout])
    if args.report:
        check_output_directory(args.report)
    auto = args.method == "auto"
    ladder = args.method == "ladder"
    if args.early_stop < 0:
        raise UsageError(f"--early-stop {args.early_stop}: give a number of iterations, or 0 for never")
    try:
        estimator = EstimatorSettings(args.window_s, args.average_s, args.step_s)
        if args.inputs == "paper":
            inputs = default_inputs(estimator)
        else:
            inputs = parse_inputs(args.inputs or DEFAULT_INPUTS_TEXT, estimator.average_s, estimator.step_s)
        if ladder:
            sets = [parse_inputs(text, args.average_s, args.step_s) for text in dict.fromkeys(r.inputs_text for r in RUNGS)]
        else:
            sets = input_sets(args.auto_inputs, args.average_s, args.step_s) if auto else [inputs]
        unit_runs = [[read_run(path) for path in unit.runs] for unit in units]
        for loaded in (each for runs in unit_runs for each in runs):
            estimator.samples(loaded.rate_hz)  # --window-s and --average-s, checked even when --inputs has no rate
            for specs in sets:
                for spec in specs:
                    if spec.estimator is not None:
                        spec.estimator.samples(loaded.rate_hz)
    except ValueError as error:
        raise UsageError(str(error)) from None
    if args.auto_inputs and not auto:
        raise UsageError("--auto-inputs goes with --method auto")
    if ladder and (args.compare or args.inputs):
        raise UsageError("the ladder chooses the model and its inputs; --compare and --inputs go with another --method")
    if auto and args.compare:
        raise UsageError("--compare fits every method on one input set; --method auto already compares them all")
    for loaded in (each for runs in unit_runs for each in runs):
        warmup_s = max(warmup_samples(specs, loaded.rate_hz) for specs in sets) / loaded.rate_hz
        check_calibration_run(loaded, warmup_s, args.block_s)
    particles = args.particles or (AUTO_PARTICLES if auto else LADDER_PARTICLES if ladder else 60)
    iterations = args.iterations or (AUTO_ITERATIONS if auto else 100)
    config = TrainConfig(
        method=args.method,
        inputs=inputs,
        domain_guard=args.domain_guard,
        outside=args.outside_range,
        block_s=args.block_s,
        reference=_reference(args.reference),
        fit=FitOptions(
            degree=args.degree, poly_terms=args.poly_terms, particles=particles, iterations=iterations, patience=args.early_stop,
            c1=args.c1, c2=args.c2,
            fitness=args.fitness, trend=args.trend, coil_mix=args.coil_mix, rate_prior=args.rate_prior, folds=args.folds,
            n_jobs=args.jobs, seed=args.seed, progress=not args.quiet,
        ),  # fmt: skip
        name=args.name,
        sensor_resolution_c=args.sensor_resolution_c,
        sensor_noise_c=args.sensor_noise_c,
        smoothed_fit=args.fit_temperature == "smoothed",
    )
    settings = Settings(config, sets, auto=auto, compare=args.compare, log=not args.quiet, ladder=ladder,
                        average_s=args.average_s, step_s=args.step_s)  # fmt: skip
    jobs = [channel_jobs(unit.name if args.manifest else "", runs, [read_run(path) for path in unit.holdout],
                         unit.channels, settings)
            for unit, runs in zip(units, unit_runs)]  # fmt: skip
    fits = fit_channels([job for unit_jobs in jobs for job in unit_jobs], settings, args.jobs)
    failed: list[str] = []
    for unit, unit_jobs in zip(units, jobs):
        unit_fits, fits = fits[: len(unit_jobs)], fits[len(unit_jobs) :]
        try:
            _finish(args, unit, unit_jobs, unit_fits)
        except FogdError as error:
            if not args.manifest:
                raise
            print(f"{PROG}: unit {unit.name}: {error}", file=sys.stderr)
            failed.append(unit.name)
    if failed:
        raise InputError(f"{len(failed)} of {len(units)} units have no model file: {', '.join(failed)} (see above)")
    return 0


def _finish(args: argparse.Namespace, unit: Unit, jobs: list[ChannelJob], fits: list[ChannelFit]) -> None:
    """Print a unit's fits, refuse what cannot be written, write its model file and report."""
    for fit in fits:
        fit.transcript.replay()
    for fit in fits:
        where = f"{fit.channel}: " if fit.channel else ""
        if fit.error is not None:
            raise type(fit.error)(f"{where}{fit.error}")
        if fit.worse and args.force:
            print(f"{PROG}: warning: {where}{fit.worse}; written anyway (--force)", file=sys.stderr)
        elif fit.worse:
            leave_out = "leave the channel out (--channels), " if fit.channel else ""
            raise InputError(f"{where}{fit.worse}; record more or longer runs over the range in use, {leave_out}"
                             "try --method auto, or --force to write it anyway")  # fmt: skip
    passed = [fit.channel or "the gyro" for fit in fits if fit.uncompensated]
    if passed and len(passed) == len(fits):  # a valid model that compensates nothing: written, and said so
        where = f"unit {unit.name}: " if args.manifest else ""
        print(f"{PROG}: warning: {where}{'nothing' if len(fits) == 1 else 'no channel'} is compensated: no model's "
              "held-out drift was below the uncompensated drift, so the model file passes the readings through "
              "unchanged; record runs over a wider temperature range, or try --method auto", file=sys.stderr)  # fmt: skip
    if unit.out:
        document = unit_document(args.name or (unit.name if args.manifest else None), fits)
        modelfile.save(unit.out, document, inputs=[*unit.runs, *unit.holdout])
        if len(fits) == 1 and fits[0].channel is None:
            print(f"\nwrote {unit.out} ({fits[0].label}, {fits[0].chosen.model.name})", file=sys.stderr)
        else:
            through = f"; passed through uncompensated: {', '.join(passed)}" if passed else ""
            print(f"\nwrote {unit.out} ({len(fits)} channels: {', '.join(fit.channel for fit in fits)}{through})",
                  file=sys.stderr)  # fmt: skip
    if args.report:
        from fogd.calibration.report import (
            write_report,  # matplotlib only when a report is asked for
        )

        for job, fit in zip(jobs, fits):
            directory = Path(args.report, *(part for part in (job.unit, job.channel) if part))
            path = write_report(str(directory), fit.trained, fit.label, job.holdouts, args.block_s,
                                selection=fit.selection, allan=True, unit=channel_unit(fit.channel))  # fmt: skip
            print(f"wrote report {path}", file=sys.stderr)


def _units(args: argparse.Namespace) -> list[Unit]:
    """The units to train: the manifest's, or the one the command line describes."""
    channels = _channel_list(args.channels)
    if args.manifest:
        if args.runs or args.holdout or args.name:
            raise UsageError("--manifest gives every unit's runs, holdout runs and name; give no RUN.csv, --holdout or --name")
        if args.output and not Path(args.output).is_dir():
            raise UsageError(f"-o {args.output}: with --manifest, -o is the directory for the units' <name>.json")
        units = read_manifest(args.manifest, args.output)
        for unit in units:
            unit.channels = unit.channels or channels
        return units
    if not args.runs:
        raise UsageError(f"give the calibration runs (RUN.csv ...) or --manifest UNITS.yaml (see {PROG} --help)")
    if not args.output and not args.compare:
        raise UsageError(f"give -o MODEL.json (or --compare to only compare methods) (see {PROG} --help)")
    return [Unit("", list(args.runs), args.output, channels, list(args.holdout))]


def _channel_list(text: str | None) -> list[str] | None:
    if text is None:
        return None
    names = [name.strip() for name in text.split(",") if name.strip()]
    bad = [name for name in names if name not in CHANNELS]
    if bad or not names:
        raise UsageError(f"--channels {text!r}: channels are {', '.join(CHANNELS)} (comma-separated)")
    return names


def _reference(text: str) -> str | float:
    if text == "mean":
        return "mean"
    try:
        return float(text)
    except ValueError:
        raise UsageError(f"--reference must be 'mean' or a rate in deg/h, not {text!r}") from None


def main(argv: Sequence[str] | None = None) -> int:
    return run(PROG, body, argv)


if __name__ == "__main__":
    sys.exit(main())
