"""Gravity fields of mascon sets and the paper's field-error metrics (canonical units).

Sign convention: the potential is positive, V(q) = sum_i m_i / |q - q_i|, so that the
Hamiltonian carries ``-V`` and the acceleration is ``grad V``. The perturbing potential is
V minus the central term 1/r (masses sum to 1).
"""

from __future__ import annotations

import numpy as np

from .interiors import MasconSet

__all__ = [
    "mascon_potential",
    "mascon_acceleration",
    "perturbing_potential",
    "shell_points",
    "relative_field_error",
    "perturbation_ratio",
]

_CHUNK_ELEMENTS = 4_000_000  # points x mascons per block: bounded memory, vectorised inner loop


def _blocks(n_points: int, n_mascons: int):
    step = max(1, _CHUNK_ELEMENTS // max(1, n_mascons))
    for start in range(0, n_points, step):
        yield slice(start, min(start + step, n_points))


def mascon_potential(mascons: MasconSet, points: np.ndarray) -> np.ndarray:
    """V(q) = sum m_i / |q - q_i| at ``points`` (n, 3); returns (n,)."""
    points = np.atleast_2d(np.asarray(points, dtype=float))
    out = np.empty(len(points))
    for sl in _blocks(len(points), len(mascons)):
        d = points[sl, None, :] - mascons.positions[None, :, :]
        out[sl] = (mascons.masses / np.sqrt(np.einsum("ijk,ijk->ij", d, d))).sum(axis=1)
    return out


def mascon_acceleration(mascons: MasconSet, points: np.ndarray) -> np.ndarray:
    """a(q) = grad V = -sum m_i (q - q_i) / |q - q_i|^3 at ``points`` (n, 3); returns (n, 3)."""
    points = np.atleast_2d(np.asarray(points, dtype=float))
    out = np.empty((len(points), 3))
    for sl in _blocks(len(points), len(mascons)):
        d = points[sl, None, :] - mascons.positions[None, :, :]
        r2 = np.einsum("ijk,ijk->ij", d, d)
        w = mascons.masses / (r2 * np.sqrt(r2))
        out[sl] = -np.einsum("ij,ijk->ik", w, d)
    return out


def central_potential(points: np.ndarray) -> np.ndarray:
    """1/r of the unit point mass at the origin."""
    return 1.0 / np.linalg.norm(np.atleast_2d(points), axis=1)


def perturbing_potential(mascons: MasconSet, points: np.ndarray) -> np.ndarray:
    """V - 1/r: the part of the field a correction term has to represent."""
    return mascon_potential(mascons, points) - central_potential(points)


def shell_points(radius: float, n: int = 500, seed: int = 0) -> np.ndarray:
    """``n`` seeded random directions (uniform on the sphere) at ``radius``; (n, 3)."""
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(n, 3))
    return radius * u / np.linalg.norm(u, axis=1, keepdims=True)


def relative_field_error(v_model: np.ndarray, v_truth: np.ndarray) -> float:
    """eps = sqrt(sum (V_model - V_truth)^2 / sum V_truth^2) over an evaluation set.

    0 is a perfect recovery; 1 is the error of no correction at all (V_model = 0).
    """
    v_model = np.asarray(v_model, dtype=float)
    v_truth = np.asarray(v_truth, dtype=float)
    if v_model.shape != v_truth.shape:
        raise ValueError(f"shape mismatch: model {v_model.shape} vs truth {v_truth.shape}")
    return float(np.sqrt(np.sum((v_model - v_truth) ** 2) / np.sum(v_truth**2)))


def perturbation_ratio(mascons: MasconSet, points: np.ndarray) -> float:
    """Median of |a_perturbing| / |a_central| over ``points``."""
    points = np.atleast_2d(points)
    a_total = mascon_acceleration(mascons, points)
    r = np.linalg.norm(points, axis=1, keepdims=True)
    a_central = -points / r**3
    ratio = np.linalg.norm(a_total - a_central, axis=1) / np.linalg.norm(a_central, axis=1)
    return float(np.median(ratio))
