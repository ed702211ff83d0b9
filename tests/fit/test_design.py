"""D-optimal orbit design: predicted arcs, information matrices, greedy vs random picks."""

from dataclasses import replace

import numpy as np
import pytest

from hamgrav.core.model import Model
from hamgrav.core.problem import ArcProblem
from hamgrav.core.terms import PointMass, SphericalHarmonics, sh_coefficients_of_mascons
from hamgrav.fit.design import (
    d_optimal_gain,
    greedy_d_optimal,
    information_matrix,
    predicted_arcs,
    random_order_logdet,
    regularisation,
    trajectory_informations,
)
from hamgrav.sim.tracking import OrbitFamily, TrackingConfig, simulate_orbits

# 8 candidates, 1.3 - 2.2 R_B, 0 - 90 deg; 2 arcs of 40 samples in a 0.1 spin-period window
FAMILIES = [
    OrbitFamily(float(r), i)
    for r, i in zip(np.linspace(1.3, 2.2, 8), [0, 90, 30, 60, 15, 75, 45, 5], strict=True)
]
TRACKING = TrackingConfig(arcs_per_orbit=2, samples_per_arc=40, window_spin_periods=0.1)


def _slogdet(m):
    sign, value = np.linalg.slogdet(m)
    assert sign > 0
    return value


def _body_kwargs(truth, seed=3):
    body = truth.body
    return dict(
        brillouin_radius=body.brillouin_radius,
        body_name=body.name,
        gm_m3_s2=body.gm_m3_s2,
        spin_period_s=body.spin_period_s,
        seed=seed,
    )


@pytest.fixture(scope="module")
def sh_model(synthetic_truth):
    r_b = synthetic_truth.body.brillouin_radius
    model = Model((PointMass(),), SphericalHarmonics(3, r_b))
    return model, sh_coefficients_of_mascons(synthetic_truth.mascons, 3, r_b)


@pytest.fixture(scope="module")
def pool(sh_model, synthetic_truth):
    model, theta = sh_model
    arcs = predicted_arcs(model, theta, FAMILIES, TRACKING, **_body_kwargs(synthetic_truth))
    return arcs, trajectory_informations(model, theta, arcs)


def test_predicted_arcs_layout(pool):
    arcs, infos = pool
    assert arcs.n_arcs == 16 and arcs.samples_per_arc == 40
    assert list(np.bincount(arcs.trajectory)) == [2] * 8
    assert arcs.trajectory_info["dropped"].size == 0
    assert np.array_equal(arcs.trajectory_info["candidate"], np.arange(8))
    assert np.array_equal(arcs.states, arcs.true_states) and np.all(np.isfinite(arcs.states))
    assert arcs.interior == "predicted"
    assert len(infos) == 8 and all(info.shape == (12, 12) for info in infos)


@pytest.fixture(scope="module")
def simulated(synthetic_truth):
    """The truth simulation of the same families, tracking and seed (no redraw needed)."""
    arcs = simulate_orbits(synthetic_truth, FAMILIES, TRACKING, seed=3)
    assert np.all(arcs.trajectory_info["redraws"] == 0)
    return arcs


def test_predicted_arcs_follow_simulate_orbits_draws(pool, simulated):
    """Same seed and families: same sample times and initial states as the simulation."""
    arcs, _ = pool
    assert np.array_equal(arcs.times, simulated.times)
    assert np.array_equal(
        arcs.trajectory_info["initial_state"], simulated.trajectory_info["initial_state"]
    )


def test_predicted_arcs_at_exact_coefficients_track_the_truth(pool, simulated, synthetic_truth):
    """Degree-3 SH at the truth's exact coefficients vs the truth propagation of the same
    initial states (the simulation's noiseless states).

    Over the first arc of each candidate the relative position error is below 1e-3 and well
    below that of the point mass alone; over the whole (short) window it stays below 2e-2.
    """
    arcs, _ = pool
    kepler = predicted_arcs(
        Model((PointMass(),)), np.zeros(0), FAMILIES, TRACKING, **_body_kwargs(synthetic_truth)
    )
    q = simulated.true_states[..., :3]

    def rel(pred):
        return np.linalg.norm(pred[..., :3] - q, axis=-1) / np.linalg.norm(q, axis=-1)

    err_sh, err_pm = rel(arcs.states), rel(kepler.states)
    assert np.all(np.isfinite(err_sh))
    first = np.flatnonzero(np.diff(arcs.trajectory, prepend=-1))  # first arc of each orbit
    assert np.all(err_sh[first].max(axis=1) < 1e-3)
    assert np.all(err_sh[first].max(axis=1) < 0.3 * err_pm[first].max(axis=1))
    assert err_sh.max() < 2e-2


def test_point_mass_prediction_conserves_jacobi_constant(synthetic_truth):
    arcs = predicted_arcs(
        Model((PointMass(),)), np.zeros(0), FAMILIES, TRACKING, **_body_kwargs(synthetic_truth)
    )
    s = arcs.states
    x, y, p = s[..., 0], s[..., 1], s[..., 3:]
    r = np.linalg.norm(s[..., :3], axis=-1)
    jacobi = 0.5 * np.sum(p * p, axis=-1) + y * p[..., 0] - x * p[..., 1] - 1.0 / r
    for k in range(len(FAMILIES)):
        h = jacobi[arcs.trajectory == k]
        assert np.ptp(h) < 1e-10, k
    # and the circular starts stay circular (Keplerian): constant radius
    for k in range(len(FAMILIES)):
        radius = r[arcs.trajectory == k]
        assert np.ptp(radius) < 1e-10 * radius.max()


def test_escaping_candidates_are_dropped(sh_model, synthetic_truth, pool):
    """A tight escape radius drops the slightly eccentric predictions and records them."""
    model, theta = sh_model
    tight = replace(TRACKING, escape_factor=1.001)
    arcs = predicted_arcs(model, theta, FAMILIES, tight, **_body_kwargs(synthetic_truth))
    kept, dropped = arcs.trajectory_info["candidate"], arcs.trajectory_info["dropped"]
    assert kept.size and dropped.size
    assert sorted([*kept, *dropped]) == list(range(len(FAMILIES)))
    assert list(np.bincount(arcs.trajectory)) == [2] * kept.size
    full, _ = pool
    assert np.array_equal(arcs.states, full.states[np.isin(full.trajectory, kept)])


def test_information_matrix_is_ata(sh_model, pool):
    model, theta = sh_model
    arcs, infos = pool
    _, a = ArcProblem(model, arcs).design(theta)
    total = information_matrix(model, theta, arcs)
    assert np.allclose(total, a.T @ a, rtol=1e-12, atol=0)
    assert np.allclose(sum(infos), total, rtol=1e-10, atol=0)
    assert np.allclose(infos[0], infos[0].T)


def test_d_optimal_gain_matches_slogdet(pool):
    _, infos = pool
    n = infos[0].shape[0]
    l_acc = infos[2] + infos[5]
    eps = max(1e-8, 1e-6 * np.trace(l_acc) / n)
    assert regularisation(l_acc) == pytest.approx(eps)
    direct = _slogdet(l_acc + infos[0] + eps * np.eye(n)) - _slogdet(l_acc + eps * np.eye(n))
    assert d_optimal_gain(l_acc, infos[0]) == pytest.approx(direct, rel=1e-10)
    first = d_optimal_gain(np.zeros((n, n)), infos[0])  # L_acc = 0: eps = 1e-8
    assert np.isfinite(first) and first > 0
    assert first == pytest.approx(_slogdet(infos[0] + 1e-8 * np.eye(n)) - n * np.log(1e-8))


def test_greedy_maximises_gain_at_each_step(pool):
    _, infos = pool
    n = infos[0].shape[0]
    picked, logdets, gains = greedy_d_optimal(infos, 5)
    assert len(set(picked)) == 5 and len(logdets) == len(gains) == 5
    l_acc = np.zeros((n, n))
    for step, pick in enumerate(picked):
        eye = regularisation(l_acc) * np.eye(n)
        base = _slogdet(l_acc + eye)
        brute = {
            c: _slogdet(l_acc + infos[c] + eye) - base for c in range(8) if c not in picked[:step]
        }
        assert pick == max(brute, key=brute.get)
        assert gains[step] == pytest.approx(brute[pick], rel=1e-9)
        l_acc = l_acc + infos[pick]
        assert logdets[step] == pytest.approx(_slogdet(l_acc + regularisation(l_acc) * np.eye(n)))


def test_greedy_beats_random_orders(pool):
    """Greedy vs seeded random pick orders, on the logdet(L_acc + eps(L_acc) I) history.

    Guaranteed in general: nothing beyond the first pick maximising the *gain* (whose eps is
    that of L_start, the same for every candidate). The history's eps at step 1 is eps(L_c),
    which differs between candidates, so even step 1 of the history is checked, not implied;
    so is every later step. In this pool greedy is ahead (or level, when a random order starts
    with the same candidate) at every step, and its final logdet beats the random mean.
    """
    _, infos = pool
    picked, logdets, _ = greedy_d_optimal(infos, 5)
    finals = []
    for seed in range(5):
        order, rand = random_order_logdet(infos, 5, seed)
        assert order != picked
        if order[0] == picked[0]:
            assert logdets[0] == pytest.approx(rand[0], rel=1e-12)
        else:
            assert logdets[0] > rand[0]
        assert np.all(logdets >= rand - 1e-9 * np.abs(rand))  # true here, not a theorem
        finals.append(rand[-1])
    assert logdets[-1] >= np.mean(finals)
