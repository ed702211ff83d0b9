"""Statistics over repetitions and their table spelling: median, min, max and count of each
number, and ``median (min-max)`` as it appears in every README table."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["aggregate", "summarise", "format_range", "range_row"]


def aggregate(repetitions: list[dict], keys: tuple[str, ...]) -> dict:
    """Per key, model and statistic: median, min, max and count over the repetitions of every
    numeric (non-boolean) value of ``result[key][model][statistic]``; None values are left out
    of the statistics (``n`` counts the others)."""
    out: dict = {}
    for key in keys:
        table: dict = {}
        for rep in repetitions:
            for model, stats in rep.get(key, {}).items():
                for stat, value in stats.items():
                    if isinstance(value, bool) or not isinstance(value, int | float | type(None)):
                        continue
                    table.setdefault(model, {}).setdefault(stat, []).append(value)
        out[key] = {
            model: {stat: summarise(values) for stat, values in stats.items()}
            for model, stats in table.items()
        }
    return out


def summarise(values: list) -> dict:
    """Median, min, max and count of the finite numbers among ``values`` (None left out)."""
    present = [float(v) for v in values if v is not None and math.isfinite(v)]
    if not present:
        return {"median": None, "min": None, "max": None, "n": 0}
    return {
        "median": float(np.median(present)),
        "min": float(np.min(present)),
        "max": float(np.max(present)),
        "n": len(present),
    }


def range_row(cells: list, stats: dict, keys, fmt: str = "{:.3f}", after: list = ()) -> str:
    """A README table row: the ``cells`` first, then ``format_range(stats[k], fmt)`` for each
    of ``keys``, then the ``after`` cells."""
    ranges = [format_range(stats[k], fmt) for k in keys]
    return "| " + " | ".join(str(c) for c in [*cells, *ranges, *after]) + " |"


def format_range(summary: dict | None, fmt: str = "{:.1f}") -> str:
    """``median`` alone for one value, else ``median (min-max)``; "-" when missing."""
    if not summary or summary.get("median") is None:
        return "-"
    med = fmt.format(summary["median"])
    if summary["n"] <= 1 or summary["min"] == summary["max"]:
        return med
    return f"{med} ({fmt.format(summary['min'])}-{fmt.format(summary['max'])})"
