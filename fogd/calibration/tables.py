"""Plain-text and markdown rendering of the paper's tables (3 and 4) for terminals and reports."""

from __future__ import annotations

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
