"""A body's rotation model: from an inertial frame (ICRF) to hamgrav's body-fixed frame.

The IAU (WGCCRE) convention: the body's north pole points at right ascension ``alpha_0``
and declination ``delta_0`` in the ICRF, and the prime meridian has angle ``W(t)`` from the
node of the body's equator on the ICRF equator::

    M(t) = R3(W(t)) R1(90 deg - delta_0) R3(90 deg + alpha_0),
    W(t) = W_0 + 360 deg * (t - epoch) / spin_period_s,

with ``R3(a)`` = [[cos a, sin a, 0], [-sin a, cos a, 0], [0, 0, 1]] and ``R1(a)`` = [[1, 0, 0],
[0, cos a, sin a], [0, -sin a, cos a]] (frame rotations), so that r_body = M(t) r_inertial.
The spin rate is the body's own (``2 pi / spin_period_s``): it is what defines hamgrav's
rotating frame and canonical time unit, so a rotation model cannot carry another one.

States: position r_body = M r_in; the canonical momentum is the inertial velocity in body
axes, p = M v_in; the rotating-frame velocity is v_rot = M v_in - omega x r_body with omega
along +z. Precession and nutation of the pole are not modelled (constant alpha_0, delta_0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputError

__all__ = ["RotationModel", "J2000_TDB"]

#: The IAU reference epoch J2000.0 (2000-01-01 12:00:00 TDB), ISO string.
J2000_TDB = "2000-01-01T12:00:00"


def _r1(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])


def _r3(a: np.ndarray) -> np.ndarray:
    """Frame rotations about z by the angles ``a`` (n,), shape (n, 3, 3)."""
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a), np.sin(a)
    out = np.zeros((*a.shape, 3, 3))
    out[..., 0, 0] = c
    out[..., 0, 1] = s
    out[..., 1, 0] = -s
    out[..., 1, 1] = c
    out[..., 2, 2] = 1.0
    return out


@dataclass(frozen=True)
class RotationModel:
    """Uniform rotation about a fixed pole (IAU convention, see the module docstring).

    Attributes:
        pole_ra_deg: right ascension of the north pole in the ICRF [deg].
        pole_dec_deg: declination of the north pole in the ICRF [deg].
        prime_meridian_deg: W_0, the prime meridian angle at ``epoch`` [deg].
        spin_period_s: sidereal spin period [s] (the body's; W grows by 360 deg per period).
        epoch: the TDB epoch of W_0, ISO string (default J2000.0).
    """

    pole_ra_deg: float
    pole_dec_deg: float
    prime_meridian_deg: float
    spin_period_s: float
    epoch: str = J2000_TDB

    def __post_init__(self) -> None:
        for name in ("pole_ra_deg", "pole_dec_deg", "prime_meridian_deg", "spin_period_s"):
            if not math.isfinite(float(getattr(self, name))):
                raise InputError(f"rotation model: {name} must be a finite number")
        if not -90.0 <= self.pole_dec_deg <= 90.0:
            raise InputError(
                f"rotation model: pole declination must lie in [-90, 90] deg, got "
                f"{self.pole_dec_deg!r}"
            )
        if not self.spin_period_s > 0:
            raise InputError("rotation model: spin_period_s must be positive")

    @property
    def omega_rad_s(self) -> float:
        """Spin rate [rad/s]."""
        return 2.0 * math.pi / self.spin_period_s

    def prime_meridian_rad(self, seconds_since_epoch) -> np.ndarray:
        """W(t) [rad] at ``seconds_since_epoch`` [s, TDB] after :attr:`epoch`."""
        t = np.asarray(seconds_since_epoch, dtype=float)
        w0 = math.radians(self.prime_meridian_deg % 360.0)
        # the angle grown since the epoch, reduced modulo one turn before it is added
        turns = np.mod(t / self.spin_period_s, 1.0)
        return w0 + 2.0 * math.pi * turns

    def matrix(self, seconds_since_epoch) -> np.ndarray:
        """M(t) (n, 3, 3): r_body = M r_inertial at ``seconds_since_epoch`` (n,) [s, TDB]."""
        pole = _r1(math.radians(90.0 - self.pole_dec_deg)) @ _r3(
            math.radians(90.0 + self.pole_ra_deg)
        )
        return _r3(self.prime_meridian_rad(seconds_since_epoch)) @ pole

    def to_body(self, seconds_since_epoch, position, velocity):
        """Inertial position [m] and velocity [m/s] (n, 3) at ``seconds_since_epoch`` (n,)
        -> body-fixed position [m], inertial velocity in body axes (the canonical momentum's
        direction) [m/s] and rotating-frame velocity [m/s], each (n, 3)."""
        m = self.matrix(seconds_since_epoch)
        r = np.einsum("nij,nj->ni", m, np.asarray(position, dtype=float))
        p = np.einsum("nij,nj->ni", m, np.asarray(velocity, dtype=float))
        w = self.omega_rad_s
        v_rot = p + w * np.stack([r[:, 1], -r[:, 0], np.zeros(len(r))], axis=1)
        return r, p, v_rot

    def to_inertial(self, seconds_since_epoch, position, velocity):
        """Body-fixed position [m] and rotating-frame velocity [m/s] (n, 3) -> inertial
        position [m] and velocity [m/s] (n, 3): the inverse of :meth:`to_body`."""
        m = self.matrix(seconds_since_epoch)
        r = np.asarray(position, dtype=float)
        w = self.omega_rad_s
        p = np.asarray(velocity, dtype=float) + w * np.stack(
            [-r[:, 1], r[:, 0], np.zeros(len(r))], axis=1
        )
        return np.einsum("nji,nj->ni", m, r), np.einsum("nji,nj->ni", m, p)

    def describe(self) -> dict:
        """Plain-data description (JSON-able)."""
        return {
            "convention": "IAU: M = R3(W) R1(90 - dec) R3(90 + ra), W = W0 + 360 (t - epoch) / P",
            "pole_ra_deg": self.pole_ra_deg,
            "pole_dec_deg": self.pole_dec_deg,
            "prime_meridian_deg": self.prime_meridian_deg,
            "spin_period_s": self.spin_period_s,
            "epoch_tdb": self.epoch,
        }
