"""Ballistic descents: release states, propagation to contact with the mesh, miss statistics.

A descent starts at ``release_radius_rb`` R_B from a seeded random direction, at rest in
inertial space (a hover in the body frame would put the spacecraft on an orbit whose periapsis
can clear the body), plus an inward manoeuvre of ``dv`` [m/s] (uniform in the given range, its
direction within ``cone_deg`` of the centre): the fall then takes about an hour at Itokawa, as
in the paper. It is propagated (truth or fitted model) until it touches the surface
(:func:`hamgrav.core.propagation.propagate_to_contact`). Descents that escape, diverge or do
not touch down within ``max_duration_s`` are "not landed".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..bodies.catalogue import Body
from ..core.model import DEFAULT_FIT_TOLERANCE, Model
from ..core.propagation import Touchdown, propagate_to_contact

__all__ = ["DescentConfig", "Touchdown", "release_states", "descend", "miss_statistics"]


@dataclass(frozen=True)
class DescentConfig:
    """Descent settings (physical units): ``count`` descents released at
    ``release_radius_rb`` [R_B] with inward manoeuvres in ``dv_m_s`` [m/s] within
    ``cone_deg`` [deg] of the centre; at most ``max_duration_s`` [s], contact checked every
    ``check_step_s`` [s] and refined to ``contact_tol_s`` [s]; beyond ``escape_radius_rb``
    [R_B] a descent has escaped."""

    count: int = 30
    release_radius_rb: float = 1.3
    dv_m_s: tuple[float, float] = (0.01, 0.03)
    cone_deg: float = 20.0
    max_duration_s: float = 6 * 3600.0
    check_step_s: float = 10.0
    contact_tol_s: float = 1e-3
    escape_radius_rb: float = 3.0


def release_states(body: Body, config: DescentConfig = DescentConfig(), seed: int = 0):
    """Canonical release states (count, 6) and the manoeuvre sizes [m/s] (count,)."""
    rng = np.random.default_rng(seed)
    units = body.units
    r0 = config.release_radius_rb * body.brillouin_radius
    states, dvs = [], []
    for _ in range(config.count):
        u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        q = r0 * u
        # inward direction tilted by up to cone_deg
        tilt = rng.normal(size=3)
        tilt -= (tilt @ u) * u
        tilt /= np.linalg.norm(tilt)
        angle = math.radians(config.cone_deg) * math.sqrt(rng.uniform())
        direction = -math.cos(angle) * u + math.sin(angle) * tilt
        dv = rng.uniform(*config.dv_m_s)
        # canonical momentum = inertial velocity in body axes
        p = float(units.to_velocity(dv)) * direction
        states.append(np.concatenate([q, p]))
        dvs.append(dv)
    return np.array(states), np.array(dvs)


def descend(
    model: Model,
    params,
    release: np.ndarray,
    body: Body,
    config: DescentConfig = DescentConfig(),
    *,
    tol: float = DEFAULT_FIT_TOLERANCE,
) -> list[Touchdown]:
    """Propagate each canonical release state (n, 6) under ``model`` at runtime parameters
    ``params`` to contact with ``body``'s mesh (canonical, the body's frame)."""
    units = body.units
    triangles = np.asarray(body.mesh.triangles)
    settings = {
        "check_step": float(units.to_time(config.check_step_s)),
        "duration": float(units.to_time(config.max_duration_s)),
        "escape_radius": config.escape_radius_rb * body.brillouin_radius,
        "contact_tol": float(units.to_time(config.contact_tol_s)),
        "bound_radius": body.brillouin_radius,
    }
    params = np.asarray(params, dtype=float)[: model.n_system_params]
    return [
        propagate_to_contact(model, s, triangles, params=params, tol=tol, **settings)
        for s in release
    ]


def miss_statistics(truth: list[Touchdown], model: list[Touchdown], length_m: float) -> dict:
    """Miss distances [m] between predicted and true contact points, over descents that land
    under both; median, 90th percentile, worst [m], the landed count and the total."""
    misses = [
        float(np.linalg.norm(m.point - t.point)) * length_m
        for t, m in zip(truth, model, strict=True)
        if t.landed and m.landed
    ]
    total = sum(t.landed for t in truth)
    if not misses:
        return {
            "median_m": None,
            "p90_m": None,
            "worst_m": None,
            "landed": 0,
            "total": total,
            "misses_m": [],
        }
    return {
        "median_m": float(np.median(misses)),
        "p90_m": float(np.percentile(misses, 90)),
        "worst_m": float(np.max(misses)),
        "landed": len(misses),
        "total": total,
        "misses_m": misses,
    }
