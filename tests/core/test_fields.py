import numpy as np

from hamgrav.core.fields import (
    acceleration_field_error,
    field_errors,
    pointwise_field_errors,
    shell_points,
)
from hamgrav.core.mascons import MasconSet, mascon_potential
from hamgrav.core.model import Model
from hamgrav.core.terms import MasconTerm, PointMass, SphericalHarmonics


def _truth_and_prior():
    rng = np.random.default_rng(5)
    pos = rng.normal(size=(40, 3)) * [0.4, 0.2, 0.15]
    mass = rng.uniform(0.5, 1.5, 40)
    pos -= mass @ pos / mass.sum()
    truth = MasconSet(pos, mass / mass.sum())
    # a "shape prior": the same positions at equal masses (a constant-density guess)
    prior = MasconSet(pos, np.full(40, 1.0 / 40))
    return truth, prior


def test_errors_are_of_the_whole_model_against_the_perturbation():
    truth, prior = _truth_and_prior()
    pts = {"r1.5": shell_points(1.5, 300, seed=1)}
    pert = mascon_potential(truth, pts["r1.5"]) - 1.0 / np.linalg.norm(pts["r1.5"], axis=1)
    # the point mass alone: no correction, 1 exactly
    none = field_errors(Model((PointMass(),)), np.zeros(0), truth, pts)["r1.5"]
    assert np.isclose(none, 1.0, rtol=1e-12)
    # the prior alone: how much of the perturbation it misses, by hand
    miss = mascon_potential(prior, pts["r1.5"]) - mascon_potential(truth, pts["r1.5"])
    expected = np.sqrt(np.sum(miss**2) / np.sum(pert**2))
    alone = field_errors(Model((MasconTerm(prior),)), np.zeros(0), truth, pts)["r1.5"]
    assert 0.0 < alone < 1.0 and np.isclose(alone, expected, rtol=1e-12)
    # a residual on the prior is scored on the same scale: a zero residual is the prior alone
    sh = SphericalHarmonics(2, 1.0)
    residual = Model((MasconTerm(prior),), sh)
    assert np.isclose(field_errors(residual, np.zeros(sh.n_params), truth, pts)["r1.5"], alone)


def test_acceleration_error_against_central_differences_of_the_potential():
    truth, prior = _truth_and_prior()
    pts = shell_points(1.2, 200, seed=3)
    assert np.isclose(
        acceleration_field_error(Model((PointMass(),)), np.zeros(0), truth, pts), 1.0, rtol=1e-12
    )
    assert acceleration_field_error(Model((MasconTerm(truth),)), np.zeros(0), truth, pts) < 1e-12

    # the prior's miss, from central differences of the potentials (independent of the
    # acceleration code)
    def gradient(mascons):
        h, out = 1e-6, np.zeros_like(pts)
        for k in range(3):
            step = np.zeros(3)
            step[k] = h
            out[:, k] = (
                mascon_potential(mascons, pts + step) - mascon_potential(mascons, pts - step)
            ) / (2 * h)
        return out

    central = -pts / np.linalg.norm(pts, axis=1, keepdims=True) ** 3
    miss = gradient(prior) - gradient(truth)
    expected = np.sqrt(np.sum(miss**2) / np.sum((gradient(truth) - central) ** 2))
    alone = acceleration_field_error(Model((MasconTerm(prior),)), np.zeros(0), truth, pts)
    assert 0.0 < alone < 1.0 and np.isclose(alone, expected, rtol=1e-6)


def test_pointwise_errors_are_the_one_point_field_error():
    truth, prior = _truth_and_prior()
    pts = shell_points(1.3, 50, seed=2)
    model = Model((MasconTerm(prior),))
    pointwise = pointwise_field_errors(model, np.zeros(0), truth, pts)
    assert pointwise.shape == (50,)
    for k in (0, 17, 49):
        one = field_errors(model, np.zeros(0), truth, {"p": pts[k : k + 1]})["p"]
        assert np.isclose(pointwise[k], one, rtol=1e-12)
    # no correction is 1 at every point
    none = pointwise_field_errors(Model((PointMass(),)), np.zeros(0), truth, pts)
    assert np.allclose(none, 1.0, rtol=1e-12)


def test_member_spread_is_the_members_standard_deviation_over_sqrt_members():
    """Two members: std (ddof 1) / sqrt 2 = |N_0 - N_1| / 2, each member's potential from
    its own one-network model; a single network has no spread."""
    from hamgrav.core.fields import member_spread
    from hamgrav.core.model import evaluate_field
    from hamgrav.core.terms import NeuralPotential

    pair = Model((PointMass(),), NeuralPotential((4,), members=2))
    params = pair.learnable.initial_params(5)
    points = np.array([[1.2, 0.3, -0.2], [0.1, -1.5, 0.4], [2.0, 0.0, 1.0]])
    one = Model((PointMass(),), NeuralPotential((4,)))
    n0, n1 = (evaluate_field(one, b, points)[0] for b in pair.learnable.split_members(params))
    spread = member_spread(pair, params, points)
    np.testing.assert_allclose(spread, np.abs(n0 - n1) / 2, rtol=1e-12)
    assert spread.min() > 0
    np.testing.assert_array_equal(member_spread(one, params[: one.n_learn], points), 0.0)
