"""fogd: real-time temperature compensation for fibre-optic gyroscopes."""

__version__ = "0.1.0"
