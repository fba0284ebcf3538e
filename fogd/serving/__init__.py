"""The daemon and its I/O: config, serial port, reader thread, ring, the compensation loop, the writer and
its sinks, the status file, systemd notification, the optional Prometheus endpoint, and the recorder
behind fogd-record (the same reader and sample clock, writing a run CSV).

Imports the core and the protocols; must never import calibration, simulation, the command line,
scikit-learn or scipy, so the running daemon stays small (see docs/architecture.md).
"""
