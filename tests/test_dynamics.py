import math

import numpy as np
import pytest

from hamgrav.fields import mascon_acceleration
from hamgrav.hamiltonian import STATE_VARIABLES, TruthDynamics


@pytest.fixture(scope="module")
def dynamics(synthetic_truth):
    return TruthDynamics.for_mascons(synthetic_truth.mascons)


def test_compiled_once(synthetic_truth, dynamics):
    assert TruthDynamics.for_mascons(synthetic_truth.mascons) is dynamics


def test_equations_of_motion_match_mascon_field(dynamics, synthetic_truth, rng):
    """Hamilton's equations give q' = p + (y, -x, 0) and p' = (p_y, -p_x, 0) + grad V."""
    import heyoka as hy

    rhs = hy.cfunc([f for _, f in dynamics.system], vars=list(STATE_VARIABLES))
    states = np.concatenate([rng.normal(size=(20, 3)) + [2.0, 0, 0], rng.normal(size=(20, 3))], 1)
    derivs = rhs(np.ascontiguousarray(states.T)).T
    q, p = states[:, :3], states[:, 3:]
    acc = mascon_acceleration(synthetic_truth.mascons, q)
    assert np.allclose(derivs[:, :3], p + np.c_[q[:, 1], -q[:, 0], 0 * q[:, 0]], atol=1e-14)
    assert np.allclose(derivs[:, 3:], np.c_[p[:, 1], -p[:, 0], 0 * p[:, 0]] + acc, rtol=1e-12)


def test_jacobi_conserved_over_ten_orbits(dynamics, synthetic_truth):
    radius = 1.5 * synthetic_truth.body.brillouin_radius
    state0 = np.array([radius, 0.0, 0.0, 0.0, radius**-0.5, 0.0])
    period = 2 * math.pi * radius**1.5
    states, ok = dynamics.propagate(state0, np.linspace(0.0, 10 * period, 501))
    assert ok
    jacobi = dynamics.jacobi(states)
    assert np.max(np.abs(jacobi - jacobi[0])) / abs(jacobi[0]) < 1e-10
    # and the orbit really went round: it is not a trivial propagation
    angle = np.unwrap(np.arctan2(states[:, 1], states[:, 0]))
    assert abs(angle[-1] - angle[0]) > 2 * math.pi


def test_propagate_many_matches_single(dynamics, synthetic_truth):
    radius = 1.4 * synthetic_truth.body.brillouin_radius
    s0 = np.array(
        [[radius, 0.0, 0.0, 0.0, radius**-0.5, 0.0], [0.0, radius, 0.1, -(radius**-0.5), 0.0, 0.0]]
    )
    times = np.linspace(0.5, 3.0, 7)
    many, ok = dynamics.propagate_many(s0, times)
    assert ok.all()
    for i in range(2):
        single, _ = dynamics.propagate(s0[i], times)
        assert np.allclose(many[i], single, rtol=1e-13, atol=1e-14)
