"""The adjoint gradient against the forward sensitivities' (the independent reference), on
the models and settings a first-order fit meets."""

import copy
from dataclasses import replace

import heyoka as hy
import numpy as np
import pytest

from hamgrav.core import propagation
from hamgrav.core.model import Model
from hamgrav.core.problem import ArcProblem
from hamgrav.core.propagation import adjoint_gradient
from hamgrav.core.terms import (
    NeuralPotential,
    PointMass,
    SolarRadiationPressure,
    SphericalHarmonics,
)
from hamgrav.errors import PropagationError


def _adjoint(model, arcs, theta, **kwargs):
    """adjoint_gradient of ``arcs`` started at their first samples, the same ``theta`` for all."""
    rp = np.repeat(theta[:, None], arcs.n_arcs, axis=1)
    return adjoint_gradient(
        model, arcs.states[:, 0], arcs.times, arcs.states, rp, n_shared=model.n_learn, **kwargs
    )


def _agree(problem: ArcProblem, theta, rel=1e-9):
    cost, grad = problem.gradient(theta)
    reference = copy.copy(problem)  # the same arcs and settings
    reference.gradient_method = "forward"
    ref_cost, ref_grad = reference.gradient(theta)
    assert cost == pytest.approx(ref_cost, rel=1e-12)
    assert np.abs(grad - ref_grad).max() <= rel * np.abs(ref_grad).max()
    return grad


@pytest.fixture(scope="module")
def network():
    model = Model((PointMass(),), NeuralPotential((6, 5)))
    return model, model.learnable.initial_params(4) * 3.0  # away from the near-linear start


def test_network_gradient_matches_forward_sensitivities(small_arcs, network):
    model, theta = network
    grad = _agree(ArcProblem(model, small_arcs), theta)
    assert np.count_nonzero(grad) > 0.9 * len(grad)


def test_whitened_and_subset_gradient(small_arcs, network):
    model, theta = network
    w = np.diag([3.0, 1.0, 2.0, 50.0, 40.0, 60.0])
    w[0, 1] = 0.5  # not diagonal: W^T W, not W^2
    problem = ArcProblem(model, small_arcs, whitening=w)
    _agree(problem, theta)
    cost, grad = problem.gradient(theta, [1, 4, 7])
    forward = ArcProblem(model, small_arcs, whitening=w, gradient_method="forward")
    ref_cost, ref_grad = forward.gradient(theta, [1, 4, 7])
    assert cost == pytest.approx(ref_cost, rel=1e-12)
    assert np.abs(grad - ref_grad).max() <= 1e-9 * np.abs(ref_grad).max()


def test_weighted_arcs_gradient(small_arcs, network):
    """Arc weights scale each arc's cost and its part of the gradient: the adjoint agrees
    with the forward sensitivities' weighted sums, on all arcs and on a subset."""
    model, theta = network
    weights = np.linspace(0.0, 3.0, small_arcs.n_arcs)
    w = np.diag([3.0, 1.0, 2.0, 50.0, 40.0, 60.0])
    w[0, 1] = 0.5
    problem = ArcProblem(model, small_arcs, whitening=w, arc_weights=weights)
    _agree(problem, theta)
    cost, grad = problem.gradient(theta, [8, 1, 4])
    plain = ArcProblem(model, small_arcs, whitening=w)
    ref = sum(weights[k] * plain.gradient(theta, [k])[1] for k in (8, 1, 4))
    assert cost == pytest.approx(
        sum(weights[k] * plain.cost(theta, [k]) for k in (8, 1, 4)), rel=1e-12
    )
    assert np.abs(grad - ref).max() <= 1e-10 * np.abs(ref).max()


def test_sh_and_estimated_srp_gradient(small_arcs, synthetic_truth):
    units = synthetic_truth.body.units
    srp = SolarRadiationPressure(SolarRadiationPressure.pressure_for(units), 20.0)
    sh = SphericalHarmonics(3, synthetic_truth.body.brillouin_radius)
    model = Model((PointMass(),), sh, (srp,))
    problem = ArcProblem(model, small_arcs, estimate_trajectory_params=True)
    theta = np.concatenate([np.full(sh.n_params, 2e-3), [0.3, 0.8, 1.2]])
    grad = _agree(problem, theta)
    assert np.all(grad[sh.n_params :] != 0)  # each trajectory's coefficient from its own arcs


@pytest.fixture(scope="module")
def long_arcs(synthetic_truth):
    """Arcs of 40 samples 300 s apart (about 1.7 rad of motion, several segments of the
    interpolation, whose ends fall between samples)."""
    from hamgrav.sim.tracking import OrbitFamily, TrackingConfig, simulate_orbits

    families = [OrbitFamily(1.3, 20.0), OrbitFamily(2.0, 45.0), OrbitFamily(1.6, 150.0)]
    tracking = TrackingConfig(arcs_per_orbit=2, cadence_s=300.0, window_spin_periods=2.0)
    return simulate_orbits(synthetic_truth, families, tracking, seed=3)


def test_long_arcs_are_interpolated_on_segments(long_arcs, network, monkeypatch):
    """On arcs spanning several segments the gradient agrees with the forward one; with
    fewer nodes per segment it does not (the check sees the interpolation)."""
    model, theta = network
    counts = propagation._arc_nodes(long_arcs.times, long_arcs.states)[2]
    assert min(counts // propagation.ADJOINT_SEGMENT_NODES) >= 4
    _agree(ArcProblem(model, long_arcs), theta)
    monkeypatch.setattr(propagation, "ADJOINT_SEGMENT_NODES", 3)
    reference = ArcProblem(model, long_arcs, gradient_method="forward").gradient(theta)[1]
    coarse = ArcProblem(model, long_arcs).gradient(theta)[1]
    assert np.abs(coarse - reference).max() > 1e-7 * np.abs(reference).max()


@pytest.mark.parametrize("degree", [8, 16])
def test_high_degree_sh_on_long_arcs(long_arcs, synthetic_truth, degree):
    """SH terms of high degree, whose rates vary along the track faster than low degrees',
    on arcs over several segments, prograde and retrograde."""
    sh = SphericalHarmonics(degree, synthetic_truth.body.brillouin_radius)
    theta = 1e-3 * np.random.default_rng(0).standard_normal(sh.n_params)
    _agree(ArcProblem(Model((PointMass(),), sh), long_arcs), theta)


def test_blocks_of_one_batch_give_the_same_gradient(long_arcs, network, monkeypatch):
    """A thread handles a block of several SIMD batches at once (one grid, padded to the
    block's most nodes); blocks of one batch each give the same numbers, each arc's part to
    the last bits (the sum over blocks is added in another grouping)."""
    model, theta = network
    arcs = long_arcs.subset(np.tile(np.arange(long_arcs.n_arcs), 3))
    blocks = _adjoint(model, arcs, theta, threads=2)
    monkeypatch.setattr(propagation, "_BLOCK_BATCHES", 1)
    batches = _adjoint(model, arcs, theta, threads=2)
    assert blocks.ok.all() and batches.ok.all()
    np.testing.assert_array_equal(batches.costs, blocks.costs)
    assert np.abs(batches.gradient - blocks.gradient).max() <= 1e-14 * np.abs(blocks.gradient).max()


def test_the_motion_rate_is_the_fastest_of_spin_orbit_and_track():
    """Circular equatorial orbits of radius r (canonical: n = r^-3/2, spin 1), in the
    rotating frame: prograde, the track moves at |n - 1| and the rate is max(1, n);
    retrograde, the track moves at n + 1, faster than either."""
    t = np.linspace(0.0, 0.3, 7)

    def circle(r, sense):
        n = r**-1.5
        angle = (sense * n - 1.0) * t  # inertial phase minus the spin's
        q = np.stack([r * np.cos(angle), r * np.sin(angle), 0 * t], axis=-1)
        v = np.stack([-r * np.sin(angle), r * np.cos(angle), 0 * t], axis=-1) * (sense * n - 1)
        p = v + np.stack([-q[:, 1], q[:, 0], 0 * t], axis=-1)  # p = v + z x q
        return np.concatenate([q, p], axis=-1)

    states = np.stack([circle(2.0, 1), circle(0.8, 1), circle(2.0, -1), circle(0.8, -1)])
    n_far, n_near = 2.0**-1.5, 0.8**-1.5
    expected = [1.0, n_near, n_far + 1, n_near + 1]
    np.testing.assert_allclose(propagation._motion_rate(states), expected, rtol=1e-12)


def test_the_node_weights_integrate_polynomials_exactly():
    """The weights W (node x interval) of an arc integrate, on every interval between its
    samples, any polynomial of degree below the nodes per segment given by its values at
    the nodes (sum_i W_ik p(tau_i) = integral of p over interval k), here on one segment and
    on several."""
    n = propagation.ADJOINT_SEGMENT_NODES
    times = np.array([[0.0, 0.013, 0.05, 0.051, 0.2], [0.0, 0.4, 0.9, 1.3, 2.1]])
    states = np.zeros((2, 5, 6))
    states[..., 0] = 2.0  # radius 2: the rate is the spin's, 1
    poly = np.polynomial.Polynomial(np.linspace(1.0, -2.0, n))  # degree n - 1
    node_times, weights, counts = propagation._arc_nodes(times, states)
    assert counts.tolist() == [2 * n, 21 * n]
    assert np.isnan(node_times[0, counts[0] :]).all() and not weights[0, counts[0] :].any()
    for t, nodes, w, k in zip(times, node_times, weights, counts, strict=True):
        exact = np.diff(poly.integ()(t))
        np.testing.assert_allclose(poly(nodes[:k]) @ w[:k], exact, rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("keep", [[0, 19, 39], [0, 39], [0]])
def test_sparse_samples(small_arcs, network, keep):
    """Samples far apart: the quadrature between them spans long intervals (the costate
    pass itself never stops at them); one sample: no interval, a zero gradient."""
    model, theta = network
    sparse = replace(
        small_arcs,
        times=small_arcs.times[:, keep],
        states=small_arcs.states[:, keep],
        true_states=small_arcs.true_states[:, keep],
    )
    _agree(ArcProblem(model, sparse), theta)


def test_a_loose_costate_tolerance_shows_in_the_gradient(small_arcs, network):
    """The gradient depends on the costate pass's tolerance: at 1e-2 it is off by far more
    than at the default (so the comparisons above check the pass, not only the quadrature)."""
    model, theta = network
    ref = ArcProblem(model, small_arcs, gradient_method="forward").gradient(theta)[1]
    loose = _adjoint(model, small_arcs, theta, adjoint_tol=1e-2).gradient
    assert np.abs(loose - ref).max() > 1e-7 * np.abs(ref).max()


def test_sums_do_not_depend_on_threads(small_arcs, network):
    """36 arcs: several SIMD batches on two threads. The sum over batches is added in a
    fixed order, so repeated calls agree to the last bit (a resumed or distributed fit
    depends on it; three or more batches added in the order the threads end would not)."""
    model, theta = network
    arcs = small_arcs.subset(np.tile(np.arange(small_arcs.n_arcs), 4))
    runs = [_adjoint(model, arcs, theta, threads=2) for _ in range(12)]
    assert runs[0].ok.all()
    assert all(np.array_equal(r.gradient, runs[0].gradient) for r in runs[1:])


class _NaNForArc:
    """The parameter rates, NaN at the nodes of the first arc of every call (of every block
    of arcs)."""

    def __init__(self, rates, n_nodes):
        self.rates, self.n_nodes = rates, n_nodes
        self.nparams, self.is_time_dependent = rates.nparams, rates.is_time_dependent

    def __call__(self, points, **kwargs):
        values = self.rates(points, **kwargs)
        values[:, : self.n_nodes] = np.nan
        return values


@pytest.mark.parametrize("reduction", ["none", "not finite"])
def test_an_arc_whose_costate_pass_fails_is_reported(small_arcs, network, monkeypatch, reduction):
    """heyoka's rates not finite at one arc's nodes: that arc, and only it, fails. The
    network's own reduction over a block's nodes is either absent or not finite (then the
    block falls back to the rates node by node, which find the arc)."""
    from hamgrav.core import model as model_module

    model, theta = network
    term = type(model.learnable)
    if reduction == "none":
        monkeypatch.setattr(term, "parameter_rate_sum", lambda self, *a: None)
    else:
        monkeypatch.setattr(term, "parameter_rate_sum", lambda self, p, *a: np.full(len(p), np.nan))
    rates = model_module.parameter_rate_function(model)
    n_nodes = propagation._arc_nodes(small_arcs.times[:1], small_arcs.states[:1])[2][0]
    monkeypatch.setattr(
        model_module, "parameter_rate_function", lambda m: _NaNForArc(rates, n_nodes)
    )
    monkeypatch.setattr(propagation, "_BLOCK_BATCHES", 1)  # several blocks: one batch each
    run = _adjoint(model, small_arcs, theta)
    width = int(hy.recommended_simd_size())
    failed = np.zeros(small_arcs.n_arcs, bool)
    failed[::width] = True  # the first arc of every block
    assert np.array_equal(~run.ok, failed)
    assert np.isnan(run.costs[failed]).all() and np.isfinite(run.costs[~failed]).all()
    assert np.isfinite(run.gradient).all()
    with pytest.raises(PropagationError, match="failed in the gradient's propagation"):
        ArcProblem(model, small_arcs).gradient(theta)


def test_stiff_parameters_are_reported(small_arcs, network):
    model, theta = network
    with pytest.raises(PropagationError, match="gradient"):
        ArcProblem(model, small_arcs, max_steps=1).gradient(theta * 1e3)


def test_unknown_method_refused(small_arcs, network):
    with pytest.raises(ValueError, match="gradient_method"):
        ArcProblem(network[0], small_arcs, gradient_method="reverse")


def test_an_arcs_gradient_does_not_depend_on_the_other_arcs(small_arcs, long_arcs, network):
    """Each arc's nodes are its own (a batch pads the shorter node lists with nodes of
    weight 0): an arc sampled 14 s apart gives the same gradient alone and in one batch with
    an arc sampled 300 s apart, which needs many more nodes."""
    model, theta = network
    dense = replace(
        small_arcs,
        times=small_arcs.times[:, :3],
        states=small_arcs.states[:, :3],
        true_states=small_arcs.true_states[:, :3],
    )
    keep = [0, 19, 38]
    sparse = replace(
        long_arcs,
        times=long_arcs.times[:, keep],
        states=long_arcs.states[:, keep],
        true_states=long_arcs.true_states[:, keep],
    )
    a, b = dense.subset([2]), sparse.subset([1])
    alone_a = _adjoint(model, a, theta, threads=1)
    alone_b = _adjoint(model, b, theta, threads=1)
    together = adjoint_gradient(
        model,
        np.concatenate([a.states[:, 0], b.states[:, 0]]),
        np.concatenate([a.times, b.times]),
        np.concatenate([a.states, b.states]),
        np.repeat(theta[:, None], 2, axis=1),
        n_shared=model.n_learn,
        threads=1,
    )
    expected = alone_a.gradient + alone_b.gradient
    assert np.abs(together.gradient - expected).max() <= 1e-13 * np.abs(expected).max()
    nodes = [propagation._arc_nodes(x.times, x.states)[2][0] for x in (a, b)]
    assert nodes[1] > nodes[0]  # the sparse arc does need more nodes: the batch pads


def test_a_kept_block_layout_gives_the_same_gradient(small_arcs, network, monkeypatch):
    """The second call on the same arcs reads each block's nodes and grid from the kept
    layouts: the same numbers to the last bit, at other parameters too."""
    model, theta = network
    arcs = small_arcs.subset(np.tile(np.arange(small_arcs.n_arcs), 3))
    # blocks of two batches: 27 arcs make two blocks or more at any SIMD width up to 8
    monkeypatch.setattr(propagation, "_BLOCK_BATCHES", 2)
    propagation._forget_layouts()
    first = _adjoint(model, arcs, theta, threads=2)
    kept = len(propagation._LAYOUTS)
    assert kept >= 2
    again = _adjoint(model, arcs, theta, threads=2)
    assert len(propagation._LAYOUTS) == kept  # nothing new formed
    np.testing.assert_array_equal(again.gradient, first.gradient)
    other = _adjoint(model, arcs, theta * 1.1, threads=2)
    propagation._forget_layouts()
    fresh = _adjoint(model, arcs, theta * 1.1, threads=2)
    np.testing.assert_array_equal(fresh.gradient, other.gradient)
