"""The body-fixed rotating-frame Hamiltonian and its equations of motion (canonical units).

    H(q, p, t) = |p|^2 / 2 + y p_x - x p_y - V(q, t)

with mu = omega = 1 and V the sum of a model's potential terms (heyoka expressions of the
position variables, optionally of ``heyoka.time`` for external, time-dependent physics such as
solar radiation pressure). The truth is the model whose only term is its mascon set.
"""

from __future__ import annotations

from collections.abc import Sequence

import heyoka as hy

__all__ = ["STATE_VARIABLES", "POSITION", "rotating_hamiltonian", "equations_of_motion"]

x, y, z, px, py, pz = hy.make_vars("x", "y", "z", "px", "py", "pz")
#: The canonical state, in this order everywhere in hamgrav: (x, y, z, p_x, p_y, p_z).
STATE_VARIABLES = (x, y, z, px, py, pz)
#: The position variables (x, y, z) that potential terms are written in.
POSITION = (x, y, z)


def rotating_hamiltonian(potentials: Sequence[hy.expression]) -> hy.expression:
    """H = |p|^2/2 + y p_x - x p_y - sum(potentials) (canonical energy per unit mass)."""
    kinetic = 0.5 * (px * px + py * py + pz * pz) + y * px - x * py
    if not potentials:
        return kinetic
    return kinetic - hy.sum(list(potentials))


def equations_of_motion(hamiltonian: hy.expression) -> list[tuple[hy.expression, hy.expression]]:
    """Hamilton's equations for the canonical state (heyoka system, one pair per variable)."""
    return hy.hamiltonian(hamiltonian, [x, y, z], [px, py, pz])
