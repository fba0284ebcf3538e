"""Per-point compensation cost (paper table 5): one sample = eq. 16 rate-estimator update + model evaluation.

For each of the paper's three models (5th-order least squares, RBF network, PSO-SVR as the paper's plain SVR
with its training-RMSE fitness), fitted the way fogd-train fits them, the same temperature samples go through:
  - sklearn per point: the paper's way, scikit-learn's predict on one row per sample (SVR.predict for
    PSO-SVR), after fogd's scalar estimator update and the same clamp and scaling (so the ratio is the model
    evaluation's alone, not flattered by numpy's per-call overhead in the estimator);
  - fogd array per point: TempRateEstimator.update on a 1-element array (which now takes update_one for
    chunks of up to SCALAR_CHUNK samples) + FrozenModel.predict on one row;
  - fogd fast per point: TempRateEstimator.update_one + FrozenModel.predict_one (pure Python floats; a row
    equal to the previous one reuses its result, exactly), and the same with that reuse defeated;
  - Compensator.process with 1 sample (what the daemon pays per frame when frames arrive one at a time) and
    with chunks of 4096 (what replay and the daemon under load pay), per sample.
Then fogd-train's default model (1b) and, in the same run, that model on all six channels of an IMU through
the ChannelCompensator on the daemon's path for each batch size (process_row up to SCALAR_CHUNK frames, process beyond,
as fogd-replay too), beside it on one channel (1c; issue 12's six-vs-one); and FrozenModel.predict_one run cold, the
row written out as straight-line Python against its loop (1d; issue 37).
Target: fast per point >= 20x faster than sklearn per point, with output equal to 1e-9 deg/h.

Usage: python tools/bench_point.py [--quick]
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np
from bench_common import machine, print_table, sim_run, trained_model, us, verdict

import fogd.core.estimator as fogd_estimator
from fogd.core.channels import ChannelCompensator
from fogd.core import modelfile, straightline
from fogd.core.columns import CHANNELS
from fogd.core.compensator import Compensator
from fogd.core.estimator import SCALAR_CHUNK, TempRateEstimator
from fogd.core.inputs import DEFAULT_INPUTS_TEXT

METHODS = ("ls-poly", "rbf-nn", "pso-svr")
TARGET_RATIO = 20.0
TOLERANCE_DPH = 1e-9
DEMO_MODEL = Path(__file__).resolve().parents[1] / "fogd" / "data" / "demo-model.json"
COLD_SWEEP_BYTES = 64 << 20  # larger than any cache of the machines fogd runs on


def model_terms(trained) -> str:
    params = trained.document["params"]
    if trained.model.method == "pso-svr":
        return f"{len(params['support_vectors'])} SVs"
    if trained.model.method == "rbf-nn":
        return f"{len(params['centres'])} centres"
    return f"{len(params['coef'])} terms"


def sklearn_predictor(trained):
    """The fitted scikit-learn estimator's predict on one raw row (scaled as training scaled it)."""
    fitted, model = trained.fitted, trained.model
    estimator = fitted.estimator
    if model.method == "pso-svr":
        assert not estimator.trend  # the paper's plain SVR
        estimator = estimator.svr_
    low, high = model.domain_min, model.domain_max

    def predict(temp_c: float, rate_cps: float) -> float:
        xs = (np.clip(np.array([[temp_c, rate_cps]]), low, high) - fitted.x_mean) / fitted.x_scale
        return fitted.y_mean + fitted.y_scale * float(estimator.predict(xs)[0])

    return predict


def per_point(trained, temps: np.ndarray, warm: np.ndarray, rate_hz: float) -> dict:
    model = trained.model
    spec = model.inputs[1].estimator

    def fresh() -> TempRateEstimator:
        estimator = TempRateEstimator(spec, rate_hz)
        estimator.update(warm)
        return estimator

    results = {}
    # the paper's way
    predict = sklearn_predictor(trained)
    estimator, out = fresh(), np.empty(temps.size)
    start = time.perf_counter()
    for index, temp_c in enumerate(temps.tolist()):
        out[index] = predict(temp_c, estimator.update_one(temp_c))
    results["sklearn"] = (time.perf_counter() - start) / temps.size, out
    # fogd, numpy on one row
    estimator, out = fresh(), np.empty(temps.size)
    start = time.perf_counter()
    for index in range(temps.size):
        one = temps[index : index + 1]
        rate = estimator.update(one)
        out[index] = model.predict(np.column_stack((one, rate)))[0][0]
    results["array"] = (time.perf_counter() - start) / temps.size, out
    # fogd, scalar fast path
    estimator, out = fresh(), np.empty(temps.size)
    start = time.perf_counter()
    for index, temp_c in enumerate(temps.tolist()):
        out[index] = model.predict_one((temp_c, estimator.update_one(temp_c)))[0]
    results["fast"] = (time.perf_counter() - start) / temps.size, out
    # the same with the reuse of the previous row's result defeated: every sample evaluated
    estimator, out, forget = fresh(), np.empty(temps.size), model.__dict__
    start = time.perf_counter()
    for index, temp_c in enumerate(temps.tolist()):
        forget.pop("_last_point", None)
        if forget.get("_rows"):  # a model served through StackedModels keeps its own last row
            forget["_rows"]._last = forget["_rows"]._last_kernel = None
        kernel = getattr(model.evaluator, "_point", None)
        if kernel is not None and hasattr(kernel, "_last"):  # and a large kernel its last sum
            kernel._last = None
        out[index] = model.predict_one((temp_c, estimator.update_one(temp_c)))[0]
    results["fast_cold"] = (time.perf_counter() - start) / temps.size, out
    # the shared compensator, one sample per call and in chunks
    for label, chunk in (("comp1", 1), ("comp4096", 4096)):
        compensator = Compensator(model, rate_hz)
        compensator.process(np.zeros(warm.size), warm)
        rate_dph = np.zeros(temps.size)
        parts = []
        start = time.perf_counter()
        for begin in range(0, temps.size, chunk):
            parts.append(compensator.process(rate_dph[begin : begin + chunk], temps[begin : begin + chunk]).comp_dph)
        results[label] = (time.perf_counter() - start) / temps.size, np.concatenate(parts)
    return results


def estimator_only(temps: np.ndarray, warm: np.ndarray, spec, rate_hz: float) -> tuple[float, float]:
    estimator = TempRateEstimator(spec, rate_hz)
    estimator.update(warm)
    saved, fogd_estimator.SCALAR_CHUNK = fogd_estimator.SCALAR_CHUNK, 0  # the numpy form even for 1 sample
    try:
        start = time.perf_counter()
        for index in range(temps.size):
            estimator.update(temps[index : index + 1])
        array_s = (time.perf_counter() - start) / temps.size
    finally:
        fogd_estimator.SCALAR_CHUNK = saved
    estimator = TempRateEstimator(spec, rate_hz)
    estimator.update(warm)
    start = time.perf_counter()
    for temp_c in temps.tolist():
        estimator.update_one(temp_c)
    return array_s, (time.perf_counter() - start) / temps.size


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--strict", action="store_true", help="exit 1 when a target is missed")
    parser.add_argument("--quick", action="store_true", help="a short run, a tiny swarm and few points (smoke test)")
    parser.add_argument("--points", type=int, default=None, help="samples timed per path (default 20000; quick 300)")
    args = parser.parse_args(argv)
    points = args.points or (300 if args.quick else 20_000)
    train_hz = 5.0 if args.quick else 50.0
    swarm = (4, 3) if args.quick else (20, 20)
    print(machine())
    run = sim_run("cooling", train_hz)
    print(f"models fitted on {run.path} ({run.rows} rows, 100 s blocks); PSO {swarm[0]}x{swarm[1]}, fitness train, "
          f"no trend (the paper's plain SVR); {points} points timed per path")  # fmt: skip
    rows, failures = [], []
    estimator_rows = None
    for method in METHODS:
        trained = trained_model(run, method, particles=swarm[0], iterations=swarm[1])
        warmup = int(round(trained.model.inputs[1].estimator.window_s * run.rate_hz))
        warm = run.temp_c[:warmup]
        temps = run.temp_c[warmup : warmup + points]
        if temps.size < points:  # a short quick run: go round it again
            temps = np.resize(run.temp_c, points)
        results = per_point(trained, temps, warm, run.rate_hz)
        base_s, base = results["sklearn"]
        fast_s, fast = results["fast"]
        diff = float(np.max(np.abs(fast - base)))
        array_diff = float(np.max(np.abs(fast - results["array"][1]) / np.maximum(1.0, np.abs(fast))))
        comp_diff = max(float(np.max(np.abs(results[key][1] - results["array"][1]))) for key in ("comp1", "comp4096"))
        ratio = base_s / fast_s
        cold_s, cold = results["fast_cold"]
        diff = max(diff, float(np.max(np.abs(cold - base))))
        inputs = np.column_stack((temps, TempRateEstimator(trained.model.inputs[1].estimator, run.rate_hz).update(
            np.concatenate((warm, temps)))[warm.size :]))  # fmt: skip
        repeats = float(np.mean(np.all(inputs[1:] == inputs[:-1], axis=1)))
        ok = ratio >= TARGET_RATIO and diff <= TOLERANCE_DPH
        if not ok:
            failures.append(method)
        rows.append([
            method, model_terms(trained), us(base_s), us(results["array"][0]), us(fast_s), us(cold_s), f"{100 * repeats:.0f}%",
            us(results["comp1"][0]), us(results["comp4096"][0]), f"{ratio:.1f}x", f"{base_s / cold_s:.1f}x", f"{base_s / results['comp4096'][0]:.0f}x", f"{diff:.1e}",
            f"{array_diff:.1e}", f"{comp_diff:.1e}", verdict(ok),
        ])  # fmt: skip
        if estimator_rows is None:
            estimator_rows = estimator_only(temps, warm, trained.model.inputs[1].estimator, run.rate_hz)
    print_table(
        "1. Per-point compensation cost (paper table 5), microseconds per sample; target fast >= 20x sklearn, |diff| <= 1e-9",
        ["model", "size", "sklearn/pt", "fogd array/pt", "fogd fast/pt", "fast, no reuse/pt", "rows = previous",
         "compensator 1/call", "compensator 4096/call", "fast vs sklearn", "no reuse vs sklearn", "batch vs sklearn", "max|fast-sklearn| dph", "fast vs array (rel)", "compensator vs array",
         "target"],
        rows,
    )  # fmt: skip
    array_s, one_s = estimator_rows
    print(f"eq. 16 estimator alone: numpy form on a 1-element array {us(array_s)} us, update_one {us(one_s)} us "
          f"({array_s / one_s:.0f}x); paper table 5 reports 1.11e-4 s per point for PSO-SVR")  # fmt: skip
    default_rows(run, points, swarm, paper_comp1_s=results["comp1"][0], paper_comp4096_s=results["comp4096"][0])
    return 1 if args.strict and failures else 0


def default_rows(run, points: int, swarm: tuple[int, int], paper_comp1_s: float, paper_comp4096_s: float) -> None:
    """fogd-train's default model (PSO-SVR on the coil trend over temp and the lag bank) through the compensator,
    beside the paper's PSO-SVR (temperature and eq. 16 rate) timed above in the same run."""
    trained = trained_model(run, "pso-svr", particles=swarm[0], iterations=swarm[1], fitness="cv", trend="coil",
                            inputs=DEFAULT_INPUTS_TEXT)  # fmt: skip
    temps = np.resize(run.temp_c, points)
    rows = []
    for label, chunk, paper_s in (("1/call", 1, paper_comp1_s), ("4096/call", 4096, paper_comp4096_s)):
        compensator = Compensator(trained.model, run.rate_hz)
        start = time.perf_counter()
        for begin in range(0, temps.size, chunk):
            compensator.process(np.zeros(temps[begin : begin + chunk].size), temps[begin : begin + chunk])
        seconds = (time.perf_counter() - start) / temps.size
        rows.append([f"compensator {label}", model_terms(trained), us(paper_s), us(seconds), f"{seconds / paper_s:.2f}x"])
    print_table(
        f"1b. fogd-train's default ({DEFAULT_INPUTS_TEXT}, coil trend, SVR) against the paper's PSO-SVR, microseconds per sample",
        ["path", "default size", "paper's pso-svr", "default", "default / paper's"],
        rows,
    )  # fmt: skip
    channel_rows(trained, temps, run.rate_hz)
    cold_rows({"bundled demo model": modelfile.load(DEMO_MODEL), "fogd-train's default (1b)": trained.model},
              min(points, 2000))  # fmt: skip


def cold_rows(models: dict, calls: int) -> None:
    """FrozenModel.predict_one warm (the best of three passes over the rows) and cold (each call after a sweep over
    64 MB flushes the caches, timed by the thread's CPU clock: median, less an empty call's): the model's row
    written out (fogd.core.straightline) against predict_one's loop over the same model, each row a new one."""
    sweep = np.ones(COLD_SWEEP_BYTES // 8)

    def cold_us(function, rows: list[list[float]]) -> float:
        times = []
        for row in rows:
            sweep.sum()
            start = time.thread_time_ns()
            function(row)
            times.append(time.thread_time_ns() - start)
        return float(np.median(times)) / 1e3

    def warm_us(function, rows: list[list[float]]) -> float:
        start = time.perf_counter()
        for row in rows:
            function(row)
        return (time.perf_counter() - start) / len(rows) * 1e6

    table = []
    for label, model in models.items():
        rng = np.random.default_rng(0)
        low, high = np.asarray(model.domain_min, dtype=float), np.asarray(model.domain_max, dtype=float)
        rows = (low + (high - low) * rng.uniform(0.1, 0.9, (calls, len(model.inputs)))).tolist()  # each row new
        loop = dataclasses.replace(model)
        loop._one_plan(straight=False)
        empty = cold_us(lambda row: None, rows)
        straight = cold_us(model.predict_one, rows) - empty
        looped = cold_us(loop.predict_one, rows) - empty
        warm = [min(warm_us(function, rows) for _ in range(3)) for function in (loop.predict_one, model.predict_one)]
        table.append([label, "yes" if straightline.written_out(model._one_plan()) else "no (the loop)", f"{warm[0]:.2f}", f"{warm[1]:.2f}",
                      f"{warm[0] / warm[1]:.2f}x", f"{looped:.1f}", f"{straight:.1f}", f"{looped / straight:.2f}x"])  # fmt: skip
    print_table(
        "1d. FrozenModel.predict_one, microseconds per call, warm (rows one after another) and cold (caches flushed before "
        "each call, the thread's CPU): predict_one's loop against the row written out as straight-line Python "
        "(fogd.core.straightline)",
        ["model", "written out", "warm loop", "warm straight", "warm ratio", "cold loop", "cold straight", "cold ratio"],
        table,
    )  # fmt: skip


def channel_rows(trained, temps: np.ndarray, rate_hz: float) -> None:
    """The default model on all six channels of an IMU (as bench_daemon's table 3i: the same model on each, so
    six channels carry six times the kernel terms) through the ChannelCompensator, beside it on one channel, on
    the daemon's paths: a batch of up to SCALAR_CHUNK frames goes row by row through `process_row` (plain Python
    lists, as Daemon.compensate does), a longer one through `process` (numpy arrays, as fogd-replay too)."""
    rows = []
    for chunk in (1, 40, 4096):
        seconds = {}
        for channels in (CHANNELS[:1], CHANNELS):
            best = float("inf")
            for _ in range(3):  # the least disturbed of three (a noisy, shared machine)
                compensator = ChannelCompensator(dict.fromkeys(channels, trained.model), rate_hz)
                values, usable = [0.0] * len(channels), [True] * len(channels)
                start = time.perf_counter()
                if chunk <= SCALAR_CHUNK:  # every sample alike, whatever the batch: one row covers 1..SCALAR_CHUNK
                    row = compensator.process_row
                    for temp_c in temps.tolist():
                        row(values, usable, temp_c, False)
                else:
                    for begin in range(0, temps.size, chunk):
                        part = temps[begin : begin + chunk]
                        compensator.process(dict.fromkeys(channels, np.zeros(part.size)), part)
                best = min(best, (time.perf_counter() - start) / temps.size)
            seconds[len(channels)] = best
        label = f"1-{SCALAR_CHUNK}/call (process_row)" if chunk <= SCALAR_CHUNK else f"{chunk}/call (process)"
        rows.append([label, us(seconds[1]), us(seconds[6]), f"{seconds[6] / seconds[1]:.2f}x"])
    print_table(
        "1c. The default model on six channels (ChannelCompensator, the channels stacked) against one, microseconds per "
        "sample, on the daemon's path for each batch size",
        ["chunk", "one channel", "six channels", "six / one"],
        rows,
    )  # fmt: skip


if __name__ == "__main__":
    raise SystemExit(main())
