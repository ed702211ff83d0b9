"""Exact sensitivities against central finite differences (tests only), and the shared path."""

from dataclasses import dataclass

import heyoka as hy
import numpy as np
import pytest

from hamgrav.bodies.shape_prior import fit_shape_prior
from hamgrav.core.hamiltonian import POSITION
from hamgrav.core.model import Model, compiled_integrators
from hamgrav.core.problem import ArcProblem
from hamgrav.core.terms import (
    MasconTerm,
    NeuralPotential,
    PointMass,
    SolarRadiationPressure,
    SphericalHarmonics,
    Term,
    sh_coefficients_of_mascons,
)

TOL = 1e-15  # tight, so that finite differences are limited by their step, not the integrator


def _check_fd(problem, theta, columns, rel=1e-6):
    jac = problem.predict(theta, sensitivities=True).jacobian
    for k in columns:
        h = 1e-5 * max(1.0, abs(theta[k]))
        plus, minus = theta.copy(), theta.copy()
        plus[k] += h
        minus[k] -= h
        fd = (problem.predict(plus).states - problem.predict(minus).states) / (2 * h)
        scale = np.abs(jac[..., k]).max()
        assert scale > 0, f"column {k} has no sensitivity"
        assert np.abs(fd - jac[..., k]).max() <= rel * scale, k


@pytest.fixture(scope="module")
def arcs(small_arcs):
    return small_arcs.subset(np.arange(0, 9, 2))  # 5 arcs from three orbits


def test_network_sensitivities(arcs):
    nn = NeuralPotential((16, 16))
    problem = ArcProblem(Model((PointMass(),), nn), arcs, tol=TOL, sensitivity_tol=TOL)
    theta = nn.initial_params(3)
    theta[nn.n_weights :] = 0.05  # non-zero biases exercise every path
    _check_fd(problem, theta, [0, 17, 100, 300, nn.last_bias_index()])


def test_last_bias_has_gradient(arcs):
    nn = NeuralPotential((16, 16))
    problem = ArcProblem(Model((PointMass(),), nn), arcs)
    _, grad = problem.gradient(nn.initial_params(0))
    assert abs(grad[nn.last_bias_index()]) > 1e-6 * np.abs(grad).max()


def test_sh_sensitivities(arcs, synthetic_truth):
    radius = synthetic_truth.body.brillouin_radius
    sh = SphericalHarmonics(4, radius)
    problem = ArcProblem(Model((PointMass(),), sh), arcs, tol=TOL, sensitivity_tol=TOL)
    theta = sh_coefficients_of_mascons(synthetic_truth.mascons, 4, radius)
    _check_fd(problem, theta, range(sh.n_params))


def test_shape_prior_plus_network_sensitivities(arcs, synthetic_truth):
    prior, report = fit_shape_prior(synthetic_truth.body, 40, samples=20_000)
    assert report["perturbing_error_r1.05"] < 0.05
    nn = NeuralPotential((16,))
    problem = ArcProblem(Model((MasconTerm(prior),), nn), arcs, tol=TOL, sensitivity_tol=TOL)
    _check_fd(problem, nn.initial_params(1), [0, 30, nn.n_params - 1])


def test_srp_coefficient_sensitivities(arcs, synthetic_truth):
    units = synthetic_truth.body.units
    srp = SolarRadiationPressure(SolarRadiationPressure.pressure_for(units), 20.0)
    nn = NeuralPotential((16,))
    model = Model((PointMass(),), nn, (srp,))
    problem = ArcProblem(model, arcs, estimate_trajectory_params=True, tol=TOL, sensitivity_tol=TOL)
    theta = np.concatenate([nn.initial_params(2), [0.3, 0.8, 1.5]])
    assert problem.n_params == nn.n_params + 3
    jac = problem.predict(theta, sensitivities=True).jacobian
    # a trajectory's coefficient moves only its own arcs
    for k in range(arcs.n_arcs):
        others = [t for t in range(3) if t != arcs.trajectory[k]]
        assert np.all(jac[k, ..., nn.n_params + np.array(others)] == 0.0)
    _check_fd(problem, theta, [0, nn.n_params, nn.n_params + 1, nn.n_params + 2])


def test_anchor_and_noiseless_truth(small_arcs, synthetic_truth):
    """The truth mascons as a known term reproduce the noiseless arcs: residuals are the noise."""
    from dataclasses import replace

    clean = replace(small_arcs, states=small_arcs.true_states)
    problem = ArcProblem(Model((MasconTerm(synthetic_truth.mascons),)), clean)
    pred = problem.predict(np.zeros(0))
    assert np.allclose(pred.states, small_arcs.true_states, atol=1e-10)


def test_normal_equations_agree_with_design(arcs):
    sh = SphericalHarmonics(3, 0.7)
    problem = ArcProblem(Model((PointMass(),), sh), arcs)
    theta = np.full(sh.n_params, 1e-3)
    r, a = problem.design(theta)
    cost, atr, ata = problem.normal_equations(theta, chunk=2)
    assert cost == pytest.approx(0.5 * r @ r, rel=1e-12)
    assert np.allclose(atr, a.T @ r, rtol=1e-12, atol=1e-20)
    assert np.allclose(ata, a.T @ a, rtol=1e-12, atol=1e-20)
    assert problem.gradient(theta)[1] == pytest.approx(atr, rel=1e-12)


def test_normal_equations_at_the_sensitivity_tolerance_agree_with_tight_ones(arcs):
    """The propagations that carry sensitivities run looser than the states' (order 13 rather
    than 15); the normal equations they give must still agree with tight ones far below what
    an LM step needs."""
    nn = NeuralPotential((16, 16))
    theta = nn.initial_params(1)
    model = Model((PointMass(),), nn)
    loose = ArcProblem(model, arcs)
    assert loose.sensitivity_tol > loose.tol
    cost, atr, ata = loose.normal_equations(theta)
    cost_t, atr_t, ata_t = ArcProblem(model, arcs, sensitivity_tol=TOL).normal_equations(theta)
    assert not np.array_equal(ata, ata_t)  # the looser tolerance is the one in use
    assert cost == pytest.approx(cost_t, rel=1e-10)
    assert np.linalg.norm(atr - atr_t) <= 1e-9 * np.linalg.norm(atr_t)
    assert np.linalg.norm(ata - ata_t) <= 1e-9 * np.linalg.norm(ata_t)
    assert loose.cost(theta) == pytest.approx(cost_t, rel=1e-10)


def test_arc_normals_add_to_known_sums_of_the_same_arcs(arcs):
    """Sums of some arcs at the same parameters are added to: the result equals the sums
    formed from scratch, and only the other arcs are propagated. Sums at other parameters,
    or of other data at the same indices, are not used."""
    sh = SphericalHarmonics(3, 0.7)
    model = Model((PointMass(),), sh)
    problem = ArcProblem(model, arcs)
    theta = np.full(sh.n_params, 1e-3)
    full = problem.arc_normals(theta)
    first = ArcProblem(model, arcs.subset([0, 1, 2])).arc_normals(theta)
    propagated = []
    design = problem.design
    problem.design = lambda th, idx: propagated.extend(idx) or design(th, idx)
    reused = problem.arc_normals(theta, known=first)
    assert sorted(propagated) == [3, 4]
    assert reused.cost == pytest.approx(full.cost, rel=1e-12)
    assert np.allclose(reused.atr, full.atr, rtol=1e-12, atol=1e-20)
    assert np.allclose(reused.ata, full.ata, rtol=1e-12, atol=1e-20)
    assert reused.fingerprint == full.fingerprint
    propagated.clear()
    moved = ArcProblem(model, arcs.subset([0, 1, 2])).arc_normals(theta * 2)
    assert np.allclose(problem.arc_normals(theta, known=moved).ata, full.ata, rtol=1e-12)
    assert sorted(propagated) == [0, 1, 2, 3, 4]
    propagated.clear()
    other = arcs.subset([4, 3, 2])  # other data at indices 0-2
    foreign = ArcProblem(model, other).arc_normals(theta)
    assert np.allclose(problem.arc_normals(theta, known=foreign).ata, full.ata, rtol=1e-12)
    assert sorted(propagated) == [0, 1, 2, 3, 4]


def test_whitening_applies_to_every_sample(arcs):
    """With a whitening W, r_w = (I x W) r and A_w = (I x W) A (one W per sample), the cost
    is half the whitened residuals' sum of squares, and the normal equations are those of
    the whitened A and r. A full W (not triangular, not symmetric) tells W from W^T."""
    sh = SphericalHarmonics(3, 0.7)
    model = Model((PointMass(),), sh)
    w = np.random.default_rng(5).standard_normal((6, 6)) + 3 * np.eye(6)
    plain = ArcProblem(model, arcs)
    weighted = ArcProblem(model, arcs, whitening=w)
    theta = np.full(sh.n_params, 1e-3)
    r, a = plain.design(theta)
    r_w, a_w = weighted.design(theta)
    block = np.kron(np.eye(arcs.n_arcs * arcs.samples_per_arc), w)
    np.testing.assert_allclose(r_w, block @ r, rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(a_w, block @ a, rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(weighted.residuals(theta).reshape(-1), r_w, rtol=0, atol=0)
    assert weighted.cost(theta) == pytest.approx(0.5 * np.sum((block @ r) ** 2), rel=1e-12)
    cost, atr, ata = weighted.normal_equations(theta, chunk=2)
    assert cost == pytest.approx(0.5 * r_w @ r_w, rel=1e-12)
    np.testing.assert_allclose(atr, a_w.T @ r_w, rtol=1e-12, atol=1e-20)
    np.testing.assert_allclose(ata, a_w.T @ a_w, rtol=1e-12, atol=1e-20)
    assert weighted.gradient(theta)[1] == pytest.approx(atr, rel=1e-12)
    assert weighted.cost(theta, [1, 3]) == pytest.approx(
        0.5 * np.sum(r_w.reshape(arcs.n_arcs, -1)[[1, 3]] ** 2), rel=1e-12
    )
    with pytest.raises(ValueError, match="finite \\(6, 6\\) matrix"):
        ArcProblem(model, arcs, whitening=np.ones(6))


def test_arc_weights_scale_each_arcs_rows(arcs):
    """With arc weights w, arc k's residuals and rows of A are sqrt(w_k) times the
    unweighted (after the whitening), its cost w_k times; the weights enter the fingerprint,
    so sums formed under other weights are not reused; bad weights are refused."""
    sh = SphericalHarmonics(3, 0.7)
    model = Model((PointMass(),), sh)
    w = np.diag([3.0, 1.0, 2.0, 50.0, 40.0, 60.0])
    weights = np.array([1.0, 0.25, 4.0, 0.0, 2.0])
    plain = ArcProblem(model, arcs, whitening=w)
    weighted = ArcProblem(model, arcs, whitening=w, arc_weights=weights)
    theta = np.full(sh.n_params, 1e-3)
    r, a = plain.design(theta)
    r_w, a_w = weighted.design(theta)
    rows = np.repeat(np.sqrt(weights), arcs.samples_per_arc * 6)
    np.testing.assert_allclose(r_w, rows * r, rtol=1e-13, atol=0)
    np.testing.assert_allclose(a_w, rows[:, None] * a, rtol=1e-13, atol=0)
    np.testing.assert_allclose(
        weighted.arc_costs(theta), weights * plain.arc_costs(theta), rtol=1e-13
    )
    picked = [4, 1, 2]
    assert weighted.cost(theta, picked) == pytest.approx(
        float(weights[picked] @ plain.arc_costs(theta, picked)), rel=1e-12
    )
    cost, atr, ata = weighted.normal_equations(theta, chunk=2)
    np.testing.assert_allclose(atr, a_w.T @ r_w, rtol=1e-12, atol=1e-20)
    np.testing.assert_allclose(ata, a_w.T @ a_w, rtol=1e-12, atol=1e-20)
    # arcs 0 and 2 keep weight 1 under the other weights: only their fingerprints agree
    other = ArcProblem(model, arcs, whitening=w, arc_weights=np.array([1, 1, 4.0, 1, 1]))
    assert other.fingerprint([0, 2]) == weighted.fingerprint([0, 2])
    assert other.fingerprint([0, 1]) != weighted.fingerprint([0, 1])
    for bad, says in (
        (np.ones(4), "got shape \\(4,\\)"),
        (np.array([1.0, -1, 1, 1, 1]), "got -1.0 for arc 1"),
        (np.array([1.0, 1, np.nan, 1, 1]), "got nan for arc 2"),
    ):
        with pytest.raises(ValueError, match=f"arc_weights must be 5 finite numbers.*{says}"):
            ArcProblem(model, arcs, arc_weights=bad)


def test_compiled_once_per_structure():
    m1 = Model((PointMass(),), SphericalHarmonics(3, 0.7))
    m2 = Model((PointMass(),), SphericalHarmonics(3, 0.7))
    assert compiled_integrators(m1, variational=True) is compiled_integrators(m2, variational=True)
    assert compiled_integrators(m1, variational=True) is not compiled_integrators(
        Model((PointMass(),), SphericalHarmonics(3, 0.8)), variational=True
    )


def test_fit_compiles_each_structure_once(arcs):
    """Repeated predictions, gradients and normal equations never recompile."""
    from hamgrav.core.model import cache_info

    model = Model((PointMass(),), SphericalHarmonics(2, 0.71))
    problem = ArcProblem(model, arcs)
    theta = np.zeros(model.n_learn)
    problem.normal_equations(theta)
    problem.cost(theta)
    problem.gradient(theta)  # the adjoint's integrator: compiled on first use
    before = cache_info()
    for _ in range(3):
        problem.normal_equations(theta + 1e-4)
        problem.cost(theta)
        ArcProblem(model, arcs).gradient(theta)
    assert cache_info() == before


def test_known_trajectory_values_are_data(arcs, synthetic_truth):
    """Per-trajectory parameters that are not estimated are taken as given, per trajectory."""
    units = synthetic_truth.body.units
    srp = SolarRadiationPressure(SolarRadiationPressure.pressure_for(units), 20.0)
    model = Model((PointMass(),), None, (srp,))
    values = np.array([[0.0], [50.0], [0.0]])
    moved = ArcProblem(model, arcs, trajectory_values=values).predict(np.zeros(0)).states
    still = ArcProblem(model, arcs, trajectory_values=np.zeros((3, 1))).predict(np.zeros(0))
    for k in range(arcs.n_arcs):
        same = np.allclose(moved[k], still.states[k], rtol=0, atol=0)
        assert same == (arcs.trajectory[k] != 1)
    with pytest.raises(ValueError, match="trajectory_values of shape"):
        ArcProblem(model, arcs)


def test_bad_theta_named(arcs):
    problem = ArcProblem(Model((PointMass(),), SphericalHarmonics(3, 0.7)), arcs)
    with pytest.raises(ValueError, match="theta must have 12 entries"):
        problem.predict(np.zeros(5))


@dataclass(frozen=True)
class _ConstantForce(Term):
    """A per-trajectory constant acceleration (a_x, a_y, a_z): a second kind of trajectory
    parameter, three per trajectory, written without touching the model or the problem."""

    trajectory_params = 3

    def potential(self, offset: int = 0):
        x, y, z = POSITION
        return hy.par[offset] * x + hy.par[offset + 1] * y + hy.par[offset + 2] * z

    def key(self) -> str:
        return "force"

    def describe(self) -> dict:
        return {"kind": "force"}


def test_any_per_trajectory_term_is_estimated(arcs, synthetic_truth):
    """Two per-trajectory terms (SRP, 1 value; a constant force, 3 values) estimated with the
    learnable term: layout trajectory-major, exact sensitivities, each trajectory's columns
    moving only its own arcs."""
    units = synthetic_truth.body.units
    srp = SolarRadiationPressure(SolarRadiationPressure.pressure_for(units), 20.0)
    sh = SphericalHarmonics(2, synthetic_truth.body.brillouin_radius)
    model = Model((PointMass(),), sh, (srp, _ConstantForce()))
    problem = ArcProblem(model, arcs, estimate_trajectory_params=True, tol=TOL, sensitivity_tol=TOL)
    assert model.n_trajectory_params == 4 and problem.n_params == sh.n_params + 3 * 4
    rng = np.random.default_rng(5)
    per_traj = np.column_stack([[0.2, 0.6, 1.1], rng.normal(size=(3, 3)) * 1e-4])
    theta = np.concatenate([np.full(sh.n_params, 1e-3), per_traj.ravel()])
    assert np.array_equal(problem.trajectory_params(theta), per_traj)
    jac = problem.predict(theta, sensitivities=True).jacobian
    for k in range(arcs.n_arcs):
        own = sh.n_params + 4 * arcs.trajectory[k] + np.arange(4)
        others = np.setdiff1d(np.arange(sh.n_params, problem.n_params), own)
        assert np.all(jac[k, ..., others] == 0.0)
        assert np.all(np.abs(jac[k, 1:, :, own]).max(axis=(1, 2)) > 0)
    _check_fd(problem, theta, [0, sh.n_params + 1, sh.n_params + 4 * 2 + 3])
