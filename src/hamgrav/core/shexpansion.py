"""Spherical-harmonic tables of a model's exterior potential (canonical units, no I/O).

Convention (geodesy; heyoka ``model.sh_gravity_pot``; ICGEM and SHADR files): 4-pi fully
normalised associated Legendre functions without the Condon-Shortley phase, P_lm(sin lat),
and the positive exterior potential

    V(r, lat, lon) = mu / r * sum_{l=0..L} (R / r)^l sum_{m=0..l} P_lm(sin lat)
                     (C_lm cos(m lon) + S_lm sin(m lon)),

with ``mu`` the gravitational parameter the table is scaled by (1 = the body's GM in
canonical units) and ``R`` the reference radius. Tables are (L + 1, L + 1) arrays indexed
[l, m]; S[l, 0] = 0.

Where the coefficients come from:

- a point mass mu at the origin: C00 = mu;
- a mascon set: exact, C_lm + i S_lm = sum_i m_i (r_i / R)^l P_lm(sin lat_i) e^{i m lon_i}
  / (2 l + 1), degrees 0..L (a truncation of the infinite series);
- a learnable SH term: its own coefficients, rescaled to another reference radius R' by
  (R / R')^l (its ``mu`` times the table);
- anything else (a network): :func:`project_on_sphere`, the Gauss-Legendre quadrature of the
  potential on the sphere of radius R against each P_lm cos / sin (exact for degrees up to L
  of a band-limited function; a network is not band-limited, and its field is not exactly
  harmonic, so the projection has an error that :func:`relative_rms` measures).
"""

from __future__ import annotations

import math

import numpy as np

from .mascons import MasconSet
from .terms import SphericalHarmonics, _normalised_legendre, sh_index

__all__ = [
    "empty_tables",
    "mascon_tables",
    "sh_term_tables",
    "sh_potential",
    "quadrature_points",
    "project_on_sphere",
    "relative_rms",
]


def empty_tables(degree: int) -> tuple[np.ndarray, np.ndarray]:
    """Zero (C, S) tables of shape (degree + 1, degree + 1)."""
    return np.zeros((degree + 1, degree + 1)), np.zeros((degree + 1, degree + 1))


def _spherical(points: np.ndarray):
    points = np.atleast_2d(np.asarray(points, dtype=float))
    r = np.linalg.norm(points, axis=1)
    sin_lat = np.clip(points[:, 2] / r, -1.0, 1.0)
    lon = np.arctan2(points[:, 1], points[:, 0])
    return r, sin_lat, lon


def mascon_tables(mascons: MasconSet, degree: int, reference_radius: float):
    """Exact (C, S) of a mascon set's exterior potential, degrees 0..``degree``, scaled by
    mu = 1 (masses in units of the body's GM; the module docstring gives the formula)."""
    c, s = empty_tables(degree)
    if len(mascons) == 0:
        return c, s
    r, sin_lat, lon = _spherical(mascons.positions)
    p = _normalised_legendre(degree, sin_lat)
    for l in range(degree + 1):
        radial = mascons.masses * (r / reference_radius) ** l / (2 * l + 1)
        for m in range(l + 1):
            c[l, m] = float(np.sum(radial * p[l, m] * np.cos(m * lon)))
            s[l, m] = float(np.sum(radial * p[l, m] * np.sin(m * lon))) if m else 0.0
    return c, s


def sh_term_tables(term: SphericalHarmonics, params, degree: int, reference_radius: float):
    """(C, S) of a learnable SH term with parameters ``params`` (its layout), at reference
    radius ``reference_radius`` and scaled by mu = 1, degrees 0..``degree`` (degrees above
    ``degree`` are dropped; ``degree`` >= the term's keeps them all)."""
    c, s = empty_tables(degree)
    params = np.asarray(params, dtype=float)
    ratio = term.reference_radius / reference_radius
    for k, (kind, l, m) in enumerate(sh_index(term.degree)):
        if l > degree:
            continue
        value = term.mu * params[k] * ratio**l
        if kind == "C":
            c[l, m] = value
        else:
            s[l, m] = value
    return c, s


def sh_potential(c: np.ndarray, s: np.ndarray, reference_radius: float, points, mu=1.0):
    """V (n,) of the table (C, S) at ``points`` (n, 3) (module-docstring formula; a numpy
    reference independent of heyoka's Cunningham recursion)."""
    degree = c.shape[0] - 1
    r, sin_lat, lon = _spherical(points)
    p = _normalised_legendre(degree, sin_lat)
    total = np.zeros(len(r))
    for l in range(degree + 1):
        inner = np.zeros(len(r))
        for m in range(l + 1):
            inner += p[l, m] * (c[l, m] * np.cos(m * lon) + s[l, m] * np.sin(m * lon))
        total += (reference_radius / r) ** l * inner
    return mu / r * total


def quadrature_points(degree: int, reference_radius: float, n_lat: int | None = None):
    """Gauss-Legendre nodes on the sphere of ``reference_radius``: points (n, 3), weights (n,)
    summing to 4 pi. ``n_lat`` latitude rings (default 2 degree + 34) and 2 n_lat longitudes."""
    n_lat = int(n_lat or 2 * degree + 34)
    x, w = np.polynomial.legendre.leggauss(n_lat)  # x = sin(latitude)
    n_lon = 2 * n_lat
    lon = 2.0 * math.pi * np.arange(n_lon) / n_lon
    cos_lat = np.sqrt(1.0 - x * x)
    pts = reference_radius * np.stack(
        [
            np.outer(cos_lat, np.cos(lon)).ravel(),
            np.outer(cos_lat, np.sin(lon)).ravel(),
            np.repeat(x, n_lon),
        ],
        axis=1,
    )
    weights = np.repeat(w, n_lon) * (2.0 * math.pi / n_lon)
    return pts, weights


def project_on_sphere(potential, degree: int, reference_radius: float, n_lat: int | None = None):
    """(C, S), degrees 0..``degree`` and mu = 1, whose exterior field equals ``potential`` (a
    callable: points (n, 3) -> V (n,), canonical) on the sphere of ``reference_radius``, by
    Gauss-Legendre quadrature (:func:`quadrature_points`): C_lm = R / (4 pi) * integral of
    V P_lm cos(m lon) over the sphere (S_lm with sin)."""
    pts, weights = quadrature_points(degree, reference_radius, n_lat)
    values = np.asarray(potential(pts), dtype=float) * weights
    _, sin_lat, lon = _spherical(pts)
    p = _normalised_legendre(degree, sin_lat)
    c, s = empty_tables(degree)
    scale = reference_radius / (4.0 * math.pi)
    for l in range(degree + 1):
        for m in range(l + 1):
            c[l, m] = scale * float(np.sum(values * p[l, m] * np.cos(m * lon)))
            if m:
                s[l, m] = scale * float(np.sum(values * p[l, m] * np.sin(m * lon)))
    return c, s


def relative_rms(approx: np.ndarray, reference: np.ndarray) -> float:
    """sqrt(sum (approx - reference)^2 / sum reference^2) (dimensionless; 0 when both are 0)."""
    num = float(np.sum((np.asarray(approx) - np.asarray(reference)) ** 2))
    den = float(np.sum(np.asarray(reference) ** 2))
    return math.sqrt(num / den) if den > 0 else math.sqrt(num)
