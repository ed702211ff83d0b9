"""Ballistic descents: release states, propagation to contact with the mesh, miss statistics.

A descent starts at ``release_radius_rb`` R_B from a seeded random direction, at rest in
inertial space (a hover in the body frame would put the spacecraft on an orbit whose periapsis
can clear the body), plus an inward manoeuvre of ``dv`` [m/s] (uniform in the given range, its
direction within ``cone_deg`` of the centre): the fall then takes about an hour at Itokawa, as
in the paper. It is propagated (truth or fitted model) until it touches the
surface: the time grid is scanned for the first sample inside the mesh, and the contact time is
then refined by bisection on the integrator's dense output to ``contact_tol_s``. Descents that
escape, diverge or do not touch down within ``max_duration_s`` are "not landed".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import heyoka as hy
import numpy as np

from .bodies import Body
from .meshgeom import points_inside
from .sensitivity import _StepLimit

__all__ = [
    "DescentConfig",
    "Touchdown",
    "release_states",
    "propagate_to_contact",
    "miss_statistics",
]


@dataclass(frozen=True)
class DescentConfig:
    count: int = 30
    release_radius_rb: float = 1.3
    dv_m_s: tuple[float, float] = (0.01, 0.03)
    cone_deg: float = 20.0
    max_duration_s: float = 6 * 3600.0
    check_step_s: float = 10.0
    contact_tol_s: float = 1e-3
    escape_radius_rb: float = 3.0


@dataclass(frozen=True)
class Touchdown:
    """Outcome of one descent: ``landed``, contact time (canonical) and point (canonical)."""

    landed: bool
    time: float
    point: np.ndarray
    reason: str = ""


def release_states(body: Body, config: DescentConfig = DescentConfig(), seed: int = 0):
    """Canonical release states (count, 6) and the manoeuvre sizes [m/s]."""
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


def propagate_to_contact(
    ta,
    state0,
    body: Body,
    config: DescentConfig = DescentConfig(),
    t0: float = 0.0,
    max_steps_per_chunk: int = 20_000,
) -> Touchdown:
    """Propagate ``state0`` with the scalar heyoka integrator ``ta`` (its pars already set)
    until contact with ``body``'s mesh."""
    units = body.units
    triangles = np.asarray(body.mesh.triangles)
    r_b = body.brillouin_radius
    step = float(units.to_time(config.check_step_s))
    t_end = t0 + float(units.to_time(config.max_duration_s))
    ta.time = t0
    ta.state[:] = state0
    grid = np.arange(t0, t_end + step, step)
    chunk = 200
    prev_t, prev_state = t0, np.array(state0, dtype=float)
    for start in range(0, len(grid), chunk):
        times = grid[start : start + chunk + 1]
        if len(times) < 2:
            break
        ta.time = prev_t
        ta.state[:] = prev_state
        limit = _StepLimit(max_steps_per_chunk)
        res = ta.propagate_grid(times, callback=limit)
        states = res[-1]
        if limit.exceeded:
            n_ok = len(states)
            return Touchdown(False, float(times[max(n_ok - 1, 0)]), prev_state[:3], "diverged")
        n_ok = len(states)
        finite = np.all(np.isfinite(states), axis=1)
        r = np.linalg.norm(states[:, :3], axis=1)
        close = np.flatnonzero(finite & (r < r_b))
        inside = np.zeros(n_ok, bool)
        if len(close):
            inside[close] = points_inside(triangles, states[close, :3])
        hit = np.flatnonzero(inside)
        bad = np.flatnonzero(~finite | (r > config.escape_radius_rb * r_b))
        first_bad = bad[0] if len(bad) else n_ok
        if len(hit) and hit[0] < first_bad:
            k = hit[0]
            return _refine(ta, times[k - 1], states[k - 1], times[k], triangles, config, units)
        if len(bad):
            return Touchdown(
                False,
                float(times[first_bad]),
                states[first_bad, :3],
                "escaped" if np.isfinite(r[first_bad]) else "diverged",
            )
        if res[0] != hy.taylor_outcome.time_limit or n_ok < len(times):
            return Touchdown(False, float(times[n_ok - 1]), states[n_ok - 1, :3], "diverged")
        prev_t, prev_state = times[-1], states[-1].copy()
        if prev_t >= t_end:
            break
    return Touchdown(False, float(prev_t), prev_state[:3], "timed out")


def _refine(ta, t_out, state_out, t_in, triangles, config, units) -> Touchdown:
    """Bisect the contact time between an outside and an inside sample."""
    tol = float(units.to_time(config.contact_tol_s))
    lo, hi = float(t_out), float(t_in)
    lo_state = np.array(state_out, dtype=float)
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        ta.time = lo
        ta.state[:] = lo_state
        ta.propagate_until(mid)
        if points_inside(triangles, ta.state[None, :3].copy())[0]:
            hi = mid
        else:
            lo, lo_state = mid, ta.state.copy()
    return Touchdown(True, hi, lo_state[:3].copy(), "")


def miss_statistics(truth: list[Touchdown], model: list[Touchdown], length_m: float) -> dict:
    """Miss distances [m] between predicted and true contact points, over descents that land
    under both; median, 90th percentile, worst and the landed count."""
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
