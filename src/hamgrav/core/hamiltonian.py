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
    "HESSIAN_ENTRIES",
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


#: The six entries of a symmetric 3 x 3 Hessian in the order terms give them: (xx, xy, xz,
#: yy, yz, zz), as (row, column) pairs.
HESSIAN_ENTRIES = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def transition_equations(
    gradient: Sequence[hy.expression], hessian: Sequence[hy.expression]
) -> list[tuple[hy.expression, hy.expression]]:
    """Hamilton's equations of H = |p|^2/2 + y p_x - x p_y - V followed by those of the state
    transition matrix Phi_ij = d x_i / d x_j(t0) (36 variables, row-major), from the gradient
    of V (3 expressions: d/dx, d/dy, d/dz) and its Hessian (6: :data:`HESSIAN_ENTRIES`).

    The Jacobian of the flow is constant apart from d p' / d q = the Hessian of V (the
    rotation's terms are +-1, d q' / d p the identity), so Phi' = J Phi takes 3 to 6
    products per entry and each second derivative of V is formed once (heyoka's
    ``var_ode_sys(..., var_args.vars, order=1)`` forms H_xy and H_yx apart). Terms give V's
    derivatives themselves (:meth:`hamgrav.core.terms.GravityTerm.derivatives`): a network
    forms its Hessian from the same layers as its gradient, which the Taylor decomposition
    then shares."""
    if len(gradient) != 3 or len(hessian) != 6:
        raise ValueError(
            f"the gradient has 3 entries and the Hessian 6, got {len(gradient)} and {len(hessian)}"
        )
    second = {}
    for entry, (i, j) in zip(hessian, HESSIAN_ENTRIES, strict=True):
        second[i, j] = second[j, i] = entry
    # q' = p + (y, -x, 0), p' = (p_y, -p_x, 0) + grad V: the same flow as equations_of_motion
    rates = [px + y, py - x, pz, py + gradient[0], -px + gradient[1], gradient[2]]
    phi = [[hy.expression(f"phi_{i}{j}") for j in range(6)] for i in range(6)]
    system = list(zip(STATE_VARIABLES, rates, strict=True))
    for i in range(6):
        for j in range(6):
            if i < 3:  # d q_i' / d x_k: the rotation in q, the identity in p
                parts = [phi[i + 3][j]]
            else:  # d p_i' / d x_k: the Hessian in q, the rotation in p
                parts = [second[i - 3, k] * phi[k][j] for k in range(3)]
            # d (y, -x, 0) / d (x, y, z): +1 for the first row, -1 for the second
            offset = 3 * (i >= 3)
            if i % 3 == 0:
                parts.append(phi[offset + 1][j])
            elif i % 3 == 1:
                parts.append(-phi[offset][j])
            system.append((phi[i][j], hy.sum(parts)))
    return system
