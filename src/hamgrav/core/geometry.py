"""Vectorised point-in-mesh tests for closed triangle meshes (plain numpy arrays, canonical or
any consistent length unit).

trimesh's ray-based ``contains`` without embree needs minutes for the ~10^5 points of a volume
sampling; here a vertical ray is cast from every query point and the crossings with the mesh are
counted in numpy. Points sharing an (x, y) column share the crossing computation, so a whole
voxel grid costs one 2-D triangle test per column. Measured on the 120k-point volume fill of
the synthetic body: 0.5 s here against 45 s for trimesh's ray ``contains`` (no embree).
"""

from __future__ import annotations

import numpy as np

__all__ = ["column_crossings", "points_inside", "grid_inside"]


def column_crossings(triangles: np.ndarray, columns: np.ndarray, chunk: int = 512):
    """Heights at which vertical lines through ``columns`` (c, 2) cross ``triangles`` (f, 3, 3).

    Returns ``(column_index, z)`` arrays of all crossings.
    """
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    tmin = triangles[:, :, :2].min(axis=1)
    tmax = triangles[:, :, :2].max(axis=1)
    # 2-D barycentric set-up of every triangle's xy projection.
    v0 = (b - a)[:, :2]
    v1 = (c - a)[:, :2]
    det = v0[:, 0] * v1[:, 1] - v0[:, 1] * v1[:, 0]
    good = np.abs(det) > 1e-300  # vertical triangles have no crossing of measure > 0
    idx_out, z_out = [], []
    order = np.argsort(tmin[:, 0])
    sorted_min_x = tmin[order, 0]
    for start in range(0, len(columns), chunk):
        cols = columns[start : start + chunk]
        # triangles whose x-range can reach this chunk of columns
        hi = np.searchsorted(sorted_min_x, cols[:, 0].max(), side="right")
        cand = order[:hi]
        cand = cand[(tmax[cand, 0] >= cols[:, 0].min()) & good[cand]]
        if len(cand) == 0:
            continue
        px = cols[:, None, 0] - a[None, cand, 0]
        py = cols[:, None, 1] - a[None, cand, 1]
        d = det[cand][None, :]
        u = (px * v1[None, cand, 1] - py * v1[None, cand, 0]) / d
        v = (v0[None, cand, 0] * py - v0[None, cand, 1] * px) / d
        hit = (u >= 0) & (v >= 0) & (u + v <= 1)
        ci, ti = np.nonzero(hit)
        tri = cand[ti]
        z = a[tri, 2] + u[ci, ti] * (b[tri, 2] - a[tri, 2]) + v[ci, ti] * (c[tri, 2] - a[tri, 2])
        idx_out.append(ci + start)
        z_out.append(z)
    if not idx_out:
        return np.zeros(0, int), np.zeros(0)
    return np.concatenate(idx_out), np.concatenate(z_out)


def _count_above(col_index, z_cross, n_columns, point_col, point_z):
    """Number of crossings above each point, in its own column (vectorised).

    Crossings and points are ordered by one composite key, column + scaled height in [0.25,
    0.75], so a single searchsorted finds each point's place among its column's crossings.
    """
    zmin = min(z_cross.min(initial=np.inf), point_z.min())
    span = max(z_cross.max(initial=-np.inf), point_z.max()) - zmin + 1e-300
    cross_key = np.sort(col_index * 1.0 + 0.25 + 0.5 * (z_cross - zmin) / span)
    point_key = point_col * 1.0 + 0.25 + 0.5 * (point_z - zmin) / span
    column_end = np.searchsorted(cross_key, np.arange(n_columns) + 1.0)
    return column_end[point_col] - np.searchsorted(cross_key, point_key, side="right")


def points_inside(triangles: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Boolean mask of ``points`` (n, 3) inside the closed surface ``triangles`` (f, 3, 3)."""
    points = np.asarray(points, dtype=float)
    if len(points) == 0:
        return np.zeros(0, bool)
    columns, point_col = np.unique(points[:, :2], axis=0, return_inverse=True)
    point_col = point_col.ravel()
    col_index, z_cross = column_crossings(triangles, columns)
    counts = _count_above(col_index, z_cross, len(columns), point_col, points[:, 2])
    return counts % 2 == 1


def grid_inside(triangles: np.ndarray, pitch: float) -> np.ndarray:
    """Centres of the cubic grid cells of size ``pitch`` lying inside the surface, (n, 3).

    The grid is offset by an irrational fraction of the pitch so that no vertical line passes
    exactly through a mesh vertex or edge.
    """
    lo = triangles.reshape(-1, 3).min(axis=0)
    hi = triangles.reshape(-1, 3).max(axis=0)
    offset = pitch * np.array([0.5 + 1e-3 * np.sqrt(2), 0.5 + 1e-3 * np.sqrt(3), 0.5])
    axes = [np.arange(lo[i] + offset[i], hi[i], pitch) for i in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    return grid[points_inside(triangles, grid)]
