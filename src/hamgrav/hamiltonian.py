"""The body-fixed rotating-frame Hamiltonian, its equations of motion, compiled integrators.

    H(q, p, t) = |p|^2 / 2 + y p_x - x p_y - V(q, t)

in canonical units (mu = omega = 1), with V the sum of the potential terms handed in (each a
heyoka expression of the position variables, optionally of ``heyoka.time`` for external,
time-dependent physics such as solar radiation pressure). For the truth, V is the mascon sum.

Integrators are compiled once per structure and cached; only states, times and runtime
parameters change afterwards.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence

import heyoka as hy
import numpy as np

from .interiors import MasconSet

__all__ = [
    "STATE_VARIABLES",
    "DEFAULT_TOLERANCE",
    "rotating_hamiltonian",
    "equations_of_motion",
    "mascon_potential_expression",
    "TruthDynamics",
]

x, y, z, px, py, pz = hy.make_vars("x", "y", "z", "px", "py", "pz")
#: The canonical state, in this order everywhere in hamgrav: (x, y, z, p_x, p_y, p_z).
STATE_VARIABLES = (x, y, z, px, py, pz)
POSITION = (x, y, z)

#: Relative/absolute tolerance of truth propagations (Taylor integrator).
DEFAULT_TOLERANCE = 1e-14


def rotating_hamiltonian(potentials: Sequence[hy.expression]) -> hy.expression:
    """H = |p|^2/2 + y p_x - x p_y - sum(potentials)."""
    kinetic = 0.5 * (px * px + py * py + pz * pz) + y * px - x * py
    if not potentials:
        return kinetic
    return kinetic - hy.sum(list(potentials))


def equations_of_motion(hamiltonian: hy.expression) -> list[tuple[hy.expression, hy.expression]]:
    """Hamilton's equations for the canonical state (heyoka system, one pair per variable)."""
    return hy.hamiltonian(hamiltonian, [x, y, z], [px, py, pz])


def mascon_potential_expression(mascons: MasconSet) -> hy.expression:
    """V = sum m_i / |q - q_i| with the masses and positions baked in as constants."""
    terms = [
        float(m) / hy.sqrt((x - float(a)) ** 2 + (y - float(b)) ** 2 + (z - float(c)) ** 2)
        for (a, b, c), m in zip(mascons.positions, mascons.masses, strict=True)
    ]
    return hy.sum(terms)


def _mascon_key(mascons: MasconSet) -> str:
    h = hashlib.sha1()
    h.update(np.ascontiguousarray(mascons.positions).tobytes())
    h.update(np.ascontiguousarray(mascons.masses).tobytes())
    return h.hexdigest()


class TruthDynamics:
    """Truth dynamics of a mascon set: compiled integrators and propagation to time grids.

    Compilation is cached per (mascon set, tolerance); use :meth:`for_mascons` to share it.
    """

    _cache: dict[tuple[str, float], TruthDynamics] = {}

    def __init__(self, mascons: MasconSet, tol: float = DEFAULT_TOLERANCE):
        self.mascons = mascons
        self.tol = tol
        potential = mascon_potential_expression(mascons)
        self.hamiltonian = rotating_hamiltonian([potential])
        self.system = equations_of_motion(self.hamiltonian)
        #: the compiled scalar integrator (shared: set state, time, then propagate)
        self.integrator = hy.taylor_adaptive(
            self.system, [1.0, 0.0, 0.0, 0.0, 1.0, 0.0], tol=tol, compact_mode=True
        )
        self._energy = hy.cfunc([self.hamiltonian], vars=list(STATE_VARIABLES), compact_mode=True)

    @classmethod
    def for_mascons(cls, mascons: MasconSet, tol: float = DEFAULT_TOLERANCE) -> TruthDynamics:
        key = (_mascon_key(mascons), float(tol))
        if key not in cls._cache:
            cls._cache[key] = cls(mascons, tol)
        return cls._cache[key]

    def jacobi(self, states: np.ndarray) -> np.ndarray:
        """The Jacobi integral (the value of H) of canonical states (..., 6)."""
        states = np.asarray(states, dtype=float)
        flat = states.reshape(-1, 6)
        return self._energy(np.ascontiguousarray(flat.T))[0].reshape(states.shape[:-1])

    def propagate(self, state0: np.ndarray, times: np.ndarray, t0: float = 0.0):
        """Propagate one canonical state from ``t0`` to the increasing ``times``.

        Returns ``(states, ok)``: states (len(times), 6), NaN after a failure, and whether the
        integration reached the last time.
        """
        times = np.asarray(times, dtype=float)
        ta = self.integrator
        ta.state[:] = np.asarray(state0, dtype=float)
        ta.time = float(t0)
        out = np.full((len(times), 6), np.nan)
        if len(times) == 0:
            return out, True
        if times[0] != t0:
            grid = np.concatenate([[t0], times])
            res = ta.propagate_grid(grid)
            states = res[-1][1:]
        else:
            res = ta.propagate_grid(times)
            states = res[-1]
        outcome = res[0]
        ok = outcome == hy.taylor_outcome.time_limit
        n = len(states)
        out[:n] = states
        return out, bool(ok and n == len(times))

    def propagate_many(self, states0: np.ndarray, times: np.ndarray, t0: float = 0.0):
        """Propagate several initial states to the same time grid, over all cores.

        Returns ``(states, ok)``: (n, len(times), 6) and (n,) booleans.
        """
        states0 = np.atleast_2d(np.asarray(states0, dtype=float))
        times = np.asarray(times, dtype=float)
        grid = times if times[0] == t0 else np.concatenate([[t0], times])
        skip = 0 if times[0] == t0 else 1
        ta = self.integrator
        ta.time = float(t0)

        def gen(tcopy, i):
            tcopy.state[:] = states0[i]
            tcopy.time = float(t0)
            return tcopy

        results = hy.ensemble_propagate_grid(ta, grid, len(states0), gen)
        out = np.full((len(states0), len(times), 6), np.nan)
        ok = np.zeros(len(states0), bool)
        for i, res in enumerate(results):
            states = res[-1][skip:]
            out[i, : len(states)] = states
            ok[i] = res[1] == hy.taylor_outcome.time_limit and len(states) == len(times)
        return out, ok
