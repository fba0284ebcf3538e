"""What each method's fitting function hands back to `fit`: the estimator, frozen params, hyper-parameters."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class MethodFit:
    """A method's result in scaled space; `estimator` is fitted, and cloned to refit it on each fold."""

    estimator: object
    params: dict
    hyperparameters: dict
    fitness_history: list[float] = field(default_factory=list)
