"""Bounded numbers read from text, one meaning for the command line and the config file.

Each parser is an argparse `type`: it returns the number or raises `argparse.ArgumentTypeError` with a
message naming the bounds; `fogd.serving.config` turns that message into its own ConfigError.
"""

from __future__ import annotations

import argparse
import math
from typing import Callable


def number_in(low: float, high: float, unit: str = "", *, low_open: bool = False) -> Callable[[str], float]:
    """An argparse type: a finite number within low..high (above low, when `low_open`)."""
    unit_text = f" {unit}" if unit else ""
    bounds = [f"above {low:g}" if low_open else f"at least {low:g}"] + ([f"at most {high:g}"] if math.isfinite(high) else [])
    where = " and ".join(bounds) + unit_text

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not (math.isfinite(value) and low <= value <= high) or (low_open and value == low):
            raise argparse.ArgumentTypeError(f"{text!r} must be {where}")
        return value

    return parse


def whole_number(minimum: int) -> Callable[[str], int]:
    """An argparse type: a whole number of at least `minimum`."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"{text!r} must be at least {minimum}")
        return value

    return parse


positive_float = number_in(0.0, math.inf, low_open=True)
non_negative_float = number_in(0.0, math.inf)
positive_int = whole_number(1)
seed = whole_number(0)
probability = number_in(0.0, 1.0)
