"""Ballistic descents: release states, propagation to contact with the mesh, miss statistics.

A descent starts at ``release_radius_rb`` R_B from a seeded random direction, at rest in
inertial space (a hover in the body frame would put the spacecraft on an orbit whose periapsis
can clear the body), plus an inward manoeuvre of ``dv`` [m/s] (uniform in the given range, its
direction within ``cone_deg`` of the centre): the fall then takes about an hour at Itokawa, as
in the paper. It is propagated (truth or fitted model) until it touches the surface
(:func:`hamgrav.core.propagation.propagate_to_contact`). Descents that escape, diverge or do
not touch down within ``max_duration_s`` are "not landed".

:func:`tracked_descents` turns descents simulated under the truth into tracking data: each
descent is one arc of the orbital arcs' sample count and cadence, ending at contact, observed
with the same noise model (:func:`hamgrav.sim.tracking.observe`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..bodies.catalogue import Body
from ..bodies.interiors import Truth
from ..core.arcs import Arcs
from ..core.model import DEFAULT_FIT_TOLERANCE, TRUTH_TOLERANCE, Model
from ..core.propagation import Touchdown, propagate_scalar, propagate_to_contact
from ..errors import InputError, SimulationError
from .tracking import TrackingConfig, observe, simulated_arcs_fields

__all__ = [
    "DescentConfig",
    "Touchdown",
    "release_states",
    "descend",
    "tracked_descents",
    "DESCENT_SPANS",
    "miss_statistics",
]

#: How a tracked descent's arc covers the fall: "end", its last samples at the tracking
#: cadence, ending at contact; "whole", its samples spread from release to contact.
DESCENT_SPANS = ("end", "whole")


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


def tracked_descents(
    truth: Truth,
    count: int,
    descents: DescentConfig = DescentConfig(),
    tracking: TrackingConfig | None = None,
    *,
    seed: int = 0,
    max_draws: int | None = None,
    span: str = "end",
) -> Arcs:
    """``count`` descents flown under ``truth`` and tracked as one arc each.

    Release states are drawn as in :func:`release_states` (seeded by ``seed``; the first
    ``count`` draws are those of a draw of ``count``) and propagated under the truth to
    contact. A descent that does not land, or lands less than one arc's length
    (``samples_per_arc - 1`` times ``cadence_s``) after release, is skipped and the next draw
    taken (at most ``max_draws``, default ``count + tracking.max_redraws``). ``tracking``
    (default :class:`~hamgrav.sim.tracking.TrackingConfig`) gives the orbital arcs'
    samples per arc, cadence and noise. With ``span`` "end" each arc holds
    ``samples_per_arc`` samples ``cadence_s`` [s] apart, the last at the contact time; with
    "whole" it holds ``samples_per_arc`` samples evenly spaced from release to contact (the
    whole fall, from the release radius down to the surface). Observed with the orbital arcs'
    noise (sigma_r = ``tracking.sigma_r_m`` [m] per position component,
    sigma_v = omega sigma_r ``velocity_noise_ratio``), noise seeded by (``seed``, 1).

    Returns canonical :class:`Arcs` (trajectory kind "descent"); ``trajectory_info`` holds per
    descent its ``initial_state`` (canonical release state), ``release_radius_rb`` [R_B],
    ``dv_m_s`` [m/s], ``duration_s`` (release to contact [s]), ``contact_point`` (canonical)
    and ``draw`` (index among the release draws).
    """
    if count < 1:
        raise InputError(f"count must be at least 1, got {count}")
    if span not in DESCENT_SPANS:
        raise InputError(f"span must be one of {', '.join(DESCENT_SPANS)}, got {span!r}")
    tracking = TrackingConfig() if tracking is None else tracking
    body = truth.body
    units = body.units
    max_draws = count + tracking.max_redraws if max_draws is None else int(max_draws)
    release, dvs = release_states(body, replace(descents, count=max(max_draws, count)), seed)
    cadence = float(units.to_time(tracking.cadence_s))
    offsets = cadence * np.arange(tracking.samples_per_arc)
    kept, times, true_states, contacts = [], [], [], []
    for k, state0 in enumerate(release):
        if len(kept) == count:
            break
        (td,) = descend(truth.model, [], state0[None], body, descents, tol=TRUTH_TOLERANCE)
        if not td.landed or td.time < offsets[-1]:
            continue
        if span == "whole":
            grid = np.linspace(0.0, td.time, tracking.samples_per_arc)
        else:
            grid = td.time - offsets[::-1]
        states, ok = propagate_scalar(truth.model, state0, grid, tol=TRUTH_TOLERANCE)
        if not ok or not np.all(np.isfinite(states)):
            continue
        kept.append(k)
        times.append(grid)
        true_states.append(states)
        contacts.append(td)
    if len(kept) < count:
        raise SimulationError(
            f"only {len(kept)} of {max_draws} descents landed at least one arc's length after "
            f"release; {count} were asked for"
        )
    sigma_r = float(units.to_length(tracking.sigma_r_m))
    sigma_v = tracking.velocity_noise_ratio * sigma_r  # omega = 1 in canonical units
    true_states = np.stack(true_states)
    noisy = observe(true_states, sigma_r, sigma_v, np.random.default_rng([seed, 1]))
    info = {
        "initial_state": release[kept],
        "release_radius_rb": np.full(count, descents.release_radius_rb),
        "dv_m_s": dvs[kept],
        "duration_s": np.array([td.time for td in contacts]) * units.time_s,
        "contact_point": np.array([td.point for td in contacts]),
        "draw": np.asarray(kept),
    }
    return Arcs(
        times=np.stack(times),
        states=noisy,
        true_states=true_states,
        trajectory=np.arange(count, dtype=np.int64),
        trajectory_kind=tuple("descent" for _ in kept),
        trajectory_info=info,
        **simulated_arcs_fields(truth, tracking.sigma_r_m, tracking.velocity_noise_ratio, seed),
        config={
            "descents": count,
            "release_radius_rb": descents.release_radius_rb,
            "span": span,
        },
    )


def miss_statistics(truth: list[Touchdown], model: list[Touchdown], length_m: float) -> dict:
    """Miss distances [m] between predicted and true contact points, over descents that land
    under both; median, 90th percentile, worst [m], the landed count and the total.
    ``length_m`` is the canonical length unit [m] (the points are canonical)."""
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
