"""The commands (`fogd`, `fogd-train`, `fogd-replay`, `fogd-sim`, `fogd-emu`, `fogd-record`, `fogd-top`):
each parses its arguments and calls the library. Nothing outside this package imports it.
"""
