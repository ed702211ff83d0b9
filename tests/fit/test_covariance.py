"""Formal covariance, sigma_V and the whitened chi-square: checked against a truth that the
model holds exactly (a point mass), where the formal errors must be calibrated."""

from dataclasses import replace

import numpy as np
import pytest

from hamgrav.bodies.evaluation import evaluation_sets
from hamgrav.bodies.interiors import Truth
from hamgrav.core.mascons import MasconSet
from hamgrav.core.propagation import state_transition
from hamgrav.core.shexpansion import sh_potential, sh_term_tables
from hamgrav.core.uncertainty import potential_gradient, potential_sigma
from hamgrav.errors import InputError
from hamgrav.fit.covariance import formal_covariance, sample_covariance, uncertainty_report
from hamgrav.fit.estimator import GravityEstimator
from hamgrav.fit.residuals import residual_report
from hamgrav.sim.tracking import OrbitFamily, TrackingConfig, simulate_orbits

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


def test_networks_have_no_formal_covariance(small_arcs, synthetic_truth):
    from hamgrav.core.model import Model
    from hamgrav.core.terms import NeuralPotential, PointMass
    from hamgrav.fit.fitted import FittedModel

    term = NeuralPotential((4,))
    fitted = FittedModel(
        Model((PointMass(),), term),
        term.initial_params(0),
        "synthetic",
        small_arcs.gm_m3_s2,
        small_arcs.spin_period_s,
    )
    with pytest.raises(InputError, match="formal covariances are computed for SH models only"):
        formal_covariance(fitted, small_arcs)
