"""The field least-squares problem: its rows and Jacobian, and a fit through the LM solver."""

import numpy as np
import pytest

from hamgrav.core.field_problem import FieldProblem
from hamgrav.core.model import Model, evaluate_field, evaluate_field_parameter_gradient
from hamgrav.core.terms import NeuralPotential, PointMass, SphericalHarmonics
from hamgrav.fit.lm import LevenbergMarquardt

NET = Model((PointMass(),), NeuralPotential((5, 4)))


def _points(n, seed, low=1.2, high=2.0):
    rng = np.random.default_rng(seed)
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    return direction * rng.uniform(low, high, size=(n, 1))


def test_field_parameter_gradient_matches_finite_differences():
    theta = NET.learnable.initial_params(5) * 3.0
    points = _points(7, 1)
    fields, grad = evaluate_field_parameter_gradient(NET, theta, points)
    potential, acceleration = evaluate_field(NET, theta, points)
    assert np.allclose(fields[:, 0], potential, rtol=1e-13, atol=0)
    assert np.allclose(fields[:, 1:], acceleration, rtol=1e-12, atol=1e-15)
    h = 1e-6
    for j in range(0, NET.n_learn, 5):
        step = np.zeros_like(theta)
        step[j] = h
        plus, minus = (
            evaluate_field(NET, theta + step, points),
            evaluate_field(NET, theta - step, points),
        )
        fd_v = (plus[0] - minus[0]) / (2 * h)
        fd_a = (plus[1] - minus[1]) / (2 * h)
        assert np.allclose(grad[:, 0, j], fd_v, rtol=1e-6, atol=1e-9), j
        assert np.allclose(grad[:, 1:, j], fd_a, rtol=1e-6, atol=1e-9), j


def test_design_is_the_residuals_jacobian():
    theta = NET.learnable.initial_params(2)
    points = _points(20, 2)
    values = 1e-2 / np.linalg.norm(points - [0.1, 0.0, 0.0], axis=1)
    problem = FieldProblem(NET, points, values)
    r, a = problem.design(theta, [3, 4, 5])
    assert np.allclose(r, problem.residuals(theta, [3, 4, 5]))
    h = 1e-6
    step = np.zeros_like(theta)
    step[7] = h
    fd = (
        problem.residuals(theta + step, [3, 4, 5]) - problem.residuals(theta - step, [3, 4, 5])
    ) / (2 * h)
    assert np.allclose(a[:, 7], fd, rtol=1e-6, atol=1e-12)
    # the default scale makes J half the squared relative error
    rel = np.sqrt(np.sum((values - evaluate_field(NET, theta, points)[0]) ** 2) / np.sum(values**2))
    assert problem.cost(theta) == pytest.approx(0.5 * rel**2, rel=1e-12)


def test_accelerations_add_three_rows_per_point():
    theta = NET.learnable.initial_params(2)
    points = _points(20, 2)
    centre = np.array([0.1, 0.0, 0.0])
    values = 1e-2 / np.linalg.norm(points - centre, axis=1)
    acc = -1e-2 * (points - centre) / np.linalg.norm(points - centre, axis=1)[:, None] ** 3
    problem = FieldProblem(NET, points, values, acc)
    r, a = problem.design(theta, [0, 5])
    assert r.shape == (8,) and a.shape == (8, NET.n_learn)
    h = 1e-6
    step = np.zeros_like(theta)
    step[3] = h
    fd = (problem.residuals(theta + step, [0, 5]) - problem.residuals(theta - step, [0, 5])) / (
        2 * h
    )
    assert np.allclose(a[:, 3], fd.reshape(-1), rtol=1e-6, atol=1e-12)
    # J: half the squared relative errors of the potential and of the acceleration
    v, g = evaluate_field(NET, theta, points)
    rel_v = np.sum((values - v) ** 2) / np.sum(values**2)
    rel_a = np.sum((acc - g) ** 2) / np.sum(acc**2)
    assert problem.cost(theta) == pytest.approx(0.5 * (rel_v + rel_a), rel=1e-12)


def test_lm_recovers_spherical_harmonics_from_their_field():
    """SH coefficients enter linearly: the fit of their own field returns them."""
    model = Model((PointMass(),), SphericalHarmonics(4, 1.0))
    true = np.random.default_rng(3).normal(scale=1e-3, size=model.n_learn)
    points = _points(400, 4)
    values = evaluate_field(model, true, points)[0]
    problem = FieldProblem(model, points, values)
    result = LevenbergMarquardt(max_iter=10).solve(problem)
    # an exact fit: the cost reaches round-off (the relative-change test then never fires)
    assert result.cost < 1e-25
    assert np.allclose(result.params, true, rtol=1e-7, atol=1e-12)


def test_network_fit_lowers_the_error_and_validation_picks_the_best():
    points = _points(300, 5)
    values = 1e-2 / np.linalg.norm(points - [0.2, 0.1, 0.0], axis=1) - 1e-2 / np.linalg.norm(
        points, axis=1
    )
    problem = FieldProblem(NET, points, values)
    theta0 = NET.learnable.initial_params(0)
    train, held = np.arange(250), np.arange(250, 300)
    result = LevenbergMarquardt(max_iter=30).solve(problem, theta0, train=train, validation=held)
    assert problem.cost(result.params, held) < 0.1 * problem.cost(theta0, held)
    assert result.cost <= problem.objective(theta0, train)


def test_bad_samples_are_refused():
    with pytest.raises(ValueError, match="points must be"):
        FieldProblem(NET, np.zeros((3, 2)), np.zeros(3))
    with pytest.raises(ValueError, match="accelerations must be"):
        FieldProblem(NET, np.ones((3, 3)), np.ones(3), np.ones((2, 3)))
    with pytest.raises(ValueError, match="all zero"):
        FieldProblem(NET, np.ones((3, 3)), np.zeros(3))
    with pytest.raises(ValueError, match="learnable"):
        FieldProblem(Model((PointMass(),), None), np.ones((3, 3)), np.ones(3))


def test_groups_weigh_their_relative_errors_alike():
    """Two groups of points, one with a field 100 times the other's and four times the
    points: with groups, J is half the sum of each group's squared relative error."""
    theta = NET.learnable.initial_params(1)
    near, far = _points(40, 6, 1.1, 1.2), _points(10, 7, 3.0, 3.5)
    points = np.concatenate([near, far])
    values = np.concatenate([np.full(40, 1.0), np.full(10, 0.01)])
    problem = FieldProblem(NET, points, values, groups=np.repeat([0, 1], [40, 10]))
    v, _ = evaluate_field(NET, theta, points)
    rel = [
        np.sum((values[g] - v[g]) ** 2) / np.sum(values[g] ** 2)
        for g in (slice(0, 40), slice(40, 50))
    ]
    assert problem.cost(theta) == pytest.approx(0.5 * sum(rel), rel=1e-12)
    weighted = FieldProblem(
        NET, points, values, groups=np.repeat([0, 1], [40, 10]), group_weights={1: 0.25}
    )
    assert weighted.cost(theta) == pytest.approx(0.5 * (rel[0] + 0.25 * rel[1]), rel=1e-12)
    with pytest.raises(ValueError, match="one label per point"):
        FieldProblem(NET, points, values, groups=np.zeros(3))
    with pytest.raises(ValueError, match="no point"):
        FieldProblem(NET, points, values, groups=np.zeros(50, int), group_weights={1: 0.5})
    with pytest.raises(ValueError, match=">= 0"):
        FieldProblem(NET, points, values, groups=np.zeros(50, int), group_weights={0: -1.0})
