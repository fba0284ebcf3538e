"""The shared core: what the daemon and calibration must compute identically, numpy only.

Owns the eq. 16 temperature-rate estimator and the lag bank (the model inputs, streaming = batch), the
frozen model evaluator and the model file that stores it, the compensator (the one code path of the daemon
and of replay), the flags, the error statistics of the paper's tables, the run CSV and the names both sides
share (`columns`). Must never import the daemon (`fogd.serving`), calibration, simulation, protocols, the
command line, scikit-learn or scipy: the daemon maps this package and nothing heavier.
"""
