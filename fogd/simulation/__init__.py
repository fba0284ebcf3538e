"""Simulated gyros and chambers: thermal physics and noise (`simulator`), chamber temperature profiles
(`profiles`) and the pty FOG emulator that stands in for hardware (`emulator`).

Imports the core and the protocols; must never import the daemon, calibration or the command line.
"""
