"""`fogd-train`: fit a temperature-error model from thermal-chamber runs and write the model file."""

from __future__ import annotations

import argparse
import sys
from typing import Sequence

from fogd.calibration.models import FITNESSES, METHODS, FitOptions
from fogd.calibration.models.folds import MIN_RUNS_LEFT_OUT, drift_rmse
from fogd.calibration.models.least_squares import POLY_TERMS
from fogd.calibration.models.svr import TRENDS
from fogd.calibration.replay import replay, replay_table
from fogd.calibration.runcheck import check_calibration_run
from fogd.calibration.selection import (
    AUTO_ITERATIONS,
    AUTO_PARTICLES,
    DEFAULT_INPUT_SETS,
    input_sets,
    select,
    stderr_log,
    table_lines,
)
from fogd.calibration.tables import error_table
from fogd.calibration.training import TrainConfig, Trained, prepare, train
from fogd.cli.common import ArgumentParser, DefaultsHelpFormatter, run
from fogd.core import modelfile
from fogd.core.atomic import refuse_inputs
from fogd.core.columns import BLOCK_S
from fogd.core.estimator import EstimatorSettings
from fogd.core.inputs import (
    DEFAULT_INPUTS_TEXT,
    INPUTS_SYNTAX,
    default_inputs,
    parse_inputs,
    warmup_samples,
)
from fogd.core.numbers import non_negative_float, positive_float, positive_int
from fogd.core.runio import read_run
from fogd.errors import InputError, UsageError

PROG = "fogd-train"


def parser() -> ArgumentParser:
    p = ArgumentParser(
        prog=PROG,
        description="Fit a FOG temperature-error model f(T, dT/dt) from thermal-chamber runs "
        "(CSV t_s,rate_dph,temp_c) and write it as a JSON model file for fogd and fogd-replay.",
        epilog="Example: fogd-train cal_heat.csv cal_cool.csv -o model.json --report report/",
        formatter_class=DefaultsHelpFormatter,
    )
    p.add_argument("runs", nargs="+", metavar="RUN.csv", help="calibration runs; blocks never straddle two runs")
    p.add_argument("-o", "--output", metavar="MODEL.json", help="model file to write (required unless --compare)")
    p.add_argument(
        "--method", choices=(*METHODS, "auto"), default="pso-svr",
        help="model family; auto: choose the family and the input set by nested held-out error (leave-one-run-out, "
        "or blocked time folds for one run; each family tuned without the fold it is scored on) among linear, "
        "ls-poly, rbf-nn, pso-svr on the --auto-inputs sets",
    )  # fmt: skip
    p.add_argument(
        "--inputs", metavar="LIST", default=None,
        help=f"model inputs (default {DEFAULT_INPUTS_TEXT}: the sensor temperature and a bank of lags spanning the "
        "thermal range; 'paper' is "
        f"the paper's temp,rate@WINDOW_S): {INPUTS_SYNTAX}",
    )  # fmt: skip
    p.add_argument(
        "--auto-inputs", metavar="LIST", action="append",
        help="an input set for --method auto (repeat the option for several; default: "
        + " | ".join(DEFAULT_INPUT_SETS) + ")",
    )  # fmt: skip
    p.add_argument(
        "--domain-guard", action=argparse.BooleanOptionalAction, default=False,
        help="store the joint-space domain guard: samples far from every calibration block are flagged "
        "OUT_OF_DOMAIN and compensated by a linear fallback (off by default: the trend under the SVR is what "
        "a sample outside the calibration data gets, and with a lag bank the guard would refuse ordinary "
        "temperature histories)",
    )  # fmt: skip
    p.add_argument(
        "--force", action="store_true",
        help="write the model even when its held-out error exceeds the uncompensated drift",
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
    p.add_argument("--particles", type=positive_int, default=None,
                   help=f"PSO population (default 60 as the paper; {AUTO_PARTICLES} inside --method auto)")
    p.add_argument("--iterations", type=positive_int, default=None,
                   help=f"PSO iterations (default 100 as the paper; {AUTO_ITERATIONS} inside --method auto)")
    p.add_argument("--c1", type=non_negative_float, default=2.0, help="PSO cognitive learning factor")
    p.add_argument("--c2", type=non_negative_float, default=2.0, help="PSO social learning factor")
    p.add_argument("--folds", type=positive_int, default=5, help="blocked time folds for cv with a single run")
    p.add_argument("--jobs", type=int, default=1, help="joblib workers evaluating particles (-1: all cores)")
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
    p.add_argument("--block-s", type=positive_float, default=BLOCK_S, help="block length for targets, in seconds")
    p.add_argument(
        "--reference", default="mean",
        help="rate subtracted to get the error: 'mean' of the training blocks, or a value in deg/h",
    )  # fmt: skip
    p.add_argument("--name", help="model name recorded in the file and in the daemon's status")
    p.add_argument("--compare", action="store_true", help="fit every method and print the paper's table 3")
    p.add_argument("--holdout", nargs="+", default=[], metavar="RUN.csv", help="runs not used for training: table 4 each")
    p.add_argument("--report", metavar="DIR", help="write figures (PNG) and a markdown summary to DIR")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    return p


def _reference(text: str) -> str | float:
    if text == "mean":
        return "mean"
    try:
        return float(text)
    except ValueError:
        raise UsageError(f"--reference must be 'mean' or a rate in deg/h, not {text!r}") from None


def body(argv: Sequence[str] | None) -> int:
    args = parser().parse_args(argv)
    if not args.output and not args.compare:
        raise UsageError(f"give -o MODEL.json (or --compare to only compare methods) (see {PROG} --help)")
    if args.output:
        refuse_inputs(args.output, [*args.runs, *args.holdout])  # before minutes of fitting, not after
    auto = args.method == "auto"
    try:
        estimator = EstimatorSettings(args.window_s, args.average_s, args.step_s)
        if args.inputs == "paper":
            inputs = default_inputs(estimator)
        else:
            inputs = parse_inputs(args.inputs or DEFAULT_INPUTS_TEXT, estimator.average_s, estimator.step_s)
        sets = input_sets(args.auto_inputs, args.average_s, args.step_s) if auto else [inputs]
        runs = [read_run(path) for path in args.runs]
        for loaded in runs:
            estimator.samples(loaded.rate_hz)  # --window-s and --average-s, checked even when --inputs has no rate
            for specs in sets:
                for spec in specs:
                    if spec.estimator is not None:
                        spec.estimator.samples(loaded.rate_hz)
    except ValueError as error:
        raise UsageError(str(error)) from None
    if args.auto_inputs and not auto:
        raise UsageError("--auto-inputs goes with --method auto")
    if auto and args.compare:
        raise UsageError("--compare fits every method on one input set; --method auto already compares them all")
    for loaded in runs:
        warmup_s = max(warmup_samples(specs, loaded.rate_hz) for specs in sets) / loaded.rate_hz
        check_calibration_run(loaded, warmup_s, args.block_s)
    particles = args.particles or (AUTO_PARTICLES if auto else 60)
    iterations = args.iterations or (AUTO_ITERATIONS if auto else 100)
    holdouts = [read_run(path) for path in args.holdout]
    config = TrainConfig(
        method=args.method,
        inputs=inputs,
        domain_guard=args.domain_guard,
        block_s=args.block_s,
        reference=_reference(args.reference),
        fit=FitOptions(
            degree=args.degree, poly_terms=args.poly_terms, particles=particles, iterations=iterations, c1=args.c1, c2=args.c2,
            fitness=args.fitness, trend=args.trend, folds=args.folds, n_jobs=args.jobs, seed=args.seed, progress=not args.quiet,
        ),  # fmt: skip
        name=args.name,
    )
    selection: list[str] | None = None
    if auto:
        best, candidates = select(runs, config, sets, log=None if args.quiet else stderr_log)
        label = f"auto: {best.label}"
        trained: dict[str, Trained] = {label: best.trained}
        chosen = best.trained
        folds = "leave-one-run-out" if len(runs) >= MIN_RUNS_LEFT_OUT else f"{args.folds} blocked time folds of every run"
        chosen.document["training"]["selection"] = {
            "folds": folds,
            "chosen": best.row(),
            "candidates": [candidate.row() for candidate in candidates],
        }
        selection = table_lines(candidates, best, markdown=True)
        print(f"\nModel selection (--method auto): nested held-out RMSE of each candidate, {folds}")
        print("\n".join(table_lines(candidates, best)))
        print(f"chosen: {best.label} (nested held-out RMSE {best.held_out_rmse_dph:.3e} deg/h)")
        held_out_dph = best.held_out_rmse_dph
    else:
        prepared = prepare(runs, config)
        methods = list(METHODS) if args.compare else [args.method]
        trained = {}
        for method in methods:
            config.method = method
            try:
                trained[method] = train(runs, config, prepared)
            except InputError as error:  # --compare: a family these runs cannot fit is skipped, and said so
                if method == args.method:
                    raise
                print(f"{PROG}: --compare: {method} skipped: {error}", file=sys.stderr)
        label = args.method
        chosen = trained[args.method]
        held_out_dph = chosen.fitted.cv_rmse_dph
    for line in _summary(chosen):
        print(line, file=sys.stderr)
    for method, fitted in ((m, t.fitted) for m, t in trained.items()):
        if fitted.unconverged_fits:
            print(f"{method}: {fitted.unconverged_fits} of scikit-learn's fits stopped at their iteration limit "
                  "(scored by held-out error like every other fit)", file=sys.stderr)
    print(f"\nTable 3: fit on the training runs ({len(chosen.error_dph)} blocks of {args.block_s:g} s, about each run's mean)")
    rows = [("Before compensation", chosen.before)] + [(m, t.after) for m, t in trained.items()]
    print(error_table(rows))
    for holdout in holdouts:
        print(f"\nTable 4: {holdout.name}, not used for training (block means about the run mean)")
        print(error_table(_holdout_rows(trained, holdout, args.block_s)))
    if args.output:
        _never_worse_than_nothing(chosen, held_out_dph, args.force)
        modelfile.save(args.output, chosen.document, inputs=[*args.runs, *args.holdout])
        print(f"\nwrote {args.output} ({label}, {chosen.model.name})", file=sys.stderr)
    if args.report:
        from fogd.calibration.report import (
            write_report,  # matplotlib only when a report is asked for
        )

        path = write_report(args.report, trained, label, holdouts, args.block_s, selection=selection, allan=True)
        print(f"wrote report {path}", file=sys.stderr)
    return 0


def uncompensated_drift_dph(trained: Trained) -> float:
    """The calibration blocks' drift with no compensation, about each run's mean (as the held-out figure)."""
    return drift_rmse(trained.error_dph, trained.data.groups)


def _never_worse_than_nothing(trained: Trained, held_out_dph: float | None, force: bool) -> None:
    """Refuse (InputError, one line) a model whose held-out drift exceeds the drift it is meant to remove."""
    uncompensated_dph = uncompensated_drift_dph(trained)
    if held_out_dph is None or held_out_dph <= uncompensated_dph:
        return
    message = (f"the model's held-out drift ({held_out_dph:.3e} deg/h) exceeds the uncompensated drift "
               f"({uncompensated_dph:.3e} deg/h): it would make the gyro worse")  # fmt: skip
    if force:
        print(f"{PROG}: warning: {message}; written anyway (--force)", file=sys.stderr)
        return
    raise InputError(f"{message}; record more or longer runs over the range in use, try --method auto, or "
                     "--force to write it anyway")


def _summary(trained: Trained) -> list[str]:
    hyper = dict(trained.fitted.hyperparameters)
    if "epsilon_dph" in hyper:  # the tube in deg/h says what the scaled epsilon says; one of them is enough
        hyper.pop("epsilon", None)
    lines = [f"{trained.fitted.method}: " + ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in hyper.items())]
    if trained.fitted.cv_rmse_dph is not None:
        lines.append(f"held-out (cv) drift RMSE: {trained.fitted.cv_rmse_dph:.3e} deg/h (about each run's mean), "
                     f"uncompensated {uncompensated_drift_dph(trained):.3e} deg/h")
    return lines


def _holdout_rows(trained: dict[str, Trained], holdout, block_s: float) -> list:
    tables = {method: replay_table(holdout, replay(t.model, holdout), block_s) for method, t in trained.items()}
    first = next(iter(tables.values()))
    rows = [("Before compensation", first.before)] + [(method, table.after) for method, table in tables.items()]
    if first.best is not None:
        rows.append(("Best possible (true error removed)", first.best))
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    return run(PROG, body, argv)


if __name__ == "__main__":
    sys.exit(main())
