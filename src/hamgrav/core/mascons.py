"""Point-mass (mascon) sets and their gravity fields, in canonical units.

Sign convention: the potential is positive, V(q) = sum_i m_i / |q - q_i|, so that the
Hamiltonian carries ``-V`` and the acceleration is ``grad V``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["MasconSet", "mascon_potential", "mascon_acceleration"]

_CHUNK_ELEMENTS = 4_000_000  # points x mascons per block: bounded memory, vectorised inner loop


@dataclass(frozen=True, eq=False)
class MasconSet:
    """Point masses: ``positions`` (n, 3) [canonical length], ``masses`` (n,) [canonical mass,
    i.e. fractions of the body's GM; a truth's sum to 1]."""

    positions: np.ndarray
    masses: np.ndarray

    def __post_init__(self) -> None:
        pos = np.asarray(self.positions, dtype=float)
        mass = np.asarray(self.masses, dtype=float)
        if pos.ndim != 2 or pos.shape[1] != 3 or mass.shape != (pos.shape[0],):
            raise ValueError(
                f"mascons need positions (n, 3) and masses (n,), got {pos.shape}, {mass.shape}"
            )
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(mass))):
            raise ValueError("mascon positions and masses must be finite")
        object.__setattr__(self, "positions", pos)
        object.__setattr__(self, "masses", mass)

    def __len__(self) -> int:
        return len(self.masses)

    @property
    def total_mass(self) -> float:
        """Sum of the masses [canonical]."""
        return float(self.masses.sum())

    @property
    def centre_of_mass(self) -> np.ndarray:
        """Mass-weighted mean position (3,) [canonical length]."""
        return self.masses @ self.positions / self.masses.sum()

    def translated(self, offset: np.ndarray) -> MasconSet:
        """The same masses with every position moved by ``offset`` (3,) [canonical length]."""
        return MasconSet(self.positions + np.asarray(offset, dtype=float), self.masses)


def _blocks(n_points: int, n_mascons: int):
    step = max(1, _CHUNK_ELEMENTS // max(1, n_mascons))
    for start in range(0, n_points, step):
        yield slice(start, min(start + step, n_points))


def mascon_potential(mascons: MasconSet, points: np.ndarray) -> np.ndarray:
    """V(q) = sum m_i / |q - q_i| at ``points`` (n, 3); returns (n,), canonical units.

    A numpy reference independent of the compiled heyoka expressions (tests compare them)."""
    points = np.atleast_2d(np.asarray(points, dtype=float))
    out = np.empty(len(points))
    for sl in _blocks(len(points), len(mascons)):
        d = points[sl, None, :] - mascons.positions[None, :, :]
        out[sl] = (mascons.masses / np.sqrt(np.einsum("ijk,ijk->ij", d, d))).sum(axis=1)
    return out


def mascon_acceleration(mascons: MasconSet, points: np.ndarray) -> np.ndarray:
    """a(q) = grad V = -sum m_i (q - q_i) / |q - q_i|^3 at ``points`` (n, 3) [canonical
    length]; returns (n, 3) [canonical acceleration]."""
    points = np.atleast_2d(np.asarray(points, dtype=float))
    out = np.empty((len(points), 3))
    for sl in _blocks(len(points), len(mascons)):
        d = points[sl, None, :] - mascons.positions[None, :, :]
        r2 = np.einsum("ijk,ijk->ij", d, d)
        w = mascons.masses / (r2 * np.sqrt(r2))
        out[sl] = -np.einsum("ij,ijk->ik", w, d)
    return out
