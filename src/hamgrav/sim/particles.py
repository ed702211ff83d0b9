"""A particle swarm: centimetre-scale particles ejected from the surface and tracked under
gravity and solar radiation pressure (SRP), the particles themselves being the tracking data.

Each particle has its own area-to-mass ratio A/m [m^2/kg] and is ejected at a seeded time
(uniform over one spin period, so the Sun's direction in the body frame differs from particle
to particle) from a seeded random surface point (uniform over the area of the mesh), lifted
``lift_m`` along the face normal, with a velocity relative to the rotating surface whose
direction is uniform over a cone of half-angle ``cone_deg`` about the face normal and whose
speed is uniform in ``speed_escape_fraction`` times the local escape speed sqrt(2 GM / r).

The truth is the truth mascons plus the SRP term (:class:`~hamgrav.core.terms.
SolarRadiationPressure`, the particle's A/m as its runtime parameter): the same term the fitted
models carry. A draw is kept only if the particle neither touches the surface nor leaves
``escape_radius_rb`` R_B over the whole tracking span (``window_s`` from ejection), checked by
:func:`hamgrav.core.propagation.propagate_to_contact`; otherwise the ejection (site, time,
velocity) is drawn again for the same particle (its A/m kept), at most ``max_redraws`` times.

The particle's arcs (``samples_per_arc`` samples at ``cadence_s``) are placed one per equal
slot of the tracking span and observed with the paper's noise model
(:func:`hamgrav.sim.tracking.observe`).

Left out of the truth (and so of the models): shadowing by the body and eclipses, the Sun's
apparent motion over the tracking span, the solar tide (third-body gravity of the Sun),
thermal (Yarkovsky-like) and reflected radiation from Bennu, and particle rotation (the
cannonball model: the force is along the Sun-particle line).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from ..bodies.catalogue import Body
from ..bodies.interiors import Truth
from ..core.arcs import Arcs
from ..core.geometry import points_inside
from ..core.model import TRUTH_TOLERANCE, Model
from ..core.propagation import Touchdown, propagate_scalar, propagate_to_contact
from ..core.terms import MasconTerm, SolarRadiationPressure
from ..errors import InputError, SimulationError
from ..units import CanonicalUnits
from .tracking import arc_start_times, observe, simulated_arcs_fields

__all__ = [
    "SwarmConfig",
    "Ejection",
    "solar_radiation_pressure",
    "swarm_truth_model",
    "area_to_mass_ratios",
    "arcs_per_particle",
    "draw_ejection",
    "ejection_outcome",
    "simulate_swarm",
]

#: Solar flux at 1 AU [W/m^2] (the value :meth:`SolarRadiationPressure.pressure_for` uses).
SOLAR_FLUX_1AU_W_M2 = 1361.0


@dataclass(frozen=True)
class SwarmConfig:
    """A particle-swarm campaign (physical units at this edge).

    Attributes:
        particles: number of particles.
        arcs: arcs in all, shared out as evenly as possible (the particles given one more
            arc than the others chosen at random).
        samples_per_arc: samples per arc; cadence_s [s] between them.
        window_s: tracking span of each particle from its ejection [s]; the arcs lie in it,
            one per equal slot, and the particle must neither impact nor escape over it.
        area_to_mass_m2_kg: (low, high) A/m range [m^2/kg]; the particles' values are
            log-uniform and stratified (one per equal log-interval, shuffled), so they span
            nearly the whole range. The default is the strength at which the paper's swarm
            statements come closest to holding together (see results/swarm-bennu).
        speed_escape_fraction: (low, high) ejection speed relative to the surface, as a
            fraction of the local escape speed sqrt(2 GM / r) (uniform).
        cone_deg: half-angle [deg] of the cone about the face normal that holds the ejection
            direction (uniform over the cone's solid angle).
        lift_m: height [m] above the surface point, along the face normal, of the first state.
        escape_radius_rb: a particle beyond this radius [R_B] has escaped.
        distance_au: heliocentric distance [AU] (constant solar flux 1361 W/m^2 at 1 AU,
            scaled by 1 / d^2).
        reflectivity: 1 + rho, the radiation-pressure coefficient of the cannonball model
            (1: a black body).
        sun_latitude_deg: latitude of the (inertially fixed) Sun direction over the body's
            equator [deg].
        sigma_r_m: position noise [m] per component; sigma_v = omega sigma_r
            ``velocity_noise_ratio`` per velocity component.
        check_step_s: spacing [s] of the impact and escape check along each draw.
        max_redraws: draws allowed per particle before the simulation gives up.
    """

    particles: int = 28
    arcs: int = 263
    samples_per_arc: int = 40
    cadence_s: float = 39.0
    window_s: float = 16_200.0
    area_to_mass_m2_kg: tuple[float, float] = (0.055, 0.825)
    speed_escape_fraction: tuple[float, float] = (0.6, 1.0)
    cone_deg: float = 45.0
    lift_m: float = 0.5
    escape_radius_rb: float = 4.0
    distance_au: float = 0.9
    reflectivity: float = 1.044
    sun_latitude_deg: float = 0.0
    sigma_r_m: float = 0.05
    velocity_noise_ratio: float = 0.1
    check_step_s: float = 10.0
    max_redraws: int = 400

    def __post_init__(self) -> None:
        def need(ok: bool, message: str) -> None:
            if not ok:
                raise InputError(message)

        need(self.particles >= 1, f"particles must be at least 1, got {self.particles}")
        need(
            self.arcs >= self.particles,
            f"arcs ({self.arcs}) must be at least particles ({self.particles}): one arc each",
        )
        need(self.samples_per_arc >= 2, "samples_per_arc must be at least 2")
        need(self.cadence_s > 0 and self.window_s > 0, "cadence_s and window_s must be > 0")
        arcs_max = -(-self.arcs // self.particles)
        arc_s = self.cadence_s * (self.samples_per_arc - 1)
        need(
            self.window_s / arcs_max >= arc_s,
            f"window_s {self.window_s:g} s cannot hold {arcs_max} arcs of {arc_s:g} s each; "
            f"raise window_s to at least {arcs_max * arc_s:g}",
        )
        lo, hi = self.area_to_mass_m2_kg
        need(0 < lo <= hi, f"area_to_mass_m2_kg must be 0 < low <= high, got {(lo, hi)}")
        lo, hi = self.speed_escape_fraction
        need(0 < lo <= hi, f"speed_escape_fraction must be 0 < low <= high, got {(lo, hi)}")
        need(0 <= self.cone_deg <= 90, f"cone_deg must lie in [0, 90], got {self.cone_deg}")
        need(self.lift_m > 0, f"lift_m must be positive, got {self.lift_m}")
        need(self.escape_radius_rb > 1, "escape_radius_rb must exceed 1")
        need(self.distance_au > 0 and self.reflectivity > 0, "distance_au, reflectivity > 0")
        need(self.sigma_r_m >= 0, "sigma_r_m must be >= 0")
        need(self.check_step_s > 0 and self.max_redraws >= 1, "check_step_s > 0, max_redraws >= 1")

    def as_dict(self) -> dict:
        """Plain data (tuples as lists)."""
        return {
            f.name: list(v) if isinstance(v := getattr(self, f.name), tuple) else v
            for f in fields(self)
        }


@dataclass(frozen=True)
class Ejection:
    """One draw of an ejection (canonical unless stated): ``time``, first ``state`` (q, p),
    surface ``site`` and unit ``normal`` there, ``speed_m_s`` relative to the surface [m/s] and
    the angle ``off_normal_deg`` [deg] between the velocity and the normal."""

    time: float
    state: np.ndarray
    site: np.ndarray
    normal: np.ndarray
    speed_m_s: float
    off_normal_deg: float


def solar_radiation_pressure(units: CanonicalUnits, config: SwarmConfig) -> SolarRadiationPressure:
    """The SRP term of ``config``: pressure at ``distance_au`` times ``reflectivity``, in
    canonical acceleration per unit A/m [m^2/kg]; Sun at ``sun_latitude_deg``."""
    k = SolarRadiationPressure.pressure_for(units, config.distance_au, config.reflectivity)
    return SolarRadiationPressure(k, config.sun_latitude_deg)


def swarm_truth_model(truth: Truth, srp: SolarRadiationPressure) -> Model:
    """The truth's dynamics with SRP: the truth mascons known, A/m as the per-trajectory
    parameter."""
    return Model((MasconTerm(truth.mascons, "truth"),), None, (srp,))


def area_to_mass_ratios(rng: np.random.Generator, n: int, bounds) -> np.ndarray:
    """``n`` A/m values [m^2/kg], log-uniform in ``bounds`` and stratified: one in each of
    ``n`` equal intervals of log A/m, in shuffled order."""
    lo, hi = (float(b) for b in bounds)
    u = (np.arange(n) + rng.uniform(size=n)) / n
    return rng.permutation(lo * (hi / lo) ** u)


def arcs_per_particle(rng: np.random.Generator, particles: int, arcs: int) -> np.ndarray:
    """Arc counts (particles,) summing to ``arcs``: ``arcs // particles`` each, one more for
    ``arcs % particles`` particles chosen at random."""
    base, extra = divmod(arcs, particles)
    return base + (rng.permutation(particles) < extra).astype(int)


def _surface_point(rng, mesh) -> tuple[np.ndarray, np.ndarray]:
    """A point uniform over the mesh's area and the outward unit normal of its face."""
    areas = np.asarray(mesh.area_faces)
    face = rng.choice(len(areas), p=areas / areas.sum())
    a, b = rng.uniform(size=2)
    if a + b > 1.0:
        a, b = 1.0 - a, 1.0 - b
    tri = np.asarray(mesh.triangles[face])
    return tri[0] + a * (tri[1] - tri[0]) + b * (tri[2] - tri[0]), np.asarray(
        mesh.face_normals[face], dtype=float
    )


def _cone_direction(rng, axis: np.ndarray, half_angle_rad: float) -> tuple[np.ndarray, float]:
    """A unit vector uniform over the solid angle of the cone about ``axis``, and its angle."""
    cos_t = rng.uniform(math.cos(half_angle_rad), 1.0)
    sin_t = math.sqrt(max(0.0, 1.0 - cos_t * cos_t))
    phi = rng.uniform(0.0, 2.0 * math.pi)
    helper = np.array([0.0, 0.0, 1.0]) if abs(axis[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    direction = cos_t * axis + sin_t * (math.cos(phi) * e1 + math.sin(phi) * e2)
    return direction, math.acos(cos_t)


def draw_ejection(rng: np.random.Generator, body: Body, config: SwarmConfig) -> Ejection:
    """One seeded ejection from ``body`` (canonical, the body's frame): see the module
    docstring for the distributions. The momentum is p = v + omega x q (v the velocity in the
    rotating frame, omega = 1 about z)."""
    units = body.units
    site, normal = _surface_point(rng, body.mesh)
    q = site + float(units.to_length(config.lift_m)) * normal
    direction, angle = _cone_direction(rng, normal, math.radians(config.cone_deg))
    v_escape = math.sqrt(2.0 / float(np.linalg.norm(q)))  # canonical, mu = 1
    speed = rng.uniform(*config.speed_escape_fraction) * v_escape
    v = speed * direction
    p = np.array([v[0] - q[1], v[1] + q[0], v[2]])
    t0 = rng.uniform(0.0, 2.0 * math.pi)
    return Ejection(
        time=float(t0),
        state=np.concatenate([q, p]),
        site=site,
        normal=normal,
        speed_m_s=float(units.from_velocity(speed)),
        off_normal_deg=math.degrees(angle),
    )


def ejection_outcome(
    model: Model, ejection: Ejection, area_to_mass: float, body: Body, config: SwarmConfig
) -> Touchdown:
    """Propagate a drawn ejection under ``model`` (the truth with SRP) over the tracking span:
    "timed out" means the particle survived it; otherwise it landed (touched the surface),
    escaped (beyond ``escape_radius_rb``) or diverged. A first state inside the mesh (the
    lift put it into a concavity) counts as landed."""
    units = body.units
    triangles = np.asarray(body.mesh.triangles)
    if points_inside(triangles, ejection.state[None, :3])[0]:  # lifted into a concavity
        return Touchdown(True, ejection.time, ejection.state[:3].copy(), "")
    return propagate_to_contact(
        model,
        ejection.state,
        triangles,
        params=np.array([area_to_mass]),
        check_step=float(units.to_time(config.check_step_s)),
        duration=float(units.to_time(config.window_s)),
        escape_radius=config.escape_radius_rb * body.brillouin_radius,
        contact_tol=float(units.to_time(config.check_step_s)),
        t0=ejection.time,
        bound_radius=body.brillouin_radius,
        tol=TRUTH_TOLERANCE,
    )


def simulate_swarm(
    truth: Truth,
    config: SwarmConfig = SwarmConfig(),
    *,
    seed: int = 0,
    progress=None,
) -> Arcs:
    """Simulate the ejection and tracking of ``config.particles`` particles under ``truth``
    with SRP (see the module docstring). ``progress(done, total)`` is called after each particle.

    Trajectory info (one entry per particle): ``area_to_mass_m2_kg`` [m^2/kg],
    ``ejection_time`` [canonical], ``initial_state`` [canonical], ``site`` [canonical],
    ``speed_m_s`` [m/s], ``off_normal_deg`` [deg], ``redraws`` (draws rejected before the
    kept one), ``impacted`` and ``escaped`` (how many of them touched the surface / escaped).
    Raises :class:`~hamgrav.errors.SimulationError` when every one of ``max_redraws`` draws of a
    particle is rejected.
    """
    rng = np.random.default_rng(seed)
    body = truth.body
    units = body.units
    srp = solar_radiation_pressure(units, config)
    model = swarm_truth_model(truth, srp)
    cadence = float(units.to_time(config.cadence_s))
    offsets = cadence * np.arange(config.samples_per_arc)
    window = float(units.to_time(config.window_s))
    sigma_r = float(units.to_length(config.sigma_r_m))
    sigma_v = config.velocity_noise_ratio * sigma_r  # omega = 1 in canonical units
    ratios = area_to_mass_ratios(rng, config.particles, config.area_to_mass_m2_kg)
    counts = arcs_per_particle(rng, config.particles, config.arcs)

    keys = ("ejection_time", "initial_state", "site", "speed_m_s", "off_normal_deg")
    info: dict[str, list] = {k: [] for k in (*keys, "redraws", "impacted", "escaped")}
    all_times, all_true, trajectory = [], [], []
    for k in range(config.particles):
        rejected = {"landed": 0, "escaped": 0, "diverged": 0}
        for _ in range(config.max_redraws):
            ejection = draw_ejection(rng, body, config)
            outcome = ejection_outcome(model, ejection, ratios[k], body, config)
            if not outcome.landed and outcome.reason == "timed out":
                break
            rejected["landed" if outcome.landed else outcome.reason] += 1
        else:
            raise SimulationError(
                f"every one of {config.max_redraws} ejections of particle {k} impacted or "
                f"escaped within {config.window_s:g} s ({rejected}); shorten window_s or "
                "change speed_escape_fraction"
            )
        starts = ejection.time + arc_start_times(rng, int(counts[k]), window, offsets[-1])
        times = starts[:, None] + offsets[None, :]
        states, ok = propagate_scalar(
            model,
            ejection.state,
            times.ravel(),
            np.array([ratios[k]]),
            t0=ejection.time,
            tol=TRUTH_TOLERANCE,
        )
        if not ok:  # survived the check, so this is a bug, not a draw to reject
            raise RuntimeError(f"particle {k} did not propagate to its samples")
        all_times.append(times)
        all_true.append(states.reshape(len(starts), -1, 6))
        trajectory += [k] * len(starts)
        info["ejection_time"].append(ejection.time)
        info["initial_state"].append(ejection.state)
        info["site"].append(ejection.site)
        info["speed_m_s"].append(ejection.speed_m_s)
        info["off_normal_deg"].append(ejection.off_normal_deg)
        info["redraws"].append(sum(rejected.values()))
        info["impacted"].append(rejected["landed"])
        info["escaped"].append(rejected["escaped"])
        if progress is not None:
            progress(k + 1, config.particles)

    true_states = np.concatenate(all_true)
    trajectory_info = {k: np.asarray(v) for k, v in info.items()}
    trajectory_info["area_to_mass_m2_kg"] = ratios
    return Arcs(
        times=np.concatenate(all_times),
        states=observe(true_states, sigma_r, sigma_v, rng),
        true_states=true_states,
        trajectory=np.asarray(trajectory, dtype=np.int64),
        trajectory_kind=tuple("particle" for _ in range(config.particles)),
        trajectory_info=trajectory_info,
        **simulated_arcs_fields(truth, config.sigma_r_m, config.velocity_noise_ratio, seed),
        config={"swarm": config.as_dict(), "srp": srp.describe()},
    )
