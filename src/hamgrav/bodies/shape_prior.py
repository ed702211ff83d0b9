"""The imaged shape at constant density, compressed to a few mascons (a known term).

Positions: k-means centroids of the shape's volume. Masses: non-negative least squares against
the exact constant-density polyhedron potential sampled between 1.02 and 1.8 R_B (relative
residuals), with the total mass held at 1 by a heavily weighted extra row. The fit is made in
the frame of the constant-density centre of mass, so the prior's origin is its own centre of
mass (exactly, after a final sub-millimetre shift), as the paper's residual architecture needs.
"""

from __future__ import annotations

import hashlib

import numpy as np
from scipy.optimize import nnls

from ..core.fields import relative_field_error, shell_points
from ..core.mascons import MasconSet, mascon_potential
from ..errors import InputError
from .catalogue import Body
from .interiors import kmeans_labels, volume_samples
from .polyhedron import polyhedron_potential

__all__ = ["fit_shape_prior", "centred_shape_prior", "DEFAULT_PRIOR_MASCONS"]

DEFAULT_PRIOR_MASCONS = 200


def fit_shape_prior(
    body: Body,
    n_mascons: int = DEFAULT_PRIOR_MASCONS,
    *,
    seed: int = 0,
    n_fit_points: int | None = None,
    radii_rb: tuple[float, float] = (1.02, 1.8),
    samples: int = 60_000,
) -> tuple[MasconSet, dict]:
    """Fit the shape prior of ``body`` (canonical units).

    Returns the mascons, expressed in ``body``'s frame (their centre of mass at the shape's
    constant-density centre of mass), and a report of how well they reproduce the polyhedron.
    For the residual architecture, use :func:`centred_shape_prior`.
    """
    if n_mascons < 1:
        raise InputError("the shape prior needs at least one mascon")
    com = body.constant_density_centre_of_mass
    centred = body.recentred(com)
    points = volume_samples(centred, samples)
    labels = kmeans_labels(points, min(n_mascons, len(points)), seed=seed)
    counts = np.bincount(labels)
    centroids = np.stack(
        [np.bincount(labels, weights=points[:, i]) / counts for i in range(3)], axis=1
    )
    rng = np.random.default_rng(seed)
    n_fit = n_fit_points or max(2000, 4 * n_mascons)
    r_b = centred.brillouin_radius
    radii = rng.uniform(*radii_rb, n_fit) * r_b
    fit_points = shell_points(1.0, n_fit, seed) * radii[:, None]
    target = polyhedron_potential(centred, fit_points)
    design = 1.0 / np.linalg.norm(fit_points[:, None, :] - centroids[None], axis=2)
    design /= target[:, None]  # relative residuals
    weight = 1e3 * np.sqrt(n_fit)
    a = np.vstack([design, weight * np.ones((1, len(centroids)))])
    b = np.concatenate([np.ones(n_fit), [weight]])
    masses, _ = nnls(a, b, maxiter=50 * len(centroids))
    keep = masses > 0
    masses = masses[keep] / masses[keep].sum()
    prior = MasconSet(centroids[keep], masses)
    prior = prior.translated(-prior.centre_of_mass)

    report = {"n_mascons": int(keep.sum()), "n_requested": n_mascons, "seed": seed}
    for s in (1.05, 1.2, 1.5):
        pts = shell_points(s * r_b, 400, seed + 1)
        v_poly = polyhedron_potential(centred, pts)
        v_prior = mascon_potential(prior, pts)
        central = 1.0 / np.linalg.norm(pts, axis=1)
        report[f"perturbing_error_r{s}"] = relative_field_error(v_prior - central, v_poly - central)
    return prior.translated(com), report


#: Priors already fitted in this process: every model of a campaign fitted on the prior (SH
#: degrees, networks) shares one, and the fit takes seconds (k-means, polyhedron, NNLS).
_CENTRED_PRIORS: dict[tuple, tuple[MasconSet, dict]] = {}


def centred_shape_prior(
    body: Body, n_mascons: int = DEFAULT_PRIOR_MASCONS, *, seed: int = 0
) -> tuple[MasconSet, dict]:
    """The shape prior centred on its own centre of mass (the origin of the arcs' frame, as
    the paper's residual architecture needs), and its report (see :func:`fit_shape_prior`);
    fitted once per body, frame, mascon count and seed in a process."""
    mesh = body.mesh_m
    geometry = hashlib.sha1(
        np.ascontiguousarray(mesh.vertices, dtype=float).tobytes()
        + np.ascontiguousarray(mesh.faces, dtype=np.int64).tobytes()
    ).hexdigest()
    key = (body.name, body.gm_m3_s2, body.spin_period_s, tuple(body.origin_m), geometry)
    key += (int(n_mascons), int(seed))
    if key not in _CENTRED_PRIORS:
        mascons, report = fit_shape_prior(body, n_mascons, seed=seed)
        _CENTRED_PRIORS[key] = (mascons.translated(-mascons.centre_of_mass), report)
    mascons, report = _CENTRED_PRIORS[key]
    return mascons, dict(report)
