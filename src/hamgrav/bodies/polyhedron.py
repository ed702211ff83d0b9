"""The exact constant-density polyhedron potential (package ``polyhedral-gravity``), canonical.

The reference for every constant-density field in hamgrav: the uniform truth is checked against
it and the shape prior is fitted to it. The body meshes are consistently wound outward but
polyhedral-gravity's integrity check mis-flags facets of concave meshes (and ``HEAL`` then
corrupts the potential), so the check is disabled and the orientation stated.
"""

from __future__ import annotations

import numpy as np
import polyhedral_gravity as pg

from .catalogue import Body

__all__ = ["polyhedron_potential"]


def polyhedron_potential(body: Body, points: np.ndarray) -> np.ndarray:
    """Potential V > 0 of the body's shape filled at constant density with unit total mass,
    at ``points`` (n, 3) [canonical length]; returns (n,) [canonical potential] (the
    convention of :mod:`hamgrav.core.fields`)."""
    mesh = body.mesh
    polyhedron = pg.Polyhedron(
        (np.asarray(mesh.vertices), np.asarray(mesh.faces)),
        1.0,
        normal_orientation=pg.NormalOrientation.OUTWARDS,
        integrity_check=pg.PolyhedronIntegrity.DISABLE,
        metric_unit=pg.MetricUnit.UNITLESS,
    )
    points = np.atleast_2d(np.asarray(points, dtype=float))
    results = pg.evaluate(polyhedron, points, parallel=True)
    potential = np.array([r[0] for r in results])
    # UNITLESS input: no G, density 1 -> divide by the volume for unit mass. Sign follows the
    # package's geodetic convention (positive); checked against 1/r far away in the tests.
    return potential / body.volume
