"""``Arcs``: observed tracking arcs and what is needed to interpret and check them."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import InputError
from .mascons import MasconSet

__all__ = ["Arcs", "BodyRecord", "MAX_SEED", "NO_TRUTH", "mesh_digest", "join_arcs", "sample_radii"]

#: The ``interior`` of arcs that carry no truth (tracking imported from files).
NO_TRUTH = "none"


def mesh_digest(vertices_m, faces) -> str:
    """SHA-256 (hex) of a triangle mesh: vertices [m] as float64 and faces as int64, with
    their shapes. Equal digests: the same shape, whatever file it came from."""
    h = hashlib.sha256()
    _hash_arrays(h, np.asarray(vertices_m, dtype=float), np.asarray(faces, dtype=np.int64))
    return h.hexdigest()


#: Largest seed: seeds are stored as 64-bit signed integers (the arcs file's ``seed``
#: attribute, numpy's int64), so a larger one would simulate and then fail to be written.
MAX_SEED = 2**63 - 1


@dataclass(frozen=True, eq=False)
class BodyRecord:
    """The body a dataset or a model was made with, as plain data: enough to rebuild the
    body (:meth:`hamgrav.bodies.catalogue.Body.from_record`) without looking anything up.

    Attributes:
        name: the body's name (free text; not looked up anywhere).
        gm_m3_s2: gravitational parameter [m^3/s^2].
        spin_period_s: sidereal spin period [s] about +z.
        origin_m: (3,) the frame origin [m] in the mesh's own frame.
        vertices_m: (n, 3) mesh vertices [m] in the mesh's own frame.
        faces: (k, 3) vertex indices of the outward-wound triangles.
        rotation: the rotation model in the ICRF as plain data (``pole_ra_deg``,
            ``pole_dec_deg``, ``prime_meridian_deg``, ``epoch_tdb``), or None.
        naif_id: the body's NAIF ID, or None.
        source: where the body came from (see ``Body.source``).
        description: free text.
    """

    name: str
    gm_m3_s2: float
    spin_period_s: float
    origin_m: tuple[float, float, float]
    vertices_m: np.ndarray
    faces: np.ndarray
    rotation: dict | None = None
    naif_id: int | None = None
    source: dict = field(default_factory=dict)
    description: str = ""

    def __post_init__(self) -> None:
        v, f = np.shape(self.vertices_m), np.shape(self.faces)
        if len(v) != 2 or v[1] != 3 or len(f) != 2 or f[1] != 3:
            raise ValueError(f"a body record needs vertices (n, 3) and faces (k, 3), got {v}, {f}")

    @property
    def mesh_sha256(self) -> str:
        """:func:`mesh_digest` of the recorded mesh."""
        return mesh_digest(self.vertices_m, self.faces)


@dataclass(frozen=True, eq=False)
class Arcs:
    """Observed arcs in canonical units (length = synchronous radius, time = spin period /
    2 pi), with what is needed to interpret and check them.

    Attributes:
        times: (n_arcs, m) canonical times of the samples.
        states: (n_arcs, m, 6) noisy canonical states (q, p).
        true_states: (n_arcs, m, 6) the truth at the same times.
        trajectory: (n_arcs,) index of the trajectory (orbit, particle, descent) of each arc.
        trajectory_kind: kind of each trajectory ("orbit", ...).
        trajectory_info: per-trajectory arrays (e.g. radius_rb, inclination_deg, initial_state).
        body_name: the body; gm_m3_s2 [m^3/s^2] and spin_period_s [s] fix the canonical units.
        body_origin_m: frame origin of the arcs in the body mesh's own frame [m].
        sigma_r_m [m], sigma_v_m_s [m/s]: noise levels per component.
        truth: the truth mascons (canonical, arcs' frame), ``interior`` its name,
            ``interior_parameters`` its settings (empty and :data:`NO_TRUTH` for imported
            tracking, see :attr:`has_truth`).
        seed: generator seed of the campaign; config: the campaign description.
        body: the body the arcs were made with (mesh, constants, provenance), or None in
            files written before hamgrav recorded it.
    """

    times: np.ndarray
    states: np.ndarray
    true_states: np.ndarray
    trajectory: np.ndarray
    trajectory_kind: tuple[str, ...]
    trajectory_info: dict[str, np.ndarray]
    body_name: str
    gm_m3_s2: float
    spin_period_s: float
    body_origin_m: tuple[float, float, float]
    sigma_r_m: float
    sigma_v_m_s: float
    truth: MasconSet
    interior: str
    interior_parameters: dict = field(default_factory=dict)
    seed: int = 0
    config: dict = field(default_factory=dict)
    body: BodyRecord | None = None

    def __post_init__(self) -> None:
        if self.body is not None and (
            float(self.body.gm_m3_s2) != float(self.gm_m3_s2)
            or float(self.body.spin_period_s) != float(self.spin_period_s)
        ):
            raise ValueError(
                f"the arcs' GM {self.gm_m3_s2} m^3/s^2 and spin period {self.spin_period_s} s "
                f"differ from their body's ({self.body.gm_m3_s2}, {self.body.spin_period_s})"
            )
        if self.body is not None and tuple(map(float, self.body.origin_m)) != tuple(
            map(float, self.body_origin_m)
        ):
            raise ValueError(
                f"the arcs' frame origin {self.body_origin_m} m differs from their body's "
                f"{self.body.origin_m}"
            )
        n, m = np.shape(self.times)
        if np.shape(self.states) != (n, m, 6) or np.shape(self.true_states) != (n, m, 6):
            raise ValueError(
                f"arcs need times (n, m) and states (n, m, 6); got {np.shape(self.times)}, "
                f"{np.shape(self.states)}, {np.shape(self.true_states)}"
            )
        if np.shape(self.trajectory) != (n,):
            raise ValueError("trajectory must hold one index per arc")
        if n and (self.trajectory.min() < 0 or self.trajectory.max() >= len(self.trajectory_kind)):
            raise ValueError("trajectory indices must refer to trajectory_kind entries")

    @property
    def has_truth(self) -> bool:
        """Whether the arcs carry a truth to compare models with (simulated arcs do; imported
        tracking does not: ``interior`` is :data:`NO_TRUTH`, no truth mascons, NaN
        ``true_states``)."""
        return self.interior != NO_TRUTH and len(self.truth) > 0

    @property
    def n_arcs(self) -> int:
        """Number of arcs."""
        return int(np.shape(self.times)[0])

    @property
    def samples_per_arc(self) -> int:
        """Samples in each arc."""
        return int(np.shape(self.times)[1])

    @property
    def n_trajectories(self) -> int:
        """Number of trajectories (orbits, particles, descents) the arcs belong to."""
        return len(self.trajectory_kind)

    def subset(self, arc_indices) -> Arcs:
        """The arcs selected by ``arc_indices`` (trajectory tables kept whole)."""
        idx = np.asarray(arc_indices)
        return replace(
            self,
            times=self.times[idx],
            states=self.states[idx],
            true_states=self.true_states[idx],
            trajectory=self.trajectory[idx],
        )

    def truth_digest(self) -> str:
        """SHA-256 (hex) identifying the truth these arcs were simulated under: the body,
        its units, the frame origin and the truth mascons. Equal digests: the same truth."""
        h = hashlib.sha256()
        h.update(
            repr(
                (
                    self.body_name,
                    float(self.gm_m3_s2),
                    float(self.spin_period_s),
                    tuple(float(v) for v in self.body_origin_m),
                )
            ).encode()
        )
        _hash_arrays(h, self.truth.positions, self.truth.masses)
        return h.hexdigest()

    def digest(self) -> str:
        """SHA-256 (hex) identifying these arcs: their truth (:meth:`truth_digest`), noise
        levels, times, noisy states and trajectory indices."""
        h = hashlib.sha256(self.truth_digest().encode())
        h.update(repr((float(self.sigma_r_m), float(self.sigma_v_m_s))).encode())
        _hash_arrays(h, self.times, self.states, self.trajectory)
        return h.hexdigest()

    def arcs_of(self, trajectories) -> np.ndarray:
        """Indices of the arcs that belong to the given trajectory indices."""
        return np.flatnonzero(np.isin(self.trajectory, np.asarray(trajectories)))


def _hash_arrays(h, *arrays) -> None:
    """Feed arrays to ``h`` by value: floats as float64, integers as int64, with shapes."""
    for a in arrays:
        a = np.asarray(a)
        canon = np.ascontiguousarray(a, dtype=np.float64 if a.dtype.kind == "f" else np.int64)
        h.update(repr(canon.shape).encode())
        h.update(canon.tobytes())


def join_arcs(first: Arcs, second: Arcs) -> Arcs:
    """``first``'s arcs followed by ``second``'s (same body, units and samples per arc); the
    second's trajectories are numbered after the first's. Per-trajectory tables are joined
    key by key, NaN where one side has no such entry (e.g. the orbits' inclinations for the
    descents)."""
    if (first.body_name, first.gm_m3_s2, first.spin_period_s) != (
        second.body_name,
        second.gm_m3_s2,
        second.spin_period_s,
    ):
        raise InputError("arcs of different bodies or units cannot be joined")
    n1, n2 = first.n_trajectories, second.n_trajectories

    def column(info: dict, key: str, n: int, like: np.ndarray) -> np.ndarray:
        if key in info:
            return np.asarray(info[key], dtype=float)
        return np.full((n, *np.shape(like)[1:]), np.nan)

    keys = list(first.trajectory_info) + [
        k for k in second.trajectory_info if k not in first.trajectory_info
    ]
    info = {}
    for key in keys:
        like = np.asarray(first.trajectory_info.get(key, second.trajectory_info.get(key)))
        info[key] = np.concatenate(
            [
                column(first.trajectory_info, key, n1, like),
                column(second.trajectory_info, key, n2, like),
            ]
        )
    return replace(
        first,
        times=np.concatenate([first.times, second.times]),
        states=np.concatenate([first.states, second.states]),
        true_states=np.concatenate([first.true_states, second.true_states]),
        trajectory=np.concatenate([first.trajectory, second.trajectory + n1]),
        trajectory_kind=first.trajectory_kind + second.trajectory_kind,
        trajectory_info=info,
    )


def sample_radii(arcs: Arcs, brillouin_radius: float, floor_rb: float) -> dict:
    """Radial distribution of the tracked samples [R_B]: min, quartiles, max, the sample
    count and how many lie below ``floor_rb``."""
    r = np.linalg.norm(arcs.states[..., :3], axis=-1).ravel() / brillouin_radius
    q = np.percentile(r, [0, 25, 50, 75, 100])
    keys = ("min", "q1", "median", "q3", "max")
    return {
        **{k: round(float(v), 3) for k, v in zip(keys, q, strict=True)},
        "n_samples": int(r.size),
        "floor_rb": floor_rb,
        "below_floor": int(np.sum(r < floor_rb)),
    }
