"""--method auto: every family on every input set, same blocks, held-out RMSE, the margin rule."""

import dataclasses

import numpy as np
import pytest

from fogd.calibration.models import FitOptions
from fogd.calibration.selection import (
    MARGIN,
    Candidate,
    choose,
    input_sets,
    nested_rmse,
    outside_policy,
    select,
    served,
    table_lines,
)
from fogd.calibration.training import TrainConfig, options_for_inputs, prepare, train
from fogd.core import modelfile
from fogd.core.inputs import DEFAULT_INPUTS_TEXT, default_inputs, dequantised, parse_inputs, shifted_columns
from fogd.core.outside_range import POLICIES, OutsideRange
from fogd.core.runio import Run


def synthetic_run(name: str, seed: int, up: bool) -> Run:
    rate_hz, n = 2.0, 2 * 3600 * 2
    t_s = np.arange(n) / rate_hz
    temp = 10 + 30 * (t_s / t_s[-1] if up else 1 - t_s / t_s[-1])
    temp = np.round(temp / 0.0625) * 0.0625
    rng = np.random.default_rng(seed)
    rate = 0.02 * (temp - 25) + 0.001 * (temp - 25) ** 2 + rng.normal(0, 0.05, n)
    return Run(name, t_s, rate, temp, rate_hz, str(seed), {})


def test_auto_scores_every_candidate_on_the_same_blocks_and_picks_the_best():
    runs = [synthetic_run("up.csv", 1, True), synthetic_run("down.csv", 2, False)]
    config = TrainConfig(block_s=100.0, fit=FitOptions(particles=4, iterations=2, progress=False), domain_guard=False)
    sets = input_sets(["temp,rate@50", "temp,rate@50,lag@300"], 0.5, 0.0)
    chosen, candidates = select(runs, config, sets, families=("linear", "ls-poly", "pso-svr"))
    # every family on the paper's inputs; on a set with a lag, no plain linear fit (it has no static curve)
    assert [(c.method, len(c.inputs)) for c in candidates] == [
        ("linear", 2), ("ls-poly", 2), ("pso-svr", 2), ("ls-poly", 3), ("pso-svr", 3)]
    targets = {c.trained.error_dph.tobytes() for c in candidates}
    assert len(targets) == 1  # one set of blocks and targets for every candidate
    assert chosen is choose(candidates) and chosen.held_out_rmse_dph <= candidates[0].held_out_rmse_dph
    # the polynomial's terms and order are chosen by held-out error
    poly = candidates[1]
    assert 1 <= poly.hyperparameters["degree"] <= 5 and poly.hyperparameters["terms"] in ("full", "temp")
    lines = table_lines(candidates, chosen)
    assert len(lines) == 1 + len(candidates) and any("<- chosen" in line for line in lines)


def _candidate(method: str, rmse: float, inputs: tuple = ()) -> Candidate:
    return Candidate(method, inputs, rmse, {}, 0.0)


def test_each_step_away_from_the_start_must_win_by_the_margin():
    # without fogd-train's default family among the candidates, the start is the first (linear)
    linear = _candidate("linear", 1.0)
    assert choose([linear, _candidate("ls-poly", 1.0 - MARGIN / 2)]) is linear
    better = _candidate("ls-poly", 1.0 - 2 * MARGIN)
    assert choose([linear, better]) is better
    richer_by_little = _candidate("ls-poly", better.held_out_rmse_dph * (1 - MARGIN / 2), inputs=("lag",))
    assert choose([linear, better, richer_by_little]) is better
    richer_by_much = _candidate("pso-svr", better.held_out_rmse_dph * (1 - 2 * MARGIN), inputs=("lag",))
    assert choose([linear, better, richer_by_little, richer_by_much]) is richer_by_much


def test_the_default_family_is_the_start():
    """pso-svr on the first input set is where auto starts: a simpler family must beat it by the margin."""
    default = _candidate("pso-svr", 1.0)
    assert choose([_candidate("linear", 1.0 - MARGIN / 2), default]) is default
    much_better = _candidate("linear", 1.0 - 2 * MARGIN)
    assert choose([much_better, default]) is much_better


def test_bad_auto_inputs_are_refused():
    with pytest.raises(ValueError, match="--inputs item"):
        input_sets(["temp,rate"], 0.5, 0.0)


def test_nested_score_predicts_each_run_from_the_others_with_clamped_inputs():
    """For linear (nothing to tune) the nested score is leave-one-run-out least squares, computed here with
    numpy's lstsq, the held-out inputs clamped to the training rows' range as the daemon clamps them."""
    runs = [synthetic_run("up.csv", 1, True), synthetic_run("down.csv", 2, False), synthetic_run("up2.csv", 3, True)]
    runs[2].temp_c[:] = runs[2].temp_c + 5.0  # partly outside the other runs' range: clamping matters
    config = TrainConfig(inputs=default_inputs(), block_s=100.0, fit=FitOptions(progress=False), domain_guard=False)
    data, reference = prepare(runs, config)
    error = data.rate_dph - reference

    def held_out(clamp: bool) -> float:
        """Least squares with one offset per training run, without the inputs that barely move within the
        training runs (their squares about the run means under one row at their overall spread: a ramp's rate,
        which the offsets already carry); drift about each held-out run's own mean."""
        squared = []
        for run in range(3):
            train, test = data.groups != run, data.groups == run
            dummies = (data.groups[train][:, None] == np.unique(data.groups[train])).astype(float)
            x = data.x[train]
            within = sum(((x[g] - x[g].mean(axis=0)) ** 2).sum(axis=0) for g in dummies.T.astype(bool))
            moves = within > x.var(axis=0)
            coef = np.zeros(x.shape[1])
            coef[moves] = np.linalg.lstsq(np.c_[dummies, x[:, moves]], error[train], rcond=None)[0][dummies.shape[1]:]
            x_test = data.x[test]
            if clamp:
                x_test = np.clip(x_test, data.x[train].min(axis=0), data.x[train].max(axis=0))
            residual = x_test @ coef - error[test]
            squared.append((residual - residual.mean()) ** 2)
        return float(np.sqrt(np.mean(np.concatenate(squared))))

    expected = held_out(clamp=True)
    assert nested_rmse("linear", data, error, config.fit) == pytest.approx(expected, rel=1e-9)
    unclamped = held_out(clamp=False)
    assert abs(unclamped - expected) > 1e-6 * expected  # the clamp changed something


def test_auto_on_a_whole_degree_sensor_scores_the_dequantised_default():
    """A KVH's whole degrees: the default input set is dequantised before the column roles are worked out (with
    a coarse sensor's own, shorter, default it once raised an IndexError from the clamp)."""
    def whole(run: Run) -> Run:
        return dataclasses.replace(run, temp_c=np.round(run.temp_c))

    runs = [whole(synthetic_run("up.csv", 1, True)), whole(synthetic_run("down.csv", 2, False))]
    config = TrainConfig(block_s=100.0, fit=FitOptions(particles=4, iterations=2, progress=False))
    chosen, candidates = select(runs, config, input_sets(None, 0.5, 0.0), families=("ls-poly", "pso-svr"))
    assert candidates and all(spec.dequantise_c == 1.0 for c in candidates for spec in c.inputs)
    # the default's play has its lag chosen (fogd.calibration.training.with_play_lag): the rest is the default
    assert not any(spec.play_lag_auto for c in candidates for spec in c.inputs)
    unchosen = {tuple(dataclasses.replace(spec, play_lag_s=None, play_lag_auto=True) if spec.width_c else spec for spec in c.inputs)
                for c in candidates}  # fmt: skip
    assert unchosen == {dequantised(parse_inputs(DEFAULT_INPUTS_TEXT), 1.0)}
    assert chosen in candidates


@pytest.mark.parametrize("policy", POLICIES)
def test_held_out_rows_beyond_the_range_are_served_as_the_daemon_serves_them(policy):
    """The ladder scores each fold as the model will be served: a row outside the training rows' range by the
    model file's `outside_range` policy, computed here as fogd.core.frozen computes it from the saved model."""
    runs = [synthetic_run("up.csv", 1, True), synthetic_run("down.csv", 2, False)]
    specs = parse_inputs("temp,lags@100..1000/3,play@1")
    options = options_for_inputs(FitOptions(particles=4, iterations=2, progress=False), specs)
    trained = train(runs, TrainConfig(method="pso-svr", inputs=specs, fit=options, domain_guard=False, outside=policy,
                                      block_s=100.0))  # 40 rows at either end: enough rows  # fmt: skip
    x = trained.data.x
    beyond = np.concatenate([x[:40] + [45.0, 40.0, 30.0, 20.0, 0.0], x[-40:] - [25.0, 3.0, 2.0, 1.0, 0.0],
                             x[:40] + [0.0, 0.0, 0.0, 0.0, 2.5]])  # fmt: skip
    model = modelfile.from_document(trained.document)
    expected, clamped = model.predict(beyond)
    assert clamped.all()
    low, high = (np.asarray(trained.document["domain"][key]) for key in ("min", "max"))
    fitted = trained.fitted
    served_by = outside_policy(policy, fitted, x, trained.error_dph, trained.data.groups, options)
    got = served(fitted, beyond, low, high, shifted_columns(specs), served_by)
    assert got == pytest.approx(expected, rel=1e-9, abs=1e-9)
    if policy != "clamp":  # the policy matters here: the clamp alone is another model beyond the range
        assert not np.allclose(got, served(fitted, beyond, low, high, shifted_columns(specs), OutsideRange("clamp")))
