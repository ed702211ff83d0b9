import math
import multiprocessing

import heyoka as hy
import numpy as np
import pytest

from hamgrav.core import propagation
from hamgrav.core.hamiltonian import STATE_VARIABLES, transition_equations
from hamgrav.core.mascons import mascon_acceleration
from hamgrav.core.model import (
    TRUTH_TOLERANCE,
    Model,
    cache_info,
    compiled_integrators,
    hamiltonian_values,
)
from hamgrav.core.propagation import propagate_batch, propagate_scalar
from hamgrav.core.terms import (
    MasconTerm,
    NeuralPotential,
    PointMass,
    SolarRadiationPressure,
    SphericalHarmonics,
)


@pytest.fixture(scope="module")
def truth_model(synthetic_truth):
    return synthetic_truth.model


def test_truth_compiled_once(synthetic_truth, truth_model):
    first = compiled_integrators(truth_model, batch=False, tol=TRUTH_TOLERANCE)
    builds = cache_info().get("scalar", 0)
    again = compiled_integrators(synthetic_truth.model, batch=False, tol=TRUTH_TOLERANCE)
    assert again is first
    assert cache_info().get("scalar", 0) == builds


def test_equations_of_motion_match_mascon_field(truth_model, synthetic_truth, rng):
    """Hamilton's equations give q' = p + (y, -x, 0) and p' = (p_y, -p_x, 0) + grad V, with V
    from heyoka's fixed-centres expression checked against the numpy mascon sum."""
    rhs = hy.cfunc([f for _, f in truth_model.system()], vars=list(STATE_VARIABLES))
    states = np.concatenate([rng.normal(size=(20, 3)) + [2.0, 0, 0], rng.normal(size=(20, 3))], 1)
    derivs = rhs(np.ascontiguousarray(states.T)).T
    q, p = states[:, :3], states[:, 3:]
    acc = mascon_acceleration(synthetic_truth.mascons, q)
    assert np.allclose(derivs[:, :3], p + np.c_[q[:, 1], -q[:, 0], 0 * q[:, 0]], atol=1e-14)
    assert np.allclose(derivs[:, 3:], np.c_[p[:, 1], -p[:, 0], 0 * p[:, 0]] + acc, rtol=1e-12)


def test_jacobi_conserved_over_ten_orbits(truth_model, synthetic_truth):
    radius = 1.5 * synthetic_truth.body.brillouin_radius
    state0 = np.array([radius, 0.0, 0.0, 0.0, radius**-0.5, 0.0])
    period = 2 * math.pi * radius**1.5
    times = np.linspace(0.0, 10 * period, 501)
    states, ok = propagate_scalar(truth_model, state0, times, tol=TRUTH_TOLERANCE)
    assert ok
    jacobi = hamiltonian_values(truth_model, states)
    assert np.max(np.abs(jacobi - jacobi[0])) / abs(jacobi[0]) < 1e-10
    # and the orbit really went round: it is not a trivial propagation
    angle = np.unwrap(np.arctan2(states[:, 1], states[:, 0]))
    assert abs(angle[-1] - angle[0]) > 2 * math.pi


def test_batch_matches_scalar(truth_model, synthetic_truth):
    radius = 1.4 * synthetic_truth.body.brillouin_radius
    s0 = np.array(
        [[radius, 0.0, 0.0, 0.0, radius**-0.5, 0.0], [0.0, radius, 0.1, -(radius**-0.5), 0.0, 0.0]]
    )
    times = np.array([np.linspace(0.5, 3.0, 7), np.linspace(1.0, 2.0, 7)])
    run = propagate_batch(truth_model, s0, times, tol=TRUTH_TOLERANCE, threads=2)
    assert run.ok.all()
    for i in range(2):
        single, _ = propagate_scalar(truth_model, s0[i], times[i], t0=times[i, 0], tol=1e-14)
        assert np.allclose(run.states[i], single, rtol=1e-13, atol=1e-14)


def test_batch_marks_failures_instead_of_raising():
    """A runaway propagation is reported per trajectory (ok False, NaN states)."""
    model = Model((PointMass(),), SphericalHarmonics(2, 0.5))
    state = np.array([[0.7, 0.0, 0.0, 0.0, 1.2, 0.0]])
    times = np.linspace(0.0, 2.0, 5)[None]
    pars = np.full((model.n_system_params, 1), 1e6)  # an absurd field: stiff or singular
    run = propagate_batch(model, state, times, pars, max_steps=50)
    assert not run.ok[0] and run.exceeded_steps[0]
    assert np.isnan(run.states).all()


def test_mascon_term_uses_the_truth_potential(synthetic_truth, rng):
    """The model of a truth is its mascon term: same potential as the numpy reference."""
    from hamgrav.core.mascons import mascon_potential
    from hamgrav.core.model import evaluate_field

    model = Model((MasconTerm(synthetic_truth.mascons),))
    pts = rng.normal(size=(10, 3)) * 2.0
    v, _ = evaluate_field(model, np.zeros(0), pts, which="known")
    assert np.allclose(v, mascon_potential(synthetic_truth.mascons, pts), rtol=1e-13)


def _propagate_into(pipe, model, states, times):
    pipe.send(propagate_batch(model, states, times, threads=2).states)


@pytest.mark.skipif(
    "fork" not in multiprocessing.get_all_start_methods(), reason="needs the fork start method"
)
def test_a_forked_child_propagates_on_threads_of_its_own():
    """The propagation threads are started once per process: a child forked after the parent
    used them (it inherits the pool but not its threads) must start its own, not wait."""
    model = Model((PointMass(),))
    radius = 2.0
    state0 = [radius, 0.0, 0.0, 0.0, radius**-0.5, 0.0]
    states = np.tile(state0, (8, 1))  # two SIMD batches of 4: both threads work
    times = np.tile(np.linspace(0.0, 1.0, 5), (8, 1))
    parent = propagate_batch(model, states, times, threads=2).states
    receive, send = multiprocessing.Pipe(duplex=False)
    child = multiprocessing.get_context("fork").Process(
        target=_propagate_into, args=(send, model, states, times)
    )
    child.start()
    got = receive.recv() if receive.poll(60) else None
    child.join(10)
    if child.is_alive():
        child.kill()
    assert got is not None, "the forked child's propagation did not finish within 60 s"
    assert np.array_equal(got, parent)


@pytest.mark.parametrize("learnable", ["network", "sh"])
def test_transition_equations_equal_heyokas_variational_system(synthetic_truth, learnable, rng):
    """The state transition equations formed from the symmetric Hessian of H equal heyoka's
    own variational system with respect to the state, term by term in the same order, at
    random states, parameters and times (a learnable term and a time-dependent SRP term)."""
    units = synthetic_truth.body.units
    srp = SolarRadiationPressure(SolarRadiationPressure.pressure_for(units), 20.0)
    if learnable == "network":
        term = NeuralPotential((5, 4))
    else:
        term = SphericalHarmonics(4, synthetic_truth.body.brillouin_radius)
    model = Model((PointMass(),), term, (srp,))
    ours = transition_equations(*model.potential_derivatives())
    reference = hy.var_ode_sys(model.system(), hy.var_args.vars, order=1).sys
    assert len(ours) == len(reference) == 42
    n = 50
    state = np.concatenate([rng.normal(size=(6, n)), rng.normal(size=(36, n))])
    state[:3] *= 1.5 / np.linalg.norm(state[:3], axis=0)  # outside the unit sphere
    pars = rng.normal(size=(model.n_system_params, n)) * 0.1
    time = rng.uniform(0.0, 10.0, n)
    values = []
    for system in (ours, reference):
        f = hy.cfunc([rate for _, rate in system], vars=[v for v, _ in system])
        values.append(f(state, pars=pars[: f.nparams], time=time))
    assert np.all(np.isfinite(values[1]))
    np.testing.assert_allclose(
        values[0], values[1], rtol=1e-12, atol=1e-12 * np.abs(values[1]).max()
    )


def _oscillators(width: int, tol: float = 1e-10):
    """A batch of (x, v, x^2 blowing up from x = 1 at t = 1): a system with a lane that can
    fail, and steps short enough that a long grid takes several."""
    x, v, w = hy.make_vars("x", "v", "w")
    state = np.zeros((3, width))
    state[0], state[1], state[2] = 1.0, 0.0, 0.1
    ta = hy.taylor_adaptive_batch([(x, v), (v, -x), (w, w * w)], state, tol=tol)
    return ta, state


def _lanes_and_grid(grid: np.ndarray, start_w: np.ndarray, max_steps=None):
    """_propagate_lanes and heyoka's propagate_grid batch by batch, from the same starts."""
    width = int(hy.recommended_simd_size())
    ta, state = _oscillators(width)
    n_lanes = grid.shape[0]

    def prepare(b):
        lanes = slice(b * width, (b + 1) * width)
        ta.set_time(np.ascontiguousarray(grid[lanes, 0]))
        ta.state[:] = state
        ta.state[0] = np.cos(grid[lanes, 0])
        ta.state[1] = -np.sin(grid[lanes, 0])
        ta.state[2] = start_w[lanes]

    ours, stopped = propagation._propagate_lanes(ta, grid, prepare, max_steps)
    reference = np.empty_like(ours)
    for b in range(n_lanes // width):
        prepare(b)
        lanes = slice(b * width, (b + 1) * width)
        states, _ = propagation._propagate_grid(ta, np.ascontiguousarray(grid[lanes].T), None)
        reference[lanes] = states.transpose(2, 0, 1)
    return ours, stopped, reference


def test_lanes_in_one_step_equal_heyokas_dense_output(rng):
    """Arcs that each end in one Taylor step (three batches): the polynomials' values at
    the grid equal heyoka's propagate_grid to rounding, the first point is the start."""
    width = int(hy.recommended_simd_size())
    n = 3 * width
    start = rng.uniform(0.0, 3.0, n)
    grid = start[:, None] + np.sort(rng.uniform(0.0, 0.05, (n, 30)), axis=1)
    grid[:, 0] = start
    ours, stopped, reference = _lanes_and_grid(grid, np.full(n, 0.1))
    assert not stopped.any()
    np.testing.assert_allclose(ours, reference, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(ours[:, -1, 0], np.cos(grid[:, -1]), rtol=1e-9)


def test_lanes_over_several_steps_or_failing_go_through_heyokas_grid(rng):
    """A batch whose arcs take several steps, and one with a lane that blows up, go through
    propagate_grid (the same numbers); the batches around them keep theirs; a start-only
    grid is the initial state; a step cap stops the long batch and leaves it NaN."""
    width = int(hy.recommended_simd_size())
    n = 3 * width
    start = rng.uniform(0.0, 1.0, n)
    span = np.full(n, 0.05)
    span[width : 2 * width] = 6.0  # the second batch: several steps
    grid = start[:, None] + span[:, None] * np.linspace(0.0, 1.0, 25)
    w0 = np.full(n, 0.1)
    w0[-1] = 40.0  # w = w0 / (1 - w0 t) blows up at t = 0.025 into the last lane's arc
    ours, stopped, reference = _lanes_and_grid(grid, w0)
    assert not stopped.any()
    good = np.ones(n, bool)
    good[-1] = False
    np.testing.assert_allclose(ours[good], reference[good], rtol=1e-13, atol=1e-14)
    assert not np.all(np.isfinite(ours[-1]))
    np.testing.assert_allclose(
        ours[width : 2 * width, -1, 0], np.cos(grid[width : 2 * width, -1]), rtol=1e-8
    )

    single = grid[:, :1]
    ours, stopped, _ = _lanes_and_grid(single, w0)
    np.testing.assert_array_equal(ours[:, 0, 0], np.cos(single[:, 0]))

    ours, stopped, _ = _lanes_and_grid(grid, np.full(n, 0.1), max_steps=1)
    np.testing.assert_array_equal(stopped, span > 1.0)
    assert np.isnan(ours[stopped]).all() and np.isfinite(ours[~stopped]).all()
