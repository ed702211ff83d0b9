import math

import numpy as np
import pytest

from hamgrav.units import CanonicalUnits, momentum_to_velocity, velocity_to_momentum

ITOKAWA = CanonicalUnits(gm_m3_s2=2.34, spin_period_s=43675.2)


def test_length_unit_is_synchronous_radius():
    # catalogue value of Itokawa's synchronous radius
    assert ITOKAWA.length_m == pytest.approx(483.5506541796145, rel=1e-12)
    omega = 2 * math.pi / 43675.2
    # a circular orbit at one length unit has the spin rate: mu = omega = 1
    assert math.sqrt(2.34 / ITOKAWA.length_m**3) == pytest.approx(omega, rel=1e-12)
    assert ITOKAWA.time_s == pytest.approx(1 / omega)
    assert ITOKAWA.potential_m2_s2 == pytest.approx(2.34 / ITOKAWA.length_m)


@pytest.mark.parametrize(
    "to, back, si",
    [
        ("to_length", "from_length", 123.4),
        ("to_time", "from_time", 14.0),
        ("to_velocity", "from_velocity", 0.02),
        ("to_acceleration", "from_acceleration", 1e-6),
        ("to_potential", "from_potential", 3e-3),
    ],
)
def test_round_trips(to, back, si):
    assert getattr(ITOKAWA, back)(getattr(ITOKAWA, to)(si)) == pytest.approx(si, rel=1e-14)


def test_momentum_mapping(rng):
    q = rng.normal(size=(10, 3))
    v = rng.normal(size=(10, 3))
    p = velocity_to_momentum(q, v)
    # p = v + omega x q with omega = z
    assert np.allclose(p, v + np.cross([0.0, 0.0, 1.0], q))
    assert np.allclose(momentum_to_velocity(q, p), v)


def test_state_round_trip(rng):
    pos = rng.normal(size=(4, 3)) * 500.0
    vel = rng.normal(size=(4, 3)) * 0.05
    back_pos, back_vel = ITOKAWA.state_from_canonical(ITOKAWA.state_to_canonical(pos, vel))
    assert np.allclose(back_pos, pos, rtol=1e-13)
    assert np.allclose(back_vel, vel, rtol=1e-13)


def test_rejects_bad_constants():
    with pytest.raises(ValueError, match="gm_m3_s2 must be a positive finite number"):
        CanonicalUnits(-1.0, 100.0)
