"""Tracking simulation: orbit families, arcs, the paper's noise model, the ``Arcs`` dataset.

An orbit is started circular (in the inertial sense) at a radius given in Brillouin radii and
an inclination, with seeded random node and argument of latitude; it is propagated under the
truth over the tracking window and rejected (and redrawn) if it touches the surface or escapes.
Arcs of ``samples_per_arc`` samples at ``cadence_s`` are cut from the window, one per slot, and
observed with Gaussian noise: sigma_r per position component and sigma_v = omega sigma_r / 10
per rotating-frame velocity component; the noisy velocities are mapped to canonical momenta
with the noisy positions.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, fields

import numpy as np

from ..bodies.interiors import Truth
from ..core.arcs import Arcs
from ..core.geometry import points_inside
from ..core.model import TRUTH_TOLERANCE
from ..core.propagation import propagate_scalar
from ..errors import InputError, SimulationError
from ..units import momentum_to_velocity, velocity_to_momentum

__all__ = [
    "OrbitFamily",
    "TrackingConfig",
    "arc_start_times",
    "circular_orbit_state",
    "draw_orbit_start",
    "orbit_grid",
    "simulate_orbits",
    "simulated_arcs_fields",
    "observe",
    "MAX_ORBIT_RADIUS_RB",
]

#: Largest orbit radius [R_B] a campaign may ask for. The irregular part of the field falls
#: off at least as (R_B / r)^3 relative to the central term: at 20 R_B it is below 1e-4 of
#: the degree-2 term at the surface, and tracking there constrains nothing a fit can use
#: (an orbit at 1000 R_B gave a field error of 5e9 after the fit).
MAX_ORBIT_RADIUS_RB = 20.0


def _check_value(owner: str, name: str, value, *, integer: bool, low, high, open_low=False):
    """``value`` must be an integer (``integer``) or a finite real number in [low, high]
    ((low, high] with ``open_low``); raises :class:`InputError` naming ``owner.name``."""
    if integer:
        ok = isinstance(value, numbers.Integral) and not isinstance(value, bool)
        kind = "an integer"
    else:
        ok = isinstance(value, numbers.Real) and not isinstance(value, bool)
        ok = ok and math.isfinite(value)
        kind = "a finite number"
    if ok:
        ok = (value > low if open_low else value >= low) and value <= high
    if not ok:
        interval = f"{'(' if open_low else '['}{low:g}, {high:g}]"
        raise InputError(f"{owner} {name} must be {kind} in {interval}, got {value!r}")


@dataclass(frozen=True)
class OrbitFamily:
    """An orbit family: initial radius [R_B] and inclination [deg] of a circular start."""

    radius_rb: float
    inclination_deg: float

    def __post_init__(self) -> None:
        for name, low, high, open_low in (
            ("radius_rb", 1.0, MAX_ORBIT_RADIUS_RB, True),
            ("inclination_deg", 0.0, 180.0, False),
        ):
            _check_value(
                "orbit",
                name,
                getattr(self, name),
                integer=False,
                low=low,
                high=high,
                open_low=open_low,
            )


@dataclass(frozen=True)
class TrackingConfig:
    """How orbits are tracked (physical units at this edge).

    ``arcs_per_orbit`` arcs of ``samples_per_arc`` samples ``cadence_s`` [s] apart;
    ``window_spin_periods``: length of the tracking window of each orbit, in spin periods; the
    arcs are spread over it, one per equal slot. ``sigma_r_m``: position noise per component
    [m]; the rotating-frame velocity noise is sigma_v = ``velocity_noise_ratio`` omega sigma_r
    [m/s]. An orbit is redrawn (at most ``max_redraws`` times) when it escapes beyond
    ``escape_factor`` times its start radius, touches the surface, or dips below
    ``min_radius_rb`` [R_B] (0: off).
    """

    arcs_per_orbit: int = 7
    samples_per_arc: int = 40
    cadence_s: float = 14.0
    window_spin_periods: float = 1.0
    sigma_r_m: float = 0.05
    velocity_noise_ratio: float = 0.1  # sigma_v = omega * sigma_r * ratio
    escape_factor: float = 3.0  # escape: r > escape_factor * initial radius
    min_radius_rb: float = 0.0  # also reject orbits dipping below this radius [R_B] (0: off)
    max_redraws: int = 50

    def __post_init__(self) -> None:
        # (integer, low, high, open_low): bounds that keep the simulation meaningful and
        # finite in memory (the graze check samples the window every 0.005 time units)
        bounds = {
            "arcs_per_orbit": (True, 1, 10_000, False),
            "samples_per_arc": (True, 2, 10_000, False),
            "cadence_s": (False, 0.0, 1e6, True),
            "window_spin_periods": (False, 0.0, 100.0, True),
            "sigma_r_m": (False, 0.0, 1e4, False),
            "velocity_noise_ratio": (False, 0.0, 1e3, False),
            "escape_factor": (False, 1.0, 1e3, True),
            "min_radius_rb": (False, 0.0, MAX_ORBIT_RADIUS_RB, False),
            "max_redraws": (True, 1, 10_000, False),
        }
        for f in fields(self):
            integer, low, high, open_low = bounds[f.name]
            _check_value(
                "[tracking]",
                f.name,
                getattr(self, f.name),
                integer=integer,
                low=low,
                high=high,
                open_low=open_low,
            )


#: Step of the graze check [canonical time]: fine enough to see a graze.
GRAZE_CHECK_STEP = 0.005


def graze_check_points(tracking: TrackingConfig) -> int:
    """Points of an orbit's dense graze-check grid over its tracking window."""
    return int(2.0 * math.pi * tracking.window_spin_periods / GRAZE_CHECK_STEP) + 1


def orbit_grid(count: int, radius_rb: tuple[float, float], inclination_deg: tuple[float, float]):
    """``count`` orbit families on a radius x inclination grid spanning the given ranges.

    The grid has the most nearly square factorisation of ``count`` (16 -> 4 x 4, 48 -> 6 x 8),
    with fewer radii than inclinations.
    """
    if count < 1:
        raise InputError("orbit count must be at least 1")
    n_r = max(d for d in range(1, int(math.isqrt(count)) + 1) if count % d == 0)
    n_i = count // n_r
    radii = np.linspace(*radius_rb, n_r) if n_r > 1 else np.array([np.mean(radius_rb)])
    incl = np.linspace(*inclination_deg, n_i) if n_i > 1 else np.array([np.mean(inclination_deg)])
    return [OrbitFamily(float(r), float(i)) for r in radii for i in incl]


def circular_orbit_state(
    radius: float, inclination_rad: float, raan_rad: float, arg_lat_rad: float
):
    """Canonical (q, p) at t = 0 of a circular Keplerian orbit (mu = 1).

    At t = 0 the rotating and inertial frames coincide and p is the inertial velocity.
    """
    ci, si = math.cos(inclination_rad), math.sin(inclination_rad)
    co, so = math.cos(raan_rad), math.sin(raan_rad)
    cu, su = math.cos(arg_lat_rad), math.sin(arg_lat_rad)
    node = np.array([co, so, 0.0])
    normal_in_plane = np.array([-so * ci, co * ci, si])
    q = radius * (cu * node + su * normal_in_plane)
    v = math.sqrt(1.0 / radius) * (-su * node + cu * normal_in_plane)
    return np.concatenate([q, v])


def observe(true_states: np.ndarray, sigma_r: float, sigma_v: float, rng: np.random.Generator):
    """Noisy canonical states: position noise sigma_r, rotating-frame velocity noise sigma_v
    (canonical units), velocities mapped back to momenta with the noisy positions."""
    q = true_states[..., :3]
    v = momentum_to_velocity(q, true_states[..., 3:])
    q_obs = q + sigma_r * rng.standard_normal(q.shape)
    v_obs = v + sigma_v * rng.standard_normal(v.shape)
    return np.concatenate([q_obs, velocity_to_momentum(q_obs, v_obs)], axis=-1)


def arc_start_times(rng, n_arcs: int, window: float, arc_length: float) -> np.ndarray:
    """Start times (canonical) of ``n_arcs`` arcs of length ``arc_length``, one at a seeded
    random place in each of ``n_arcs`` equal slots of the tracking ``window``."""
    slot = window / n_arcs
    if slot < arc_length:
        raise SimulationError(
            f"the tracking window is too short for {n_arcs} arcs: each slot lasts {slot:.4g} "
            f"time units, an arc {arc_length:.4g}; lengthen window_spin_periods"
        )
    return np.arange(n_arcs) * slot + rng.uniform(0.0, slot - arc_length, size=n_arcs)


def draw_orbit_start(rng, family: OrbitFamily, brillouin_radius: float):
    """One draw of a circular start of ``family``: seeded node and argument of latitude [rad]
    and the canonical initial state (6,) at t = 0."""
    raan, arg_lat = rng.uniform(0.0, 2.0 * math.pi, size=2)
    state0 = circular_orbit_state(
        family.radius_rb * brillouin_radius, math.radians(family.inclination_deg), raan, arg_lat
    )
    return raan, arg_lat, state0


def _touches_or_escapes(truth: Truth, states: np.ndarray, escape_radius: float) -> bool:
    if not np.all(np.isfinite(states)):
        return True
    r = np.linalg.norm(states[:, :3], axis=1)
    if np.any(r > escape_radius):
        return True
    close = states[r < truth.body.brillouin_radius, :3]
    return bool(len(close) and points_inside(np.asarray(truth.body.mesh.triangles), close).any())


def simulated_arcs_fields(
    truth: Truth, sigma_r_m: float, velocity_noise_ratio: float, seed: int
) -> dict:
    """The :class:`Arcs` fields every simulator fills alike: the truth's body (name, GM
    [m^3/s^2], spin period [s], frame origin [m], and its record: mesh and provenance), the
    noise (sigma_r [m]; sigma_v [m/s] = ``velocity_noise_ratio`` x omega x sigma_r), the
    truth's mascons and interior, the seed."""
    body = truth.body
    return {
        "body_name": body.name,
        "gm_m3_s2": body.gm_m3_s2,
        "spin_period_s": body.spin_period_s,
        "body_origin_m": tuple(body.origin_m),
        "sigma_r_m": sigma_r_m,
        "sigma_v_m_s": velocity_noise_ratio * sigma_r_m * body.units.omega_rad_s,
        "truth": truth.mascons,
        "interior": truth.interior,
        "interior_parameters": dict(truth.parameters),
        "seed": seed,
        "body": body.record(),
    }


def simulate_orbits(
    truth: Truth,
    families: list[OrbitFamily],
    tracking: TrackingConfig = TrackingConfig(),
    *,
    seed: int = 0,
    progress=None,
    config: dict | None = None,
) -> Arcs:
    """Simulate the tracking of one orbit per family under ``truth``.

    ``progress``, if given, is called with (done, total) after each orbit.
    """
    if not families:
        raise InputError("a campaign needs at least one orbit family")
    rng = np.random.default_rng(seed)
    units = truth.body.units
    truth_model = truth.model
    cadence = float(units.to_time(tracking.cadence_s))
    arc_offsets = cadence * np.arange(tracking.samples_per_arc)
    window = 2.0 * math.pi * tracking.window_spin_periods
    sigma_r = float(units.to_length(tracking.sigma_r_m))
    sigma_v = tracking.velocity_noise_ratio * sigma_r  # omega = 1 in canonical units
    r_b = truth.body.brillouin_radius

    all_times, all_true, traj, info = (
        [],
        [],
        [],
        {
            k: []
            for k in (
                "radius_rb",
                "inclination_deg",
                "raan_deg",
                "arg_lat_deg",
                "initial_state",
                "redraws",
            )
        },
    )
    for k, family in enumerate(families):
        starts = arc_start_times(rng, tracking.arcs_per_orbit, window, arc_offsets[-1])
        sample_times = (starts[:, None] + arc_offsets[None, :]).ravel()
        check = np.linspace(0.0, window, graze_check_points(tracking))
        grid = np.unique(np.concatenate([check, sample_times]))
        where = np.searchsorted(grid, sample_times)
        for attempt in range(tracking.max_redraws):  # noqa: B007 (kept: redraw count)
            raan, arg_lat, state0 = draw_orbit_start(rng, family, r_b)
            radius = family.radius_rb * r_b
            states, ok = propagate_scalar(truth_model, state0, grid, tol=TRUTH_TOLERANCE)
            low = tracking.min_radius_rb * r_b
            if (
                ok
                and not _touches_or_escapes(truth, states, tracking.escape_factor * radius)
                and np.linalg.norm(states[:, :3], axis=1).min() >= low
            ):
                break
        else:
            raise SimulationError(
                f"every one of {tracking.max_redraws} draws of the orbit at "
                f"{family.radius_rb} R_B, {family.inclination_deg} deg touched the surface, "
                "escaped or went below min_radius_rb; raise its radius or shorten "
                "window_spin_periods"
            )
        all_times.append(sample_times.reshape(tracking.arcs_per_orbit, -1))
        all_true.append(states[where].reshape(tracking.arcs_per_orbit, -1, 6))
        traj += [k] * tracking.arcs_per_orbit
        for key, value in (
            ("radius_rb", family.radius_rb),
            ("inclination_deg", family.inclination_deg),
            ("raan_deg", math.degrees(raan)),
            ("arg_lat_deg", math.degrees(arg_lat)),
            ("initial_state", state0),
            ("redraws", attempt),
        ):
            info[key].append(value)
        if progress is not None:
            progress(k + 1, len(families))

    true_states = np.concatenate(all_true)
    noisy = observe(true_states, sigma_r, sigma_v, rng)
    return Arcs(
        times=np.concatenate(all_times),
        states=noisy,
        true_states=true_states,
        trajectory=np.asarray(traj, dtype=np.int64),
        trajectory_kind=tuple("orbit" for _ in families),
        trajectory_info={k: np.asarray(v) for k, v in info.items()},
        **simulated_arcs_fields(truth, tracking.sigma_r_m, tracking.velocity_noise_ratio, seed),
        config=dict(config or {}),
    )
