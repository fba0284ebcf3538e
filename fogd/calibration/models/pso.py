"""Particle swarm minimiser (paper section 2.2, eq. 14-15): a bounded, seeded, joblib-parallel search.

This module owns only the swarm: it knows nothing about SVR. Each iteration evaluates the whole population
through one `joblib.Parallel` opened for the run, so `joblib.parallel_config(backend=...)` can send the
fitness evaluations to processes, a Dask or a Ray cluster. All random draws happen in the calling process
and the fitness is a pure function of the position, so a seed gives the same result whatever `n_jobs` is.

Early stop (`patience`): the swarm stops when its best fitness has not improved by more than `tolerance`
(relative) for `patience` iterations in a row. Most of a swarm's budget is spent after its best has settled: on
a real IMU's day the paper's 60 x 100 cv search stopped moving at iteration 37 of 100 (issue 33).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Callable

import numpy as np
from joblib import Parallel, delayed
from tqdm import tqdm


@dataclass
class PsoResult:
    """The best position found, its fitness, the best fitness after each iteration and the evaluation count."""

    best_position: np.ndarray
    best_fitness: float
    history: list[float]
    evaluations: int


def pso_minimize(
    fitness: Callable[[np.ndarray], float],
    lower: np.ndarray,
    upper: np.ndarray,
    *,
    particles: int = 60,
    iterations: int = 100,
    c1: float = 2.0,
    c2: float = 2.0,
    inertia: tuple[float, float] = (0.9, 0.4),
    velocity_fraction: float = 0.2,
    seed: int = 0,
    n_jobs: int = 1,
    progress: bool = True,
    label: str = "PSO",
    patience: int = 0,
    tolerance: float = 1e-3,
) -> PsoResult:
    """Minimise `fitness` over the box [lower, upper]; one iteration is one evaluation of every particle.

    `fitness` must be picklable (a module-level function, or a functools.partial of one with numpy
    arguments) when joblib runs it in other processes. A non-finite fitness counts as +inf. `patience` > 0:
    stop once the best has not improved by more than `tolerance` of itself for that many iterations (0: never).
    """
    lower = np.asarray(lower, dtype=np.float64)
    upper = np.asarray(upper, dtype=np.float64)
    if lower.shape != upper.shape or lower.ndim != 1 or not np.all(upper > lower):
        raise ValueError("lower and upper must be 1-D arrays of the same length with upper > lower")
    if particles < 1 or iterations < 1:
        raise ValueError("particles and iterations must be at least 1")
    if patience < 0 or not tolerance >= 0:
        raise ValueError("patience and tolerance must not be negative")
    rng = np.random.default_rng(seed)
    dims = lower.size
    # Paper step 1: velocities limited to v_max = k x_max, here k times the width of the box.
    v_max = velocity_fraction * (upper - lower)
    position = lower + rng.random((particles, dims)) * (upper - lower)
    velocity = rng.uniform(-v_max, v_max, (particles, dims))
    personal_best = position.copy()
    personal_fitness = np.full(particles, np.inf)
    best_position, best_fitness = position[0].copy(), np.inf
    history: list[float] = []
    settled_at, still = np.inf, 0  # the best when it last moved by more than `tolerance`, iterations since

    with Parallel(n_jobs=n_jobs) as parallel, tqdm(
        total=iterations, desc=label, file=sys.stderr, disable=not progress
    ) as bar:
        for iteration in range(iterations):
            values = np.array(parallel(delayed(fitness)(row) for row in position), dtype=np.float64)
            values[~np.isfinite(values)] = np.inf
            improved = values < personal_fitness
            personal_best[improved] = position[improved]
            personal_fitness[improved] = values[improved]
            leader = int(np.argmin(personal_fitness))
            if personal_fitness[leader] < best_fitness:
                best_position, best_fitness = personal_best[leader].copy(), float(personal_fitness[leader])
            history.append(best_fitness)
            bar.set_postfix(best=f"{best_fitness:.4g}", refresh=False)
            bar.update()
            if best_fitness < settled_at - tolerance * abs(best_fitness):
                settled_at, still = best_fitness, 0
            else:
                still += 1
            if iteration == iterations - 1 or (patience and still >= patience):
                break
            # Eq. 14 has no inertia weight, and without one the swarm keeps oscillating instead of
            # converging; we use Shi & Eberhart's linearly decreasing inertia (0.9 -> 0.4 by default).
            weight = inertia[0] + (inertia[1] - inertia[0]) * iteration / max(iterations - 2, 1)
            r1, r2 = rng.random((2, particles, dims))
            velocity = (
                weight * velocity
                + c1 * r1 * (personal_best - position)
                + c2 * r2 * (best_position - position)
            )
            velocity = np.clip(velocity, -v_max, v_max)
            position = position + velocity  # eq. 15
            outside = (position < lower) | (position > upper)
            position = np.clip(position, lower, upper)
            velocity[outside] = 0.0
    return PsoResult(best_position, best_fitness, history, particles * len(history))
