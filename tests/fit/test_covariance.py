"""Formal covariance, sigma_V and the whitened chi-square: checked against a truth that the
model holds exactly (a point mass), where the formal errors must be calibrated."""

from dataclasses import replace

import numpy as np
import pytest

from hamgrav.bodies.evaluation import evaluation_sets
from hamgrav.bodies.interiors import Truth
from hamgrav.core.fields import shell_points
from hamgrav.core.mascons import MasconSet
from hamgrav.core.model import Model, evaluate_field
from hamgrav.core.problem import ArcProblem
from hamgrav.core.propagation import state_transition
from hamgrav.core.shexpansion import sh_potential, sh_term_tables
from hamgrav.core.terms import NeuralPotential, PointMass
from hamgrav.core.uncertainty import potential_gradient, potential_sigma
from hamgrav.errors import InputError
from hamgrav.fit.covariance import (
    calibration,
    fit_arc_weights,
    formal_covariance,
    normal_system,
    parameter_covariance,
    sample_covariance,
    training_arcs,
    uncertainty_report,
)
from hamgrav.fit.estimator import (
    GravityEstimator,
    fitted_harmonic_penalty,
    noise_sigmas,
    noise_whitening,
)
from hamgrav.fit.fitted import FittedModel
from hamgrav.fit.lm import LevenbergMarquardt
from hamgrav.fit.residuals import residual_report
from hamgrav.sim.tracking import OrbitFamily, TrackingConfig, observe, simulate_orbits

FAMILIES = [OrbitFamily(1.4, 20.0), OrbitFamily(1.7, 75.0), OrbitFamily(2.0, 45.0)]


@pytest.fixture(scope="module")
def point_truth(synthetic_truth):
    return Truth(synthetic_truth.body, MasconSet(np.zeros((1, 3)), np.ones(1)), "point")


@pytest.fixture(scope="module")
def draws(point_truth):
    """SH 2 fits to three noise draws of a point-mass truth (true coefficients: zero)."""
    out = []
    for seed in range(3):
        arcs = simulate_orbits(point_truth, FAMILIES, TrackingConfig(arcs_per_orbit=4), seed=seed)
        fitted = GravityEstimator("sh", degree=2, body=point_truth.body).fit(arcs).fitted_
        out.append((arcs, fitted))
    return out


def test_formal_errors_are_calibrated_when_the_model_holds_the_truth(draws, point_truth):
    z2, z2_white = [], []
    for arcs, fitted in draws:
        cov = formal_covariance(fitted, arcs)
        z2 += list(fitted.params**2 / np.diag(cov))
        white = formal_covariance(fitted, arcs, anchors=False)
        z2_white += list(fitted.params**2 / np.diag(white))
    # 15 coefficients: E z^2 = 1; the anchors' noise is what makes the errors honest
    assert 0.3 < np.mean(z2) < 3.0
    assert np.mean(z2_white) > 10 * np.mean(z2)
    arcs, fitted = draws[0]
    sets = evaluation_sets(point_truth.body, (1.5,), ())
    report = uncertainty_report(fitted, formal_covariance(fitted, arcs), sets, arcs.truth)
    assert 0.2 < report["r1.5"]["rms_z"] < 3.0
    assert report["r1.5"]["rms_sigma_v_m2_s2"] > 0


def test_covariance_scales_with_the_noise(draws):
    arcs, fitted = draws[0]
    cov = formal_covariance(fitted, arcs)
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    noisier = replace(arcs, sigma_r_m=2 * arcs.sigma_r_m, sigma_v_m_s=2 * arcs.sigma_v_m_s)
    np.testing.assert_allclose(formal_covariance(fitted, noisier), 4 * cov, rtol=1e-9)


def test_chi2_of_the_truth_is_one_per_degree_of_freedom(draws):
    arcs, fitted = draws[1]
    report = residual_report(fitted, arcs)
    # no correction is the truth here: whitened residuals of pure noise
    assert abs(report["chi2_per_dof_no_correction"] - 1.0) < 0.1
    assert len(report["rms_position_m"]) == arcs.n_arcs


def test_sigma_v_of_sh_is_exact_linear_algebra(draws):
    arcs, fitted = draws[0]
    term = fitted.model.learnable
    pts = np.array([[0.9, 0.1, 0.2], [-0.3, 0.8, -0.5]])
    g = potential_gradient(fitted.model, fitted.params, pts)
    for k in range(term.n_params):
        unit = np.zeros(term.n_params)
        unit[k] = 1.0
        c, s = sh_term_tables(term, unit, term.degree, term.reference_radius)
        np.testing.assert_allclose(
            g[:, k], sh_potential(c, s, term.reference_radius, pts), rtol=1e-12, atol=1e-15
        )
    cov = np.diag(np.arange(1.0, term.n_params + 1))
    np.testing.assert_allclose(
        potential_sigma(fitted.model, fitted.params, cov, pts),
        np.sqrt(np.einsum("ki,ij,kj->k", g, cov, g)),
        rtol=1e-14,
    )


def test_state_transition_is_symplectic(draws):
    arcs, fitted = draws[0]
    phi = state_transition(
        fitted.model, arcs.states[:3, 0], arcs.times[:3], np.tile(fitted.params[:, None], 3)
    )
    np.testing.assert_array_equal(phi[:, 0], np.broadcast_to(np.eye(6), (3, 6, 6)))
    j = np.block([[np.zeros((3, 3)), np.eye(3)], [-np.eye(3), np.zeros((3, 3))]])
    product = np.einsum("akji,jl,aklm->akim", phi, j, phi)
    np.testing.assert_allclose(product, np.broadcast_to(j, product.shape), atol=1e-9)
    assert np.abs(phi[:, -1] - np.eye(6)).max() > 1e-3  # not trivially the identity


def test_sample_covariance_maps_position_noise_into_momenta():
    s = sample_covariance(2.0, 0.5)
    assert s[3, 3] == 0.25 + 4.0 and s[5, 5] == 0.25  # p_x = v_x - y; p_z = v_z
    assert s[1, 3] == -4.0 and s[0, 4] == 4.0


#: Weights of the three arcs of the arc-weighted tiny fit.
TINY_ARC_WEIGHTS = np.array([1.0, 0.3, 2.5])


@pytest.fixture(
    scope="module",
    params=["unweighted", "weighted", "arc-weighted"],
)
def tiny_fit(request, small_arcs, synthetic_truth):
    """An SH 2 fit to three arcs, unweighted, weighted (whitened) or whitened with
    :data:`TINY_ARC_WEIGHTS`, and its estimator."""
    arcs = small_arcs.subset(np.array([0, 4, 8]))
    whitened = request.param != "unweighted"
    est = GravityEstimator("sh", degree=2, weighted=whitened, body=synthetic_truth.body)
    weights = TINY_ARC_WEIGHTS if request.param == "arc-weighted" else None
    return arcs, est.fit(arcs, arc_weights=weights)


@pytest.mark.parametrize("anchors", [True, False])
def test_covariance_agrees_with_brute_force(tiny_fit, anchors):
    """The normal system against dense linear algebra over all N = 3 x 40 x 6 residuals: the
    fit's weight W^2 = (I x W)^T (I x W) (the identity unweighted), S_e the residuals' noise
    covariance built sample by sample (e_k = n_k - Phi_k n_0 with anchors, n_k without; the
    anchor sample has no residual), G = M^-1 A^T W^2, C = G S_e G^T and
    E[Q] = E[(e - A G e)^T W^2 (e - A G e)]. The data cost is what the fit minimised."""
    arcs, est = tiny_fit
    fitted, weighted = est.fitted_, est.weighted
    arc_weights = fitted.solver.get("arc_weights")
    per_arc = np.ones(arcs.n_arcs) if arc_weights is None else TINY_ARC_WEIGHTS
    sigmas = noise_sigmas(arcs)
    w = noise_whitening(arcs) if weighted else np.eye(6)
    n_arcs, m = arcs.n_arcs, arcs.samples_per_arc
    r, a = ArcProblem(fitted.model, arcs).design(fitted.params)  # canonical r and A
    phi = state_transition(
        fitted.model, arcs.states[:, 0], arcs.times, np.tile(fitted.params[:, None], n_arcs)
    )
    b = np.zeros((len(r), len(r)))  # e = B n for the samples' noise n
    for i in range(n_arcs):
        for k in range(1, m):
            row = slice((i * m + k) * 6, (i * m + k + 1) * 6)
            b[row, row] = np.eye(6)
            if anchors:
                b[row, i * m * 6 : (i * m + 1) * 6] = -phi[i, k]
    s_e = b @ np.kron(np.eye(n_arcs * m), sample_covariance(sigmas[0], sigmas[3])) @ b.T
    # each sample's W times the square root of its arc's weight in the fit's cost
    big_w = np.kron(np.diag(np.repeat(np.sqrt(per_arc), m)), w)
    w2 = big_w.T @ big_w
    normal = a.T @ w2 @ a
    g = np.linalg.solve(normal, a.T @ w2)
    cov = g @ s_e @ g.T
    resid = np.eye(len(r)) - a @ g
    expected = np.trace(resid.T @ w2 @ resid @ s_e)

    system = normal_system(fitted, arcs, anchors=anchors)
    np.testing.assert_allclose(system.data_normal[0], normal, rtol=1e-10)
    # the normal matrix the fit itself used at its solution (weighted: the whitened A)
    problem = est._problem(fitted.model, arcs, None if arc_weights is None else per_arc)
    fit_normal = problem.normal_equations(fitted.params)[2]
    np.testing.assert_allclose(system.data_normal[0], fit_normal, rtol=1e-10)
    assert system.cost[0] == pytest.approx(float(r @ w2 @ r), rel=1e-10)
    assert system.cost[0] == pytest.approx(2 * est.result_.cost, rel=1e-10)
    assert system.noise_trace[0] == pytest.approx(np.trace(w2 @ s_e), rel=1e-10)
    result = system.covariance()
    assert result.ranks == (5,)
    np.testing.assert_allclose(result.matrix, cov, rtol=1e-8, atol=1e-8 * np.abs(cov).max())
    assert result.expected_cost[0] == pytest.approx(expected, rel=1e-8)
    if weighted and arc_weights is None and not anchors:  # white noise, whitened: N - rank
        assert expected == pytest.approx(n_arcs * (m - 1) * 6 - 5, rel=1e-8)


def test_the_weights_of_a_fit_are_read_from_its_record(tiny_fit):
    """fit_arc_weights: None for a fit without arc weights, the recorded weights otherwise;
    a record without per-arc weights (an older file) or other arcs are refused."""
    arcs, est = tiny_fit
    fitted = est.fitted_
    if "arc_weights" not in fitted.solver:
        assert fit_arc_weights(fitted, arcs) is None
        return
    np.testing.assert_array_equal(fit_arc_weights(fitted, arcs), TINY_ARC_WEIGHTS)
    with pytest.raises(InputError, match="weighed 3 arcs and 2 are given"):
        normal_system(fitted, arcs.subset([0, 1]))
    summary = {k: v for k, v in fitted.solver["arc_weights"].items() if k != "values"}
    older = replace(fitted, solver={**fitted.solver, "arc_weights": summary})
    with pytest.raises(InputError, match="does not record the weights per arc"):
        normal_system(older, arcs)


@pytest.fixture(scope="module")
def network_truth(point_truth):
    """Arcs whose truth is a small network (16 parameters) with noise 100x below the
    paper's (the linear regime) and a network fitted to one noise draw, with the draws'
    maker: the network can hold its truth exactly, so its formal errors must be honest."""
    term = NeuralPotential((3,))
    model = Model((PointMass(),), term)
    theta = term.initial_params(5)
    arcs = simulate_orbits(point_truth, FAMILIES, TrackingConfig(arcs_per_orbit=4), seed=2)
    arcs = replace(arcs, sigma_r_m=arcs.sigma_r_m / 100, sigma_v_m_s=arcs.sigma_v_m_s / 100)
    true = ArcProblem(model, replace(arcs, states=arcs.true_states)).predict(theta).states
    sigmas = noise_sigmas(arcs)

    def draw(seed):
        noisy = observe(true, sigmas[0], sigmas[3], np.random.default_rng(seed))
        return replace(arcs, states=noisy, true_states=true)

    def refit(a):
        solver = LevenbergMarquardt(max_iter=60, rtol=1e-12, lambda0=1e-3)
        est = GravityEstimator("network", hidden=(3,), solver=solver, validation_fraction=0.0)
        return est.fit(a, init=theta).fitted_

    arcs0 = draw(0)
    return arcs0, refit(arcs0), draw, refit


def test_network_sigma_matches_the_spread_of_refits(network_truth, point_truth):
    arcs, fitted, draw, refit = network_truth
    cov = parameter_covariance(fitted, arcs)
    assert cov.ranks == (16,) and cov.members == 1  # the arcs constrain every direction
    assert 0.7 < cov.variance_factors[0] < 1.3  # the model holds the truth: residuals = noise
    pts = shell_points(1.7 * point_truth.body.brillouin_radius, 30, 0)
    sigma = potential_sigma(fitted.model, fitted.params, cov.matrix, pts)
    values = []
    for seed in range(1, 25):
        f = refit(draw(seed))
        values.append(evaluate_field(f.model, f.params, pts, which="learnable")[0])
    spread = np.std(values, axis=0, ddof=1)
    # 24 redraws: the spread's own scatter is ~15 %
    assert 0.7 < np.sqrt(np.mean(spread**2) / np.mean(sigma**2)) < 1.35
    assert 0.7 < np.median(spread / sigma) < 1.35


def test_network_covariance_scales_with_the_noise(network_truth):
    arcs, fitted, _, _ = network_truth
    cov = parameter_covariance(fitted, arcs)
    noisier = replace(arcs, sigma_r_m=2 * arcs.sigma_r_m, sigma_v_m_s=2 * arcs.sigma_v_m_s)
    cov2 = parameter_covariance(fitted, noisier)
    np.testing.assert_allclose(cov2.matrix, 4 * cov.matrix, rtol=1e-8, atol=0)
    # a posteriori: the same residuals against a noise stated twice as large
    np.testing.assert_allclose(cov2.variance_factors[0], cov.variance_factors[0] / 4, rtol=1e-8)
    np.testing.assert_allclose(cov2.scaled(), cov.scaled(), rtol=1e-8, atol=0)
    # a threshold above every eigenvalue but the largest keeps one direction
    assert parameter_covariance(fitted, arcs, threshold=0.999).ranks == (1,)


def test_ensemble_members_share_the_noise(network_truth):
    """Two identical members: their mean is either one, so its sigma is one member's, not
    1 / sqrt(2) of it (what independent noise per member would give)."""
    arcs, fitted, _, _ = network_truth
    term = NeuralPotential((3,), members=2)
    pair = FittedModel(
        Model((PointMass(),), term),
        np.concatenate([fitted.params, fitted.params]),
        fitted.body_name,
        fitted.gm_m3_s2,
        fitted.spin_period_s,
        solver=fitted.solver,
    )
    one = parameter_covariance(fitted, arcs)
    both = parameter_covariance(pair, arcs)
    assert both.ranks == (16, 16)
    np.testing.assert_allclose(both.variance_factors, [one.variance_factors[0]] * 2, rtol=1e-9)
    pts = np.array([[1.2, 0.1, 0.0], [-0.3, 1.1, 0.6]])
    single = potential_sigma(fitted.model, fitted.params, one.matrix, pts)
    mean = potential_sigma(pair.model, pair.params, both.matrix, pts)
    np.testing.assert_allclose(mean, single, rtol=1e-7)
    independent = potential_sigma(pair.model, pair.params, both.block_diagonal(), pts)
    np.testing.assert_allclose(independent, single / np.sqrt(2), rtol=1e-7)


def test_calibration_counts():
    out = calibration(np.array([0.5, -1.5, 3.0, 0.1]), np.ones(4))
    assert out["within_1_sigma"] == 0.5 and out["within_2_sigma"] == 0.75
    assert out["median_abs_z"] == 1.0


def test_only_models_with_a_learnable_term_have_a_formal_covariance(small_arcs):
    fitted = FittedModel(
        Model((PointMass(),), None),
        np.zeros(0),
        "synthetic",
        small_arcs.gm_m3_s2,
        small_arcs.spin_period_s,
    )
    with pytest.raises(InputError, match="computed for models with a learnable term"):
        parameter_covariance(fitted, small_arcs)


def test_the_fits_harmonic_penalty_joins_the_normal_matrix(network_truth, point_truth):
    arcs = network_truth[0]
    solver = LevenbergMarquardt(max_iter=3)
    est = GravityEstimator(
        "network", hidden=(3,), members=2, solver=solver, harmonic=1e-5, body=point_truth.body
    )
    fitted = est.fit(arcs).fitted_
    penalty = fitted_harmonic_penalty(fitted, arcs, point_truth.body)
    member = replace(fitted.model, learnable=fitted.model.learnable.member())
    np.testing.assert_array_equal(penalty.points, est.harmonic_penalty(member, arcs).points)
    assert penalty.weight == 1e-5
    data_only = parameter_covariance(fitted, arcs)
    penalised = parameter_covariance(fitted, arcs, penalty=penalty)
    assert penalised.penalised and not data_only.penalised
    assert all(p >= d for p, d in zip(penalised.ranks, data_only.ranks, strict=True))
    # the penalty fixes directions the arcs leave loose: less variance there
    pts = shell_points(1.5 * point_truth.body.brillouin_radius, 20, 1)
    loose = potential_sigma(fitted.model, fitted.params, data_only.matrix, pts)
    tight = potential_sigma(fitted.model, fitted.params, penalised.matrix, pts)
    assert np.mean(tight**2) < np.mean(loose**2)
    # the estimator's training arcs are the ones the covariance uses by default
    np.testing.assert_array_equal(training_arcs(fitted, arcs), est.train_)
