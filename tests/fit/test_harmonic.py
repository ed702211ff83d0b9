from dataclasses import replace

import numpy as np
import pytest

from hamgrav.bodies.evaluation import exterior_points
from hamgrav.core.geometry import points_inside
from hamgrav.core.model import Model, evaluate_field, evaluate_laplacian
from hamgrav.core.problem import ArcProblem
from hamgrav.core.terms import NeuralPotential, PointMass, SphericalHarmonics
from hamgrav.errors import InputError
from hamgrav.fit.estimator import GravityEstimator
from hamgrav.fit.harmonic import HarmonicPenalty
from hamgrav.fit.lm import LevenbergMarquardt

NET = Model((PointMass(),), NeuralPotential((5, 4)))


@pytest.fixture(scope="module")
def theta():
    return NET.learnable.initial_params(3) * 3.0  # away from the near-linear start


def _fd_laplacian(model, params, points, h=1e-3):
    """Central second differences of the learnable potential (independent of heyoka's diff)."""
    out = np.zeros(len(points))
    for axis in range(3):
        step = np.zeros(3)
        step[axis] = h
        up = evaluate_field(model, params, points + step)[0]
        down = evaluate_field(model, params, points - step)[0]
        mid = evaluate_field(model, params, points)[0]
        out += (up - 2 * mid + down) / h**2
    return out


def test_laplacian_matches_finite_differences(theta):
    pts = np.array([[1.3, 0.2, -0.4], [-0.7, 1.1, 0.5], [0.3, -0.9, 1.6]])
    lap, _ = evaluate_laplacian(NET, theta, pts)
    assert np.allclose(lap, _fd_laplacian(NET, theta, pts), rtol=1e-4, atol=1e-6)
    assert np.abs(lap).max() > 1e-3  # a network is not harmonic: the check is not vacuous


def test_laplacian_of_spherical_harmonics_vanishes_outside():
    sh = SphericalHarmonics(4, 0.7)
    model = Model((PointMass(),), sh)
    coeffs = np.random.default_rng(1).normal(size=sh.n_params) * 0.05
    pts = np.array([[1.3, 0.2, -0.4], [-0.7, 1.1, 0.5], [0.3, -0.9, 1.6]])
    lap, _ = evaluate_laplacian(model, coeffs, pts)
    scale = np.abs(_fd_laplacian(NET, NET.learnable.initial_params(3) * 3.0, pts)).max()
    assert np.abs(lap).max() < 1e-10 * max(scale, 1.0)


def test_laplacian_gradient_matches_finite_differences(theta):
    pts = np.array([[1.3, 0.2, -0.4], [-0.7, 1.1, 0.5]])
    _, grad = evaluate_laplacian(NET, theta, pts)
    for j in (0, 7, len(theta) - 2, len(theta) - 1):
        step = np.zeros_like(theta)
        step[j] = 1e-6
        fd = (
            evaluate_laplacian(NET, theta + step, pts)[0]
            - evaluate_laplacian(NET, theta - step, pts)[0]
        ) / 2e-6
        assert np.allclose(grad[:, j], fd, rtol=1e-5, atol=1e-8)


def test_exterior_points_lie_outside_and_reach(synthetic):
    pts = exterior_points(synthetic, 2.0, 300, seed=4)
    assert pts.shape == (300, 3)
    assert not points_inside(np.asarray(synthetic.mesh.triangles), pts).any()
    assert np.linalg.norm(pts, axis=1).max() <= 2.0
    assert np.array_equal(pts, exterior_points(synthetic, 2.0, 300, seed=4))


def test_the_penalty_enters_the_objective_not_the_cost(small_arcs, theta, synthetic):
    penalty = HarmonicPenalty(NET, exterior_points(synthetic, 2.0, 50), weight=1e-3)
    plain = ArcProblem(NET, small_arcs)
    penalised = ArcProblem(NET, small_arcs, regulariser=penalty)
    rows, jac = penalty.terms(theta)
    assert penalised.cost(theta) == plain.cost(theta)
    assert penalised.objective(theta) == pytest.approx(plain.cost(theta) + 0.5 * rows @ rows)
    c0, g0, h0 = plain.normal_equations(theta)
    c1, g1, h1 = penalised.normal_equations(theta)
    assert c1 == pytest.approx(c0 + 0.5 * rows @ rows)
    assert np.allclose(g1, g0 + jac.T @ rows) and np.allclose(h1, h0 + jac.T @ jac)
    assert np.array_equal(penalised.normal_equations(theta, regularised=False)[2], h0)


def test_a_harmonic_fit_is_more_harmonic(small_arcs, synthetic_truth):
    def fit(harmonic):
        est = GravityEstimator(
            "network",
            hidden=(6, 6),
            solver=LevenbergMarquardt(max_iter=6, lambda0=1e-2, damping_floor=1e-8),
            harmonic=harmonic,
            validation_fraction=0.0,  # the last iterate, not the best-validation one
            body=synthetic_truth.body,
        )
        return est.fit(small_arcs)

    points = exterior_points(synthetic_truth.body, 2.0, 200, seed=9)
    plain, harmonic = fit(None), fit(1e-2)
    assert harmonic.fitted_.solver["harmonic"] == {"weight": 1e-2, "collocation_points": 1500}
    assert "harmonic" not in plain.fitted_.solver
    rms = [
        np.sqrt(np.mean(evaluate_laplacian(e.model_, e.params_, points)[0] ** 2))
        for e in (plain, harmonic)
    ]
    assert rms[1] < 0.5 * rms[0]


def test_the_penalty_refuses_what_it_cannot_do(small_arcs, synthetic_truth):
    with pytest.raises(InputError, match="needs the LM solver"):
        GravityEstimator("network", hidden=(4,), solver="adam", harmonic=1e-3,
                         body=synthetic_truth.body, adam_steps=2).fit(small_arcs)  # fmt: skip
    with pytest.raises(InputError, match="SH are harmonic already"):
        HarmonicPenalty(Model((PointMass(),), SphericalHarmonics(2, 0.7)), np.ones((3, 3)), 1.0)
    with pytest.raises(InputError, match="weight must be positive"):
        HarmonicPenalty(NET, np.ones((3, 3)), -1.0)


def test_lm_returns_the_arcs_own_normal_matrix_of_its_iterate(small_arcs, synthetic):
    # the fit diagnostics count constrained directions from this matrix instead of
    # recomputing it: it must be the arcs' A^T A (no penalty) at the returned parameters,
    # which with validation arcs is the best-validation iterate, not the last one
    penalty = HarmonicPenalty(NET, exterior_points(synthetic, 2.0, 50), weight=1e-3)
    problem = ArcProblem(NET, small_arcs, regulariser=penalty)
    solver = LevenbergMarquardt(max_iter=6, lambda0=1e-3, damping_floor=1e-8)
    start = NET.learnable.initial_params(5)
    train, validation = np.arange(1, small_arcs.n_arcs), np.array([0])
    result = solver.solve(problem, start, train=train, validation=validation)
    assert result.iterations > result.best_iteration or result.best_iteration > 0
    own = ArcProblem(NET, small_arcs).normal_equations(result.params, train)[2]
    assert np.allclose(result.data_normal, own, rtol=1e-12, atol=0.0)
    penalised = problem.normal_equations(result.params, train)[2]
    assert not np.allclose(result.data_normal, penalised, rtol=1e-6, atol=0.0)


def test_fit_diagnostics_rank_matches_a_fresh_computation(small_arcs, synthetic_truth):
    from hamgrav.fit.diagnostics import constrained_parameters

    est = GravityEstimator(
        "network",
        hidden=(4, 4),
        solver=LevenbergMarquardt(max_iter=4, lambda0=1e-2, damping_floor=1e-8),
        harmonic=1e-3,
        members=2,
        body=synthetic_truth.body,
    ).fit(small_arcs)
    member = ArcProblem(replace(est.model_, learnable=est.model_.learnable.member()), small_arcs)
    blocks = est.model_.learnable.split_members(est.params_)
    fresh = [constrained_parameters(member, b, est.train_) for b in blocks]
    assert est.diagnostics_["constrained_parameters_per_member"] == fresh
    assert 0 < min(fresh) < member.n_params  # not vacuous: a rank between 0 and all
