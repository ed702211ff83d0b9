import numpy as np
import pytest
import trimesh

from hamgrav.core.model import TRUTH_TOLERANCE
from hamgrav.sim.descent import DescentConfig, Touchdown, descend, miss_statistics, release_states
from hamgrav.units import velocity_to_momentum


def test_descent_aimed_at_a_facet_lands_on_it(synthetic_truth):
    body = synthetic_truth.body
    mesh = body.mesh
    units = body.units
    rng = np.random.default_rng(0)
    for facet in rng.choice(len(mesh.faces), size=3, replace=False):
        centre = mesh.triangles_center[facet]
        normal = mesh.face_normals[facet]
        start = centre + normal * units.to_length(30.0)  # 30 m above the facet
        # fast enough (2 m/s) that gravity and the frame's rotation bend the path by far less
        # than a facet's size over the ~15 s fall
        v = -normal * units.to_velocity(2.0)
        state0 = np.concatenate([start, velocity_to_momentum(start, v)])
        (td,) = descend(
            synthetic_truth.model, [], state0[None], body, DescentConfig(check_step_s=1.0)
        )
        assert td.landed
        _, distance, triangle = trimesh.proximity.closest_point(mesh, td.point[None])
        assert triangle[0] == facet
        assert units.from_length(distance[0]) < 0.01  # refined onto the surface (< 1 cm)


def test_truth_descents_land(synthetic_truth):
    cfg = DescentConfig(count=3)
    states, dvs = release_states(synthetic_truth.body, cfg, seed=1)
    assert np.all((dvs >= 0.01) & (dvs <= 0.03))
    r = np.linalg.norm(states[:, :3], axis=1)
    assert np.allclose(r, 1.3 * synthetic_truth.body.brillouin_radius)
    tds = descend(synthetic_truth.model, [], states, synthetic_truth.body, cfg, tol=TRUTH_TOLERANCE)
    assert all(td.landed and td.time > 0 for td in tds)


def test_statistics_with_not_landed():
    p = np.zeros(3)
    truth = [Touchdown(True, 1.0, p + [0, 0, k]) for k in range(5)]
    model = [
        Touchdown(True, 1.0, p + [0.01, 0, 0]),
        Touchdown(True, 1.0, p + [0.03, 0, 1]),
        Touchdown(False, 2.0, p, "escaped"),
        Touchdown(True, 1.0, p + [0.02, 0, 3]),
        Touchdown(False, 2.0, p, "timed out"),
    ]
    stats = miss_statistics(truth, model, length_m=100.0)
    assert stats["landed"] == 3 and stats["total"] == 5
    assert stats["median_m"] == pytest.approx(2.0)
    assert stats["worst_m"] == pytest.approx(3.0)
    assert stats["p90_m"] == pytest.approx(np.percentile([1.0, 3.0, 2.0], 90))
    none = miss_statistics(truth, [Touchdown(False, 0.0, p)] * 5, 100.0)
    assert none["landed"] == 0 and none["median_m"] is None


def test_release_states_point_inward_within_the_cone(synthetic_truth):
    body = synthetic_truth.body
    config = DescentConfig(count=50)
    states, dvs = release_states(body, config, seed=4)
    q, p = states[:, :3], states[:, 3:]
    radius = np.linalg.norm(q, axis=1)
    np.testing.assert_allclose(radius, config.release_radius_rb * body.brillouin_radius)
    # the momentum is the manoeuvre (inertial velocity from rest), inward within cone_deg
    speed = body.units.from_velocity(np.linalg.norm(p, axis=1))
    np.testing.assert_allclose(speed, dvs, rtol=1e-12)
    assert np.all((dvs >= config.dv_m_s[0]) & (dvs <= config.dv_m_s[1]))
    cos_off = -np.sum(p * q, axis=1) / (np.linalg.norm(p, axis=1) * radius)
    assert np.all(cos_off >= np.cos(np.radians(config.cone_deg)) - 1e-12)
    assert np.degrees(np.arccos(cos_off.min())) > 0.5 * config.cone_deg  # the cone is used
