"""Evaluation point sets of a body: shells, surface-following sets, radial bins of a set and
equatorial-plane grids (canonical points)."""

from __future__ import annotations

import numpy as np

from ..core.fields import shell_points
from ..core.geometry import points_inside
from .catalogue import Body

__all__ = [
    "evaluation_sets",
    "set_label",
    "bin_label",
    "radial_bins",
    "equatorial_grid",
    "exterior_points",
]


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


def bin_label(low: float, high: float) -> str:
    """Label of the radial bin [low, high) in R_B, two decimals: ``0.55-0.65``."""
    return f"{low:.2f}-{high:.2f}"


def radial_bins(points: np.ndarray, brillouin_radius: float, edges_rb) -> dict[str, np.ndarray]:
    """``points`` (n, 3), canonical, split by r / R_B into the bins between consecutive
    ``edges_rb`` (increasing, in R_B; each bin holds low <= r / R_B < high): {label: (k, 3)}
    in bin order, labels from :func:`bin_label`; a bin may be empty (k = 0). Points outside
    every bin are left out."""
    edges = np.asarray(edges_rb, dtype=float)
    if edges.ndim != 1 or len(edges) < 2 or np.any(np.diff(edges) <= 0):
        raise ValueError(f"bin edges must be at least two increasing numbers, got {edges_rb!r}")
    r = np.linalg.norm(points, axis=1) / brillouin_radius
    return {
        bin_label(lo, hi): points[(r >= lo) & (r < hi)]
        for lo, hi in zip(edges[:-1], edges[1:], strict=True)
    }


def equatorial_grid(body: Body, extent_rb: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """A square grid of ``n`` x ``n`` points of the body frame's z = 0 plane spanning
    [-extent_rb, extent_rb] R_B in x and y: the points (n * n, 3), canonical, row-major with
    y along the rows (``reshape(n, n)`` gives an image with x across), and the mask (n * n,)
    of the points inside the body (its z = 0 cross-section)."""
    axis = np.linspace(-extent_rb, extent_rb, n) * body.brillouin_radius
    x, y = np.meshgrid(axis, axis)
    points = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    return points, points_inside(np.asarray(body.mesh.triangles), points)


def exterior_points(body: Body, max_radius: float, n: int = 1500, *, seed: int = 0) -> np.ndarray:
    """``n`` seeded points (n, 3) outside the body's mesh, canonical: random directions at radii
    uniform in (0, ``max_radius``] [canonical], so the space between the surface and the
    tracked orbits is covered down to the concavities (points inside the mesh are drawn
    again)."""
    if not max_radius > 0 or n < 1:
        raise ValueError("exterior points need a positive radius and a positive count")
    rng = np.random.default_rng(seed)
    triangles = np.asarray(body.mesh.triangles)
    kept: list[np.ndarray] = []
    total, draw = 0, 0
    while total < n:
        batch = 2 * n
        radii = rng.uniform(0.0, max_radius, batch)
        pts = shell_points(1.0, batch, seed + 1 + draw) * radii[:, None]
        pts = pts[~points_inside(triangles, pts)]
        kept.append(pts)
        total += len(pts)
        draw += 1
        if draw > 50:
            raise ValueError(f"could not place {n} points outside the body")
    return np.concatenate(kept)[:n]
