"""The particle swarm: ejections, rejection of impacting or escaping draws, SRP in the truth,
and exact A/m sensitivities on particle arcs."""

import numpy as np
import pytest

from hamgrav.core.model import Model
from hamgrav.core.problem import ArcProblem
from hamgrav.core.terms import PointMass, SphericalHarmonics
from hamgrav.errors import InputError, SimulationError
from hamgrav.sim import particles
from hamgrav.sim.particles import (
    SwarmConfig,
    arcs_per_particle,
    area_to_mass_ratios,
    draw_ejection,
    ejection_outcome,
    simulate_swarm,
    solar_radiation_pressure,
    swarm_truth_model,
)

SMALL = SwarmConfig(particles=3, arcs=5, samples_per_arc=8, window_s=1800.0)


@pytest.fixture(scope="module")
def swarm_arcs(synthetic_truth):
    return simulate_swarm(synthetic_truth, SMALL, seed=3)


def test_area_to_mass_span_and_arc_counts():
    rng = np.random.default_rng(0)
    ratios = area_to_mass_ratios(rng, 28, (0.005, 0.075))
    assert ratios.min() >= 0.005 and ratios.max() <= 0.075
    # stratified: one value per log-interval, so the span is close to the full factor of 15
    assert ratios.max() / ratios.min() > 11
    # one value in each of the 28 equal intervals of log A/m, in shuffled order
    bins = np.floor(28 * np.log(ratios / 0.005) / np.log(15.0)).astype(int)
    assert sorted(bins) == list(range(28)) and list(bins) != sorted(bins)
    for seed in range(10):
        low, high = sorted(area_to_mass_ratios(np.random.default_rng(seed), 2, (1.0, 100.0)))
        assert low < 10.0 < high
    counts = arcs_per_particle(rng, 28, 263)
    assert counts.sum() == 263 and set(counts) == {9, 10} and (counts == 10).sum() == 11


def test_ejection_leaves_the_surface_within_the_cone(synthetic_truth):
    body = synthetic_truth.body
    rng = np.random.default_rng(1)
    for _ in range(20):
        e = draw_ejection(rng, body, SMALL)
        q, p = e.state[:3], e.state[3:]
        v = p - np.array([-q[1], q[0], 0.0])  # rotating-frame velocity v = p - omega x q
        assert np.dot(v, e.normal) / np.linalg.norm(v) >= np.cos(np.radians(45.0)) - 1e-12
        speed_m_s = np.linalg.norm(v) * body.units.velocity_m_s
        escape = np.sqrt(2.0 / np.linalg.norm(q))
        assert speed_m_s == pytest.approx(e.speed_m_s)
        assert 0.6 - 1e-9 <= np.linalg.norm(v) / escape <= 1.0 + 1e-9
        assert np.linalg.norm(q - e.site) * body.units.length_m == pytest.approx(0.5)


def test_kept_particles_neither_impact_nor_escape(swarm_arcs, synthetic_truth):
    info = swarm_arcs.trajectory_info
    assert swarm_arcs.n_arcs == 5 and swarm_arcs.trajectory_kind == ("particle",) * 3
    assert np.bincount(swarm_arcs.trajectory).tolist() in ([2, 2, 1], [2, 1, 2], [1, 2, 2])
    srp = solar_radiation_pressure(synthetic_truth.body.units, SMALL)
    model = swarm_truth_model(synthetic_truth, srp)
    for k in range(3):
        ejection = particles.Ejection(
            float(info["ejection_time"][k]), info["initial_state"][k], info["site"][k],
            np.zeros(3), 0.0, 0.0,
        )  # fmt: skip
        outcome = ejection_outcome(
            model, ejection, info["area_to_mass_m2_kg"][k], synthetic_truth.body, SMALL
        )
        assert outcome.reason == "timed out" and not outcome.landed
    r = np.linalg.norm(swarm_arcs.true_states[..., :3], axis=-1)
    assert r.max() < SMALL.escape_radius_rb * synthetic_truth.body.brillouin_radius
    # every arc lies within the tracking span after its particle's ejection
    t0 = info["ejection_time"][swarm_arcs.trajectory]
    span = synthetic_truth.body.units.to_time(SMALL.window_s)
    assert np.all(swarm_arcs.times[:, 0] >= t0) and np.all(swarm_arcs.times[:, -1] <= t0 + span)


def test_srp_is_in_the_truth(swarm_arcs, synthetic_truth):
    """The arcs follow the truth with each particle's A/m, not the truth without SRP."""
    srp = solar_radiation_pressure(synthetic_truth.body.units, SMALL)
    model = swarm_truth_model(synthetic_truth, srp)
    clean = swarm_arcs.true_states
    from dataclasses import replace

    arcs = replace(swarm_arcs, states=clean)
    am = swarm_arcs.trajectory_info["area_to_mass_m2_kg"][:, None]
    with_srp = ArcProblem(model, arcs, trajectory_values=am).predict(np.zeros(0)).states
    without = ArcProblem(model, arcs, trajectory_values=0 * am).predict(np.zeros(0)).states
    assert np.abs(with_srp - clean).max() < 1e-9
    assert np.abs(without - clean)[:, -1, :3].max() > 1e3 * np.abs(with_srp - clean).max()


def test_a_draw_that_impacts_or_escapes_is_redrawn(synthetic_truth, monkeypatch):
    """Draws whose propagation lands or escapes are rejected and counted; the kept draw is the
    first that survives the tracking span."""
    verdicts = iter(["landed", "escaped", "keep", "escaped", "diverged", "keep", "keep"])
    seen, ratios = [], []

    def scripted(model, ejection, area_to_mass, body, config):
        verdict = next(verdicts)
        seen.append((verdict, ejection.state.copy()))
        ratios.append(area_to_mass)
        if verdict == "landed":
            return particles.Touchdown(True, ejection.time, ejection.state[:3], "")
        if verdict in ("escaped", "diverged"):
            return particles.Touchdown(False, ejection.time, ejection.state[:3], verdict)
        return particles.Touchdown(False, ejection.time + 1.0, ejection.state[:3], "timed out")

    monkeypatch.setattr(particles, "ejection_outcome", scripted)
    arcs = simulate_swarm(synthetic_truth, SMALL, seed=3)
    info = arcs.trajectory_info
    assert info["redraws"].tolist() == [2, 2, 0]  # a diverged draw is redrawn too
    assert info["impacted"].tolist() == [1, 0, 0] and info["escaped"].tolist() == [1, 1, 0]
    # every draw of a particle has that particle's A/m
    per_draw = np.repeat(info["area_to_mass_m2_kg"], [3, 3, 1])
    assert np.array_equal(ratios, per_draw)
    kept = [s for v, s in seen if v == "keep"]
    assert all(np.array_equal(a, b) for a, b in zip(info["initial_state"], kept, strict=True))
    rejected = [s for v, s in seen if v != "keep"]
    assert not any(np.array_equal(s, k) for s in rejected for k in info["initial_state"])


def test_every_draw_rejected_is_an_error(synthetic_truth):
    slow = SwarmConfig(
        particles=1, arcs=1, samples_per_arc=4, window_s=600.0,
        speed_escape_fraction=(0.01, 0.02), max_redraws=3,
    )  # fmt: skip
    with pytest.raises(SimulationError, match="every one of 3 ejections of particle 0"):
        simulate_swarm(synthetic_truth, slow, seed=0)


def test_area_to_mass_sensitivities_on_particle_arcs(swarm_arcs, synthetic_truth):
    """d state / d (A/m) of every particle agrees with central finite differences, and a
    particle's A/m moves only its own arcs."""
    srp = solar_radiation_pressure(synthetic_truth.body.units, SMALL)
    sh = SphericalHarmonics(2, synthetic_truth.body.brillouin_radius)
    model = Model((PointMass(),), sh, (srp,))
    problem = ArcProblem(
        model, swarm_arcs, estimate_trajectory_params=True, tol=1e-15, sensitivity_tol=1e-15
    )
    theta = np.concatenate(
        [np.full(sh.n_params, 1e-3), swarm_arcs.trajectory_info["area_to_mass_m2_kg"]]
    )
    jac = problem.predict(theta, sensitivities=True).jacobian
    for a in range(swarm_arcs.n_arcs):
        own = sh.n_params + swarm_arcs.trajectory[a]
        others = [sh.n_params + k for k in range(3) if sh.n_params + k != own]
        assert np.all(jac[a, ..., others] == 0.0)
        assert np.abs(jac[a, 1:, :, own]).min(axis=-1).max() > 0
    for col in range(sh.n_params, problem.n_params):
        h = 1e-4 * theta[col]
        plus, minus = theta.copy(), theta.copy()
        plus[col] += h
        minus[col] -= h
        fd = (problem.predict(plus).states - problem.predict(minus).states) / (2 * h)
        scale = np.abs(jac[..., col]).max()
        assert scale > 0 and np.abs(fd - jac[..., col]).max() <= 1e-6 * scale


def test_bad_swarm_settings_are_named():
    with pytest.raises(InputError, match="raise window_s to at least"):
        SwarmConfig(particles=2, arcs=6, window_s=100.0)
    with pytest.raises(InputError, match="area_to_mass_m2_kg must be 0 < low <= high"):
        SwarmConfig(area_to_mass_m2_kg=(0.1, 0.01))


def test_particle_noise_is_the_stated_noise(swarm_arcs, synthetic_truth):
    """The noise applied to the samples has the spread the arcs record, in position and in
    (rotating-frame) velocity."""
    from hamgrav.units import momentum_to_velocity

    units = synthetic_truth.body.units
    noisy, true = swarm_arcs.states, swarm_arcs.true_states
    dv = momentum_to_velocity(noisy[..., :3], noisy[..., 3:]) - momentum_to_velocity(
        true[..., :3], true[..., 3:]
    )  # the states hold momenta: the noise is on the rotating-frame velocity
    sigma_r = float(np.std(noisy[..., :3] - true[..., :3])) * units.length_m
    sigma_v = float(np.std(dv)) * units.length_m / units.time_s
    assert sigma_r == pytest.approx(swarm_arcs.sigma_r_m, rel=0.2)
    assert sigma_v == pytest.approx(swarm_arcs.sigma_v_m_s, rel=0.2)
    assert swarm_arcs.sigma_v_m_s < 0.5 * swarm_arcs.sigma_r_m / units.time_s
