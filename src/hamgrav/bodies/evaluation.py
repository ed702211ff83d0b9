"""Evaluation point sets of a body: shells and surface-following sets (canonical points)."""

from __future__ import annotations

import numpy as np

from ..core.fields import shell_points
from .catalogue import Body

__all__ = ["evaluation_sets", "set_label"]


def evaluation_sets(
    body: Body,
    shells_rb=(1.05, 1.1, 1.2, 1.5),
    altitudes_m=(),
    n_directions: int = 400,
    seed: int = 0,
) -> dict[str, np.ndarray]:
    """Named point sets (n, 3), canonical: shells ``r<s>`` of ``n_directions`` seeded random
    directions at s R_B, and surface-following sets ``h<alt>m``: the mesh vertices raised
    radially by each altitude [m]."""
    sets = {
        f"r{s:g}": shell_points(s * body.brillouin_radius, n_directions, seed) for s in shells_rb
    }
    for h in altitudes_m:
        sets[f"h{h:g}m"] = body.surface_points(body.altitude_to_canonical(h))
    return sets


def set_label(name: str) -> str:
    """Human label of an evaluation set name (``r1.2`` -> shell 1.2 R_B, ``h30m`` -> 30 m)."""
    if name.startswith("r"):
        return f"shell {name[1:]} R_B"
    return f"surface + {name[1:-1]} m"
