"""Canonical units of a spinning body and the conversions to and from SI.

Length unit: the synchronous radius (GM / omega^2)^(1/3); time unit: spin period / 2 pi.
In these units the body's gravitational parameter and the frame rotation rate are both 1.

Canonical momenta in the rotating frame relate to rotating-frame velocities by
``v_x = p_x + y``, ``v_y = p_y - x``, ``v_z = p_z`` (i.e. ``p = v + omega x q``), so that
the momentum is the inertial velocity expressed in body-fixed axes.

Every physical input is converted here, once, at the edge; the numerical core is unit-free.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["CanonicalUnits", "velocity_to_momentum", "momentum_to_velocity"]


def velocity_to_momentum(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Canonical momenta from rotating-frame velocities (canonical units, last axis xyz)."""
    q = np.asarray(q, dtype=float)
    p = np.array(v, dtype=float, copy=True)
    p[..., 0] -= q[..., 1]
    p[..., 1] += q[..., 0]
    return p


def momentum_to_velocity(q: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Rotating-frame velocities from canonical momenta (canonical units, last axis xyz)."""
    q = np.asarray(q, dtype=float)
    v = np.array(p, dtype=float, copy=True)
    v[..., 0] += q[..., 1]
    v[..., 1] -= q[..., 0]
    return v


@dataclass(frozen=True)
class CanonicalUnits:
    """Canonical units of a body with gravitational parameter ``gm_m3_s2`` [m^3/s^2]
    spinning with sidereal period ``spin_period_s`` [s]."""

    gm_m3_s2: float
    spin_period_s: float

    def __post_init__(self) -> None:
        for name in ("gm_m3_s2", "spin_period_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite number, got {value!r}")

    @property
    def omega_rad_s(self) -> float:
        """Spin rate [rad/s]."""
        return 2.0 * math.pi / self.spin_period_s

    @property
    def length_m(self) -> float:
        """Length unit: the synchronous radius [m]."""
        return (self.gm_m3_s2 / self.omega_rad_s**2) ** (1.0 / 3.0)

    @property
    def time_s(self) -> float:
        """Time unit: spin period / 2 pi [s]."""
        return 1.0 / self.omega_rad_s

    @property
    def velocity_m_s(self) -> float:
        """Velocity unit [m/s]."""
        return self.length_m / self.time_s

    @property
    def acceleration_m_s2(self) -> float:
        """Acceleration unit [m/s^2]."""
        return self.length_m / self.time_s**2

    @property
    def potential_m2_s2(self) -> float:
        """Potential (energy per unit mass) unit [m^2/s^2]; equals GM / length."""
        return self.velocity_m_s**2

    # Conversions. ``to_*`` take SI and return canonical, ``from_*`` the reverse.
    def to_length(self, metres):
        """A length [m] in canonical units."""
        return np.asarray(metres, dtype=float) / self.length_m

    def from_length(self, canonical):
        """A canonical length in [m]."""
        return np.asarray(canonical, dtype=float) * self.length_m

    def to_time(self, seconds):
        """A time [s] in canonical units."""
        return np.asarray(seconds, dtype=float) / self.time_s

    def from_time(self, canonical):
        """A canonical time in [s]."""
        return np.asarray(canonical, dtype=float) * self.time_s

    def to_velocity(self, m_s):
        """A velocity [m/s] in canonical units."""
        return np.asarray(m_s, dtype=float) / self.velocity_m_s

    def from_velocity(self, canonical):
        """A canonical velocity in [m/s]."""
        return np.asarray(canonical, dtype=float) * self.velocity_m_s

    def to_acceleration(self, m_s2):
        """A acceleration [m/s^2] in canonical units."""
        return np.asarray(m_s2, dtype=float) / self.acceleration_m_s2

    def from_acceleration(self, canonical):
        """A canonical acceleration in [m/s^2]."""
        return np.asarray(canonical, dtype=float) * self.acceleration_m_s2

    def to_potential(self, m2_s2):
        """A potential [m^2/s^2] in canonical units."""
        return np.asarray(m2_s2, dtype=float) / self.potential_m2_s2

    def from_potential(self, canonical):
        """A canonical potential in [m^2/s^2]."""
        return np.asarray(canonical, dtype=float) * self.potential_m2_s2

    def state_to_canonical(self, position_m, velocity_m_s) -> np.ndarray:
        """Canonical (q, p) state(s), shape (..., 6), from body-fixed position [m] and
        rotating-frame velocity [m/s]."""
        q = self.to_length(position_m)
        v = self.to_velocity(velocity_m_s)
        return np.concatenate([q, velocity_to_momentum(q, v)], axis=-1)

    def state_from_canonical(self, state) -> tuple[np.ndarray, np.ndarray]:
        """Body-fixed position [m] and rotating-frame velocity [m/s] from canonical (q, p)."""
        state = np.asarray(state, dtype=float)
        q, p = state[..., :3], state[..., 3:6]
        return self.from_length(q), self.from_velocity(momentum_to_velocity(q, p))
