"""Evaluation point sets of a body: shells, surface-following sets, radial bins of a set and
equatorial-plane grids (canonical points); and the field errors of fitted models against a
truth interior on them (deep-region bins, equatorial maps): simulation scores, for
experiments only, since a user has no truth."""

from __future__ import annotations

import numpy as np

from ..core.fields import field_errors, pointwise_field_errors, shell_points
from ..core.geometry import points_inside
from .catalogue import Body
from .interiors import Truth

__all__ = [
    "evaluation_sets",
    "set_label",
    "bin_label",
    "radial_bins",
    "equatorial_grid",
    "exterior_points",
    "significant",
    "deep_set",
    "deep_bin_errors",
    "equatorial_error_map",
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


def significant(x: float) -> float | None:
    """A finite error rounded to 4 significant digits, or None (empty set, overflow)."""
    return float(f"{x:.4g}") if np.isfinite(x) else None


def deep_set(body: Body, altitude_m: float, seed: int) -> np.ndarray:
    """The deep set: the surface-following points ``altitude_m`` [m] above the surface that
    lie inside the Brillouin sphere (n, 3) [canonical] (seeded as :func:`evaluation_sets`)."""
    surface = evaluation_sets(body, (), (altitude_m,), seed=seed)[f"h{altitude_m:g}m"]
    return surface[np.linalg.norm(surface, axis=1) < body.brillouin_radius]


def deep_bin_errors(fitted: dict, truth: Truth, altitude_m: float, bins_rb, seed: int) -> dict:
    """Relative field errors of fitted models ({name: (model, params)}) against ``truth`` on
    the surface-following set ``altitude_m`` [m] above the surface: ``deep_error`` (the
    points inside the Brillouin sphere), ``deep_bins`` ({model: {bin: error}} over the radial
    bins between ``bins_rb`` [R_B], None for an empty bin) and ``deep_bin_points`` ({bin:
    points}). Errors are rounded to 4 decimals, then to 4 significant digits."""
    body = truth.body
    surface = evaluation_sets(body, (), (altitude_m,), seed=seed)[f"h{altitude_m:g}m"]
    inside_rb = deep_set(body, altitude_m, seed)
    bins = radial_bins(surface, body.brillouin_radius, bins_rb)
    filled = {k: v for k, v in bins.items() if len(v)}
    out: dict = {
        "deep_error": {},
        "deep_bins": {},
        "deep_bin_points": {k: int(len(v)) for k, v in bins.items()},
    }
    for name, (model, params) in fitted.items():
        errors = field_errors(model, params, truth.mascons, {"deep": inside_rb, **filled})
        deep = {k: round(v, 4) for k, v in errors.items()}
        out["deep_error"][name] = significant(deep.pop("deep"))
        out["deep_bins"][name] = {k: significant(deep[k]) if k in deep else None for k in bins}
    return out


def equatorial_error_map(
    fitted: dict, truth: Truth, extent_rb: float, n: int, patch_models
) -> dict:
    """Pointwise relative field errors of fitted models ({name: (model, params)}) against
    ``truth`` on the n x n equatorial grid out to ``extent_rb`` [R_B] (NaN inside the
    body), and the patch: the outside points where any of ``patch_models`` errs by more than
    1. ``axis_m`` is the grid's axis [m]."""
    body = truth.body
    points, inside = equatorial_grid(body, extent_rb, n)
    outside = points[~inside]
    errors = {}
    for name, (model, params) in fitted.items():
        err = np.full(len(points), np.nan)
        err[~inside] = pointwise_field_errors(model, params, truth.mascons, outside)
        errors[name] = err
    patch = np.zeros(len(points), bool)
    for name in patch_models:
        patch |= errors[name] > 1.0  # NaN (inside) compares False
    r = np.linalg.norm(points, axis=1) / body.brillouin_radius
    return {
        "errors": errors,
        "inside": inside,
        "patch": patch,
        "axis_m": np.unique(points[:, 0]) * body.units.length_m,
        "patch_points": int(patch.sum()),
        "patch_inside_brillouin": significant(np.mean(r[patch] < 1.0)) if patch.any() else None,
        "patch_median": {
            k: significant(np.median(e[patch])) if patch.any() else None for k, e in errors.items()
        },
    }
