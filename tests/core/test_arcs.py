"""Arcs joined from two campaigns (core.arcs.join_arcs)."""

import numpy as np
import pytest

from hamgrav.core.arcs import join_arcs
from hamgrav.sim.descent import tracked_descents
from hamgrav.sim.tracking import OrbitFamily, TrackingConfig, simulate_orbits


@pytest.fixture(scope="module")
def campaign(synthetic_truth):
    families = [OrbitFamily(r, i) for r in (1.3, 1.9) for i in (10.0, 45.0, 80.0)]
    tracking = TrackingConfig(arcs_per_orbit=2, window_spin_periods=0.5)
    return simulate_orbits(synthetic_truth, families, tracking, seed=5)


def test_joined_arcs_number_the_descents_after_the_orbits(campaign, synthetic_truth):
    descents = tracked_descents(synthetic_truth, 2, seed=1)
    joined = join_arcs(campaign, descents)
    assert joined.n_arcs == campaign.n_arcs + 2
    assert joined.trajectory_kind[-2:] == ("descent", "descent")
    assert np.array_equal(joined.arcs_of([6, 7]), np.arange(campaign.n_arcs, joined.n_arcs))
    info = joined.trajectory_info
    assert info["inclination_deg"].shape == (8,) and np.isnan(info["inclination_deg"][6:]).all()
    assert np.array_equal(info["initial_state"][6:], descents.trajectory_info["initial_state"])
    assert np.isnan(info["dv_m_s"][:6]).all()
