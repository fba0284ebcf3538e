"""The particle swarm: finds known minima, stays in its box, and is reproducible whatever n_jobs is."""

from __future__ import annotations

import numpy as np
import pytest

from fogd.calibration.models import pso_minimize

CENTRE = np.array([1.5, -2.0, 0.7])


def sphere(x: np.ndarray) -> float:
    return float(np.sum((x - CENTRE) ** 2)) + 3.0


def rosenbrock(x: np.ndarray) -> float:
    return float((1.0 - x[0]) ** 2 + 100.0 * (x[1] - x[0] ** 2) ** 2)


def nan_left_of_zero(x: np.ndarray) -> float:
    return float("nan") if x[0] < 0 else float(np.sum((x - 0.5) ** 2))


def test_sphere_with_offset() -> None:
    result = pso_minimize(sphere, [-5.0] * 3, [5.0] * 3, particles=20, iterations=60, progress=False)
    np.testing.assert_allclose(result.best_position, CENTRE, atol=1e-3)
    assert result.best_fitness == pytest.approx(3.0, abs=1e-5)
    assert result.best_fitness == sphere(result.best_position)


def test_rosenbrock_2d() -> None:
    result = pso_minimize(rosenbrock, [-2.0, -2.0], [2.0, 2.0], particles=30, iterations=150, seed=3, progress=False)
    np.testing.assert_allclose(result.best_position, [1.0, 1.0], atol=0.05)
    assert result.best_fitness < 1e-3


def test_history_is_non_increasing_one_entry_per_iteration() -> None:
    result = pso_minimize(rosenbrock, [-2.0, -2.0], [2.0, 2.0], particles=8, iterations=25, progress=False)
    history = np.array(result.history)
    assert len(history) == 25 and result.evaluations == 8 * 25
    assert np.all(np.diff(history) <= 0)
    assert history[-1] == result.best_fitness


def test_same_seed_same_result_different_seed_different() -> None:
    run = lambda seed: pso_minimize(rosenbrock, [-2.0, -2.0], [2.0, 2.0], particles=10, iterations=10, seed=seed, progress=False)  # noqa: E731
    first, again, other = run(7), run(7), run(8)
    assert np.array_equal(first.best_position, again.best_position) and first.history == again.history
    assert not np.array_equal(first.best_position, other.best_position)


def test_n_jobs_does_not_change_the_result() -> None:
    kwargs = dict(particles=10, iterations=10, seed=5, progress=False)
    serial = pso_minimize(sphere, [-5.0] * 3, [5.0] * 3, n_jobs=1, **kwargs)
    parallel = pso_minimize(sphere, [-5.0] * 3, [5.0] * 3, n_jobs=2, **kwargs)
    assert np.array_equal(serial.best_position, parallel.best_position)
    assert serial.history == parallel.history


def test_positions_stay_in_the_box() -> None:
    seen: list[np.ndarray] = []

    def far_corner(x: np.ndarray) -> float:  # minimum at (10, -10), outside the box
        seen.append(x.copy())
        return float((x[0] - 10.0) ** 2 + (x[1] + 10.0) ** 2)

    result = pso_minimize(far_corner, [-1.0, -1.0], [1.0, 2.0], particles=10, iterations=30, progress=False)
    positions = np.array(seen)
    assert len(positions) == 300
    assert np.all(positions >= [-1.0, -1.0]) and np.all(positions <= [1.0, 2.0])
    np.testing.assert_array_equal(result.best_position, [1.0, -1.0])  # clamped onto the corner exactly


def test_non_finite_fitness_counts_as_infinity() -> None:
    result = pso_minimize(nan_left_of_zero, [-1.0, -1.0], [1.0, 1.0], particles=10, iterations=30, progress=False)
    assert np.isfinite(result.best_fitness) and result.best_position[0] >= 0
    assert result.best_fitness < 1e-3


def test_progress_bar_on_stderr_only_when_asked(capsys: pytest.CaptureFixture[str]) -> None:
    pso_minimize(sphere, [-5.0] * 3, [5.0] * 3, particles=4, iterations=3, progress=True, label="swarm-test")
    captured = capsys.readouterr()
    assert "swarm-test" in captured.err and "best=" in captured.err and captured.out == ""
    pso_minimize(sphere, [-5.0] * 3, [5.0] * 3, particles=4, iterations=3, progress=False, label="swarm-test")
    assert capsys.readouterr().err == ""


def test_bad_box_is_rejected() -> None:
    with pytest.raises(ValueError):
        pso_minimize(sphere, [1.0, 0.0], [0.0, 1.0], progress=False)
