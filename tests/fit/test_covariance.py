from dataclasses import replace

import numpy as np
import pytest

from hamgrav.core.problem import ArcProblem
from hamgrav.fit.covariance import formal_covariance
from hamgrav.fit.estimator import GravityEstimator, noise_sigmas


@pytest.fixture(scope="module")
def sh2(small_arcs, synthetic_truth):
    return GravityEstimator("sh", degree=2, body=synthetic_truth.body).fit(small_arcs).fitted_


def test_weighted_fit_covariance_is_the_inverse_weighted_normal_matrix(sh2, small_arcs):
    weighted = replace(sh2, solver={**sh2.solver, "weighted": True})
    cov = formal_covariance(weighted, small_arcs)
    problem = ArcProblem(sh2.model, small_arcs, sigmas=noise_sigmas(small_arcs))
    _, _, ata = problem.normal_equations(sh2.params)
    np.testing.assert_allclose(cov, np.linalg.inv(ata), rtol=1e-8, atol=0)


def test_covariance_scales_with_the_noise(sh2, small_arcs):
    cov = formal_covariance(sh2, small_arcs)
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    noisier = replace(
        small_arcs, sigma_r_m=2 * small_arcs.sigma_r_m, sigma_v_m_s=2 * small_arcs.sigma_v_m_s
    )
    np.testing.assert_allclose(formal_covariance(sh2, noisier), 4 * cov, rtol=1e-10)
