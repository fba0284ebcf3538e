"""What every fogd command shares: one-line errors instead of tracebacks, and argparse that says one line."""

from __future__ import annotations

import argparse
import math
import sys
from typing import Callable, NoReturn, Sequence

from fogd import __version__
from fogd.errors import FogdError, UsageError


class ArgumentParser(argparse.ArgumentParser):
    """argparse whose errors are one line naming the option, and a UsageError (exit 2); every command gets
    `--version`."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.add_argument("--version", action="version", version=f"%(prog)s {__version__}",
                          help="print the program's name and fogd's version, and exit")  # fmt: skip

    def error(self, message: str) -> NoReturn:
        raise UsageError(f"{message} (see {self.prog} --help)")


class DefaultsHelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows an option's default in --help, but not an empty one (None, False: the option is simply off)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        if action.default is None or action.default is False or action.default == []:
            return action.help or ""
        return super()._get_help_string(action)


def run(prog: str, body: Callable[[Sequence[str] | None], int], argv: Sequence[str] | None) -> int:
    """Run a command's body; an operator's mistake becomes `prog: message` on stderr and its exit status."""
    try:
        return body(argv)
    except FogdError as error:
        print(f"{prog}: {error}", file=sys.stderr)
        return error.exit_status
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 0


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
