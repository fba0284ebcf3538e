"""Fitting the temperature-error models (linear, 5th-order LS polynomial, RBF-NN, PSO-SVR) and the swarm."""

from fogd.calibration.models.fit import FITNESSES, METHODS, FitOptions, Fitted, fit
from fogd.calibration.models.folds import folds
from fogd.calibration.models.pso import PsoResult, pso_minimize

__all__ = ["FITNESSES", "METHODS", "FitOptions", "Fitted", "PsoResult", "fit", "folds", "pso_minimize"]
