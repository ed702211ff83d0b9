"""``Arcs``: observed tracking arcs and what is needed to interpret and check them."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field, replace

import numpy as np

from .mascons import MasconSet

__all__ = ["Arcs", "NO_TRUTH"]

#: The ``interior`` of arcs that carry no truth (tracking imported from files).
NO_TRUTH = "none"


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

    def __post_init__(self) -> None:
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
