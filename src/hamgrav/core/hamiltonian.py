"""The body-fixed rotating-frame Hamiltonian and its equations of motion (canonical units).

    H(q, p, t) = |p|^2 / 2 + y p_x - x p_y - V(q, t)

with mu = omega = 1 and V the sum of a model's potential terms (heyoka expressions of the
position variables, optionally of ``heyoka.time`` for external, time-dependent physics such as
solar radiation pressure). The truth is the model whose only term is its mascon set.
"""

from __future__ import annotations

from collections.abc import Sequence

import heyoka as hy

__all__ = [
    "STATE_VARIABLES",
    "POSITION",
    "rotating_hamiltonian",
    "equations_of_motion",
    "transition_equations",
]

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


def transition_equations(hamiltonian: hy.expression) -> list[tuple[hy.expression, hy.expression]]:
    """Hamilton's equations followed by those of the state transition matrix Phi_ij =
    d x_i / d x_j(t0) (36 variables, row-major): Phi' = J Phi with
    J = [[H_pq, H_pp], [-H_qq, -H_qp]], the second derivatives of the Hamiltonian.

    The same system as heyoka's ``var_ode_sys(..., var_args.vars, order=1)``, but each
    second derivative of H is formed once (the Hessian is symmetric, where differentiating
    the equations of motion forms H_xy and H_yx apart) and the constant entries of J fold
    away: for a network potential this halves the Taylor decomposition and nearly halves
    the integrator's cost."""
    tensors = hy.diff_tensors([hamiltonian], list(STATE_VARIABLES), diff_order=2)

    def second(i: int, j: int) -> hy.expression:
        index = [0] * 7
        index[1 + i] += 1
        index[1 + j] += 1
        return tensors[index]

    def jacobian(a: int, b: int) -> hy.expression:  # d f_a / d x_b, f = (H_p, -H_q)
        return second(a + 3, b) if a < 3 else -second(a - 3, b)

    zeros = (hy.expression(0.0), hy.expression(-0.0))
    phi = [[hy.expression(f"phi_{i}{j}") for j in range(6)] for i in range(6)]
    system = list(equations_of_motion(hamiltonian))
    for i in range(6):
        row = [(k, jacobian(i, k)) for k in range(6)]
        row = [(k, e) for k, e in row if not any(e == zero for zero in zeros)]
        for j in range(6):
            rate = hy.sum([e * phi[k][j] for k, e in row]) if row else zeros[0]
            system.append((phi[i][j], rate))
    return system
