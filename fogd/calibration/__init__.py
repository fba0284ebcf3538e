"""Calibration, offline: training rows from chamber runs, the model families and the swarm (`models`),
input-set selection, replay of recorded runs through the core's compensator, the paper's tables, Allan
deviation and the HTML/PNG report.

Imports the core, scikit-learn and matplotlib; must never import the daemon (`fogd.serving`), the wire
protocols or the command line.
"""
