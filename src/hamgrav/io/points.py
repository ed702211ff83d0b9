"""Points in, field values out: the CSV files of ``hamgrav evaluate --points``.

Input: a header line ``x_m,y_m,z_m`` (the unit is in the names, so a file in kilometres
cannot pass as metres), then one point per line, three comma-separated numbers [m] in the
model's body-fixed frame. Blank lines and lines starting with ``#`` are skipped; anything
else is refused naming the file and line. Output: a header and one row per point, numbers
written with 17 significant digits (float64 round-trips), atomically.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..files import atomic_path

__all__ = ["POINTS_HEADER", "read_points_csv", "write_columns_csv"]

#: The header line of a points file.
POINTS_HEADER = ("x_m", "y_m", "z_m")


def read_points_csv(path: str | os.PathLike) -> tuple[np.ndarray, list[int]]:
    """The points (n, 3) [m] of the CSV file at ``path`` (format in the module docstring)
    and the line number (1-based) of each, for messages about single points."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"--points {path} is a folder; give a CSV file of points x_m,y_m,z_m")
    if not path.is_file():
        raise InputError(f"--points: file not found: {path}")
    try:
        lines = path.read_text().splitlines()
    except UnicodeDecodeError:
        raise InputError(f"--points {path} is not a text file; give a CSV of x_m,y_m,z_m") from None
    fix = "give a header line x_m,y_m,z_m, then x,y,z [m] per line"
    header, rows, numbers = None, [], []
    for k, line in enumerate(lines, start=1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        cells = [c.strip() for c in text.split(",")]
        if header is None:
            if tuple(cells) != POINTS_HEADER:
                raise InputError(
                    f"{path} line {k}: expected the header x_m,y_m,z_m, got {text!r}; {fix}"
                )
            header = k
            continue
        try:
            values = [float(c) for c in cells]
        except ValueError:
            values = []
        if len(values) != 3 or not all(math.isfinite(v) for v in values):
            raise InputError(
                f"{path} line {k}: expected three finite numbers x,y,z [m], got {text!r}; {fix}"
            )
        rows.append(k)
        numbers.append(values)
    if not numbers:
        raise InputError(f"--points {path} holds no points; {fix}")
    return np.array(numbers, dtype=float), rows


def write_columns_csv(path: str | os.PathLike, columns: Mapping[str, np.ndarray]) -> None:
    """Write equal-length 1-D ``columns`` (header name -> values) as a CSV file at ``path``,
    atomically (nothing is left at ``path`` if writing fails)."""
    names = list(columns)
    data = np.column_stack([np.asarray(columns[n], dtype=float) for n in names])
    with atomic_path(path, suffix=".csv") as tmp:
        with open(tmp, "w") as f:
            f.write(",".join(names) + "\n")
            for row in data:
                f.write(",".join(f"{v:.17g}" for v in row) + "\n")
