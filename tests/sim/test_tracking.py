import math

import numpy as np
import pytest

from hamgrav.core.geometry import points_inside
from hamgrav.sim.tracking import (
    OrbitFamily,
    SimulationError,
    TrackingConfig,
    arc_start_times,
    circular_orbit_state,
    observe,
    orbit_grid,
    simulate_orbits,
)
from hamgrav.units import momentum_to_velocity


def test_orbit_grid():
    fams = orbit_grid(16, (1.2, 2.0), (10.0, 80.0))
    assert len(fams) == 16
    assert sorted({f.radius_rb for f in fams}) == pytest.approx(
        [1.2, 1.2 + 0.8 / 3, 1.2 + 1.6 / 3, 2.0]
    )
    assert (
        min(f.inclination_deg for f in fams) == 10.0
        and max(f.inclination_deg for f in fams) == 80.0
    )
    assert len(orbit_grid(48, (1.2, 2.0), (10.0, 80.0))) == 48
    with pytest.raises(ValueError, match=r"orbit radius_rb must be a finite number in \(1, 20\]"):
        OrbitFamily(0.9, 10.0)


def test_circular_orbit_state():
    s = circular_orbit_state(2.0, math.radians(30), 0.4, 1.1)
    q, p = s[:3], s[3:]
    assert np.linalg.norm(q) == pytest.approx(2.0)
    assert np.linalg.norm(p) == pytest.approx(math.sqrt(0.5))  # circular speed, mu = 1
    assert q @ p == pytest.approx(0.0, abs=1e-14)
    h = np.cross(q, p)
    assert math.degrees(math.acos(h[2] / np.linalg.norm(h))) == pytest.approx(30.0)


def test_arcs_shape_and_cadence(small_arcs, synthetic_truth):
    arcs = small_arcs
    assert arcs.n_arcs == 9 and arcs.samples_per_arc == 40
    dt = np.diff(arcs.times, axis=1)
    assert np.allclose(dt, synthetic_truth.body.units.to_time(14.0))
    assert list(np.bincount(arcs.trajectory)) == [3, 3, 3]


def test_arcs_never_inside_body(small_arcs, synthetic_truth):
    q = small_arcs.true_states[..., :3].reshape(-1, 3)
    assert not points_inside(np.asarray(synthetic_truth.body.mesh.triangles), q).any()
    # starts too: no first sample inside, and above the surface's largest radius here
    assert np.linalg.norm(small_arcs.states[:, 0, :3], axis=1).min() > 1.0 * (
        synthetic_truth.body.brillouin_radius
    )


def test_arcs_follow_truth(small_arcs, synthetic_truth):
    from hamgrav.core.propagation import propagate_scalar

    for k in (0, 4, 8):
        states, ok = propagate_scalar(
            synthetic_truth.model,
            small_arcs.true_states[k, 0],
            small_arcs.times[k],
            t0=small_arcs.times[k, 0],
            tol=1e-14,
        )
        assert ok and np.allclose(states, small_arcs.true_states[k], atol=1e-10)


def test_noise_statistics(rng):
    sigma_r, sigma_v = 1e-4, 1e-5
    true = np.tile([1.2, -0.3, 0.4, 0.1, 0.8, -0.2], (200_000, 1))
    noisy = observe(true, sigma_r, sigma_v, rng)
    dq = noisy[:, :3] - true[:, :3]
    dv = momentum_to_velocity(noisy[:, :3], noisy[:, 3:]) - momentum_to_velocity(
        true[:, :3], true[:, 3:]
    )
    assert np.std(dq, axis=0) == pytest.approx([sigma_r] * 3, rel=0.01)
    assert np.std(dv, axis=0) == pytest.approx([sigma_v] * 3, rel=0.01)
    assert np.abs(np.mean(dq, axis=0)).max() < 5 * sigma_r / math.sqrt(200_000)
    assert abs(np.corrcoef(dq[:, 0], dv[:, 0])[0, 1]) < 0.01


def test_campaign_noise_levels(small_arcs, synthetic_truth):
    units = synthetic_truth.body.units
    assert small_arcs.sigma_r_m == 0.05
    assert small_arcs.sigma_v_m_s == pytest.approx(units.omega_rad_s * 0.05 / 10)
    dq = (small_arcs.states - small_arcs.true_states)[..., :3]
    assert units.from_length(dq.std()) == pytest.approx(0.05, rel=0.1)  # 1080 draws


def test_reproducible(synthetic_truth):
    fam = [OrbitFamily(1.5, 40.0)]
    cfg = TrackingConfig(arcs_per_orbit=2, samples_per_arc=5, window_spin_periods=0.2)
    a = simulate_orbits(synthetic_truth, fam, cfg, seed=11)
    b = simulate_orbits(synthetic_truth, fam, cfg, seed=11)
    c = simulate_orbits(synthetic_truth, fam, cfg, seed=12)
    assert np.array_equal(a.states, b.states) and np.array_equal(a.times, b.times)
    assert not np.array_equal(a.states, c.states)


def test_impacting_family_rejected(synthetic_truth):
    # an orbit skimming at 1.01 R_B around an elongated body cannot avoid the surface for long
    fam = [OrbitFamily(1.01, 0.0)]
    cfg = TrackingConfig(arcs_per_orbit=1, window_spin_periods=2.0, max_redraws=3)
    with pytest.raises(
        SimulationError, match="touched the surface, escaped or went below min_radius_rb"
    ):
        simulate_orbits(synthetic_truth, fam, cfg, seed=0)


def test_window_too_short(synthetic_truth):
    cfg = TrackingConfig(arcs_per_orbit=50, window_spin_periods=0.05)
    with pytest.raises(SimulationError, match="tracking window is too short"):
        simulate_orbits(synthetic_truth, [OrbitFamily(1.5, 10.0)], cfg)


def test_each_arc_lies_in_its_own_slot(rng):
    # arcs exactly as long as their slots start at the slots' starts
    np.testing.assert_allclose(arc_start_times(rng, 2, 2.0, 1.0), [0.0, 1.0])
    starts = arc_start_times(rng, 7, 10.0, 0.9)
    slot = 10.0 / 7
    assert np.all(starts >= np.arange(7) * slot)
    assert np.all(starts + 0.9 <= (np.arange(7) + 1) * slot + 1e-12)
    with pytest.raises(SimulationError, match="too short for 7 arcs"):
        arc_start_times(rng, 7, 6.0, 0.9)
