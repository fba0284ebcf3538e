"""Plain-text and markdown rendering of the paper's tables (3 and 4) for terminals and reports, and the names
values in a channel's own unit are shown under (deg/h for a gyro, g for an accelerometer)."""

from __future__ import annotations

from typing import Any

from fogd.core.errorstats import ErrorStats


def error_table(rows: list[tuple[str, ErrorStats]], *, markdown: bool = False, unit: str = "deg/h") -> str:
    """A table of RMSE and maximum error (in deg/h, or the channel's `unit`: g for an accelerometer), one row
    per scheme, like the paper's tables 3 and 4."""
    header = ("Scheme", f"RMSE ({unit})", f"Max error ({unit})")
    body = [(name, f"{stats.rmse_dph:.3e}", f"{stats.max_dph:.3e}") for name, stats in rows]
    if markdown:
        lines = ["| " + " | ".join(header) + " |", "|---|---:|---:|"]
        lines += ["| " + " | ".join(row) + " |" for row in body]
        return "\n".join(lines)
    widths = [max(len(row[i]) for row in [header, *body]) for i in range(3)]
    fmt = f"{{:<{widths[0]}}}  {{:>{widths[1]}}}  {{:>{widths[2]}}}"
    return "\n".join([fmt.format(*header), *(fmt.format(*row) for row in body)])


# the suffix a value in the channel's unit carries in a name (fogd's names carry their unit: epsilon_dph)
UNIT_SUFFIXES = {"deg/h": "dph", "g": "g"}


def epsilon_key(unit: str) -> str:
    """The name the SVR's tube is shown under for a channel in `unit`: epsilon_dph, or epsilon_g."""
    return f"epsilon_{UNIT_SUFFIXES.get(unit, 'dph')}"


def unit_named(hyperparameters: dict[str, Any], unit: str) -> dict[str, Any]:
    """Hyper-parameters as shown for a channel in `unit`: the values stored under a name ending in _dph (the
    tube epsilon_dph, the trend's own score trend_alone_dph: in the targets' unit whatever the channel) named
    with the channel's suffix instead, epsilon_g for an accelerometer; the order kept."""
    suffix = UNIT_SUFFIXES.get(unit, "dph")
    return {(name[: -len("dph")] + suffix if name.endswith("_dph") else name): value
            for name, value in hyperparameters.items()}  # fmt: skip
