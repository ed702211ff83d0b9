import math
from dataclasses import replace

import numpy as np
import pytest
from scipy import stats

from hamgrav.core.model import Model, cache_info
from hamgrav.core.problem import ArcNormals, ArcProblem
from hamgrav.core.terms import (
    NeuralPotential,
    PointMass,
    SphericalHarmonics,
    sh_coefficients_of_mascons,
)
from hamgrav.errors import InputError, PropagationError
from hamgrav.fit.adam import Adam
from hamgrav.fit.base import Outcome
from hamgrav.fit.continual import ContinualFit, fit_continual
from hamgrav.fit.estimator import GravityEstimator
from hamgrav.fit.estimator import validation_split as split_validation
from hamgrav.fit.kaula import KaulaPrior, kaula_diagonal, scan_kaula
from hamgrav.fit.lm import LevenbergMarquardt, _solve_spd


@pytest.fixture(scope="module")
def sh_world(small_arcs, synthetic_truth):
    """A truth that is itself an SH field (degree 4), and arcs propagated under it."""
    r_b = synthetic_truth.body.brillouin_radius
    sh = SphericalHarmonics(4, r_b)
    model = Model((PointMass(),), sh)
    c_true = sh_coefficients_of_mascons(synthetic_truth.mascons, 4, r_b)
    anchored = replace(small_arcs, states=small_arcs.true_states)
    states = ArcProblem(model, anchored, tol=1e-15).predict(c_true).states
    return model, c_true, replace(small_arcs, states=states, true_states=states)


def test_lm_recovers_sh_truth_from_noiseless_arcs(sh_world):
    model, c_true, arcs = sh_world
    result = LevenbergMarquardt(rtol=1e-12, max_iter=20).solve(
        ArcProblem(model, arcs, tol=1e-15, sensitivity_tol=1e-15)
    )
    assert np.abs(result.params - c_true).max() < 1e-8 * np.abs(c_true).max()
    assert result.history["accepted"][1]


def test_lm_noisy_within_formal_covariance(sh_world):
    model, c_true, arcs = sh_world
    rng = np.random.default_rng(3)
    sigma = np.array([1e-4] * 3 + [1e-5] * 3)
    noisy = arcs.states.copy()
    noisy[:, 1:] += rng.standard_normal(noisy[:, 1:].shape) * sigma  # anchors kept exact
    problem = ArcProblem(model, replace(arcs, states=noisy), whitening=np.diag(1 / sigma))
    result = LevenbergMarquardt(rtol=1e-10).solve(problem)
    _, _, ata = problem.normal_equations(result.params)
    d = result.params - c_true
    chi2 = float(d @ ata @ d)  # covariance = (A^T A)^-1 for unit-weight residuals
    assert chi2 < stats.chi2.ppf(0.999, df=len(d))
    assert chi2 > stats.chi2.ppf(0.001, df=len(d))  # and not suspiciously exact


def test_kaula_diagonal_and_scan(sh_world):
    model, c_true, arcs = sh_world
    problem = ArcProblem(model, arcs)
    k = kaula_diagonal(problem)
    assert k[0] == 16.0 and k[-1] == 256.0  # C20 ... S44
    alpha, result, scores = scan_kaula(
        problem, lambda c: float(np.linalg.norm(c - c_true)), alphas=(1e-8, 1e-2, 1e2)
    )
    assert alpha == 1e-8  # noiseless data: the least regularised fit is the best
    assert [a for a, _ in scores] == [1e-8, 1e-2, 1e2]
    assert scores[-1][1] > scores[0][1]


def test_kaula_scan_never_keeps_a_weight_whose_fit_does_not_propagate(sh_world):
    model, c_true, arcs = sh_world
    problem = ArcProblem(model, arcs)

    def metric(c):
        # the held-out arcs do not propagate under the least regularised fit
        if np.linalg.norm(c - c_true) < 1e-3:
            raise PropagationError("arcs [3] did not propagate to the end")
        return float(np.linalg.norm(c - c_true))

    alpha, _, scores = scan_kaula(problem, metric, alphas=(1e-8, 1e-2, 1e2))
    assert scores[0] == (1e-8, math.inf)
    assert alpha == 1e-2 and math.isfinite(scores[1][1])


def test_warm_start_converges_faster(sh_world, synthetic_truth):
    model, _, arcs = sh_world
    rng = np.random.default_rng(0)
    noisy = replace(arcs, states=arcs.states + rng.normal(size=arcs.states.shape) * 1e-6)
    stages = [np.arange(0, 5), np.arange(5, 9)]

    def estimator():
        return GravityEstimator(
            "sh",
            degree=4,
            validation_fraction=0.0,
            solver=LevenbergMarquardt(rtol=1e-9),
            body=synthetic_truth.body,
        )

    warm_fit, cold_fit = estimator(), estimator()
    warm = fit_continual(warm_fit, noisy, stages)
    cold = fit_continual(cold_fit, noisy, stages, warm_start=False)
    assert warm_fit.model_.key() == model.key()
    assert warm[1].n_arcs == cold[1].n_arcs == 9
    assert warm[1].warm_started and not cold[1].warm_started
    assert warm[1].result.iterations < cold[1].result.iterations
    assert warm[1].result.cost == pytest.approx(cold[1].result.cost, rel=1e-6)
    assert [s["stage"] for s in warm_fit.fitted_.stages] == [0, 1]
    # every stage says how much of the no-correction cost it leaves (no hold-out here)
    for record, stage in zip(warm, warm_fit.fitted_.stages, strict=True):
        assert record.checked_on == stage["checked_on"] == "training arcs"
        assert 0 < record.relative_cost == stage["relative_cost"] < 1e-3


def test_a_stage_the_previous_model_cannot_propagate_restarts_and_says_so(
    sh_world, synthetic_truth, monkeypatch
):
    _, _, arcs = sh_world
    rng = np.random.default_rng(1)
    noisy = replace(arcs, states=arcs.states + rng.normal(size=arcs.states.shape) * 1e-6)
    est = GravityEstimator(
        "sh", degree=4, solver=LevenbergMarquardt(rtol=1e-9), body=synthetic_truth.body
    )
    run = ContinualFit(est, noisy)
    run.add(np.arange(0, 5))
    fit = est.fit
    starts = []

    def fit_unless_warm(subset, *, init=None, **kw):
        starts.append(init)
        if init is not None:  # as when the new arcs dive where the old field is singular
            raise PropagationError("arcs [6] did not propagate to the end")
        return fit(subset, init=init, **kw)

    monkeypatch.setattr(est, "fit", fit_unless_warm)
    second = run.add(np.arange(5, 9))
    assert starts[0] is not None and starts[1] is None  # tried warm, then from scratch
    assert not second.warm_started and second.n_arcs == 9
    assert second.result.outcome.ok and 0 < second.relative_cost < 1e-3
    # the restarted fit's own diagnostics, not the failed warm attempt's or stage 1's
    assert second.relative_cost == est.diagnostics_["relative_cost"]
    assert second.relative_cost != run.records[0].relative_cost
    assert not est.fitted_.stages[1]["warm_started"]


def _two_member_network(truth, *, hidden: int, max_iter: int) -> GravityEstimator:
    """A two-member network ensemble (one hidden layer) holding out a quarter of each stage."""
    return GravityEstimator(
        "network",
        hidden=(hidden,),
        members=2,
        validation_fraction=0.25,
        solver=LevenbergMarquardt(max_iter=max_iter),
        body=truth.body,
    )


def test_a_warm_stage_forms_normal_equations_of_the_new_arcs_only(small_arcs, synthetic_truth):
    """A warm-started stage adds the new training arcs to the previous stage's normal
    equations at its returned parameters, for each member of an ensemble; the sums it starts
    from equal those formed from scratch."""
    stages = [np.arange(0, 5), np.arange(5, 9)]
    est = _two_member_network(synthetic_truth, hidden=8, max_iter=3)
    run = ContinualFit(est, small_arcs)
    first = run.add(stages[0])
    starts = []
    arc_normals, normal_equations = ArcProblem.arc_normals, ArcProblem.normal_equations
    formed = []

    def spy(problem, theta, arc_indices=None, *, known=None, **kw):
        formed.clear()
        normals = arc_normals(problem, theta, arc_indices, known=known, **kw)
        if known is not None:
            starts.append((problem, known, normals, sorted(np.concatenate(formed))))
        return normals

    def spy_formed(problem, theta, arc_indices=None, *args, **kw):
        formed.append(np.asarray(arc_indices))
        return normal_equations(problem, theta, arc_indices, *args, **kw)

    ArcProblem.arc_normals, ArcProblem.normal_equations = spy, spy_formed
    try:
        second = run.add(stages[1])
    finally:
        ArcProblem.arc_normals, ArcProblem.normal_equations = arc_normals, normal_equations
    assert second.warm_started and len(starts) == 2
    # only the newest stage keeps its sums
    assert run.records[0].result.normals is None
    assert all(m.normals is None for m in run.records[0].result.members)
    assert all(m.normals is not None for m in run.records[1].result.members)
    train = np.flatnonzero(~np.isin(second.arcs, second.validation))
    for k, (problem, known, normals, propagated) in enumerate(starts):
        assert known is first.result.members[k].normals
        # only the new training arcs were propagated for the first normal equations
        assert propagated == sorted(set(train) - set(known.arcs))
        assert len(propagated) and set(propagated) <= set(range(5, 9))
        assert np.array_equal(known.params, normals.params)
        assert set(known.arcs) < set(train) and np.array_equal(normals.arcs, train)
        fresh = problem.normal_equations(normals.params, train, regularised=False)
        assert normals.cost == pytest.approx(fresh[0], rel=1e-12)
        assert np.allclose(normals.ata, fresh[2], rtol=1e-10, atol=1e-30)


def test_adam_lowers_validation_loss(small_arcs):
    nn = NeuralPotential((16,))
    problem = ArcProblem(Model((PointMass(),), nn), small_arcs)
    train, val = split_validation(small_arcs.n_arcs, 0.2, 0)
    result = Adam(steps=30, batch_size=4, eval_every=5, learning_rate=1e-2).solve(
        problem, nn.initial_params(0), train=train, validation=val
    )
    start = problem.cost(nn.initial_params(0), val)
    assert problem.cost(result.params, val) < start
    assert result.best_iteration > 0


def test_adam_is_seeded(small_arcs):
    nn = NeuralPotential((8,))
    problem = ArcProblem(Model((PointMass(),), nn), small_arcs)
    a = Adam(steps=6, batch_size=3, seed=4).solve(problem, nn.initial_params(0))
    b = Adam(steps=6, batch_size=3, seed=4).solve(problem, nn.initial_params(0))
    assert np.array_equal(a.params, b.params)


def test_cosine_schedule():
    adam = Adam(learning_rate=1e-2, final_learning_rate_ratio=0.1, steps=100)
    assert adam.learning_rate_at(0) == pytest.approx(1e-2)
    assert adam.learning_rate_at(50) == pytest.approx(0.55e-2)
    assert adam.learning_rate_at(100) == pytest.approx(1e-3)


def test_adam_resumes_exactly(small_arcs):
    nn = NeuralPotential((8,))
    problem = ArcProblem(Model((PointMass(),), nn), small_arcs)
    train, val = split_validation(small_arcs.n_arcs, 0.2, 1)
    adam = Adam(steps=8, batch_size=3, eval_every=2, seed=2)
    full = adam.solve(problem, nn.initial_params(0), train=train, validation=val)
    saved = {}

    def keep(theta, state):
        if state["step"] == 4:
            saved.update(theta=theta.copy(), state=state)

    replace(adam, checkpoint_every=2).solve(
        problem, nn.initial_params(0), train=train, validation=val, checkpoint=keep
    )
    resumed = adam.solve(
        problem, saved["theta"], train=train, validation=val, resume=saved["state"]
    )
    assert np.array_equal(resumed.params, full.params)
    assert resumed.history["validation"] == full.history["validation"]


def test_kaula_scan_on_a_dask_client_equals_builtin_map(sh_world):
    from dask.distributed import Client

    model, c_true, arcs = sh_world
    problem = ArcProblem(model, arcs)

    def metric(c):
        return float(np.linalg.norm(c - c_true))

    alphas = (1e-8, 1e-4)
    serial = scan_kaula(problem, metric, alphas=alphas)
    with Client(processes=False, n_workers=2, threads_per_worker=1, dashboard_address=":0") as c:
        mapped = scan_kaula(
            problem, metric, alphas=alphas, mapper=lambda f, xs: c.gather(c.map(f, list(xs)))
        )
    assert mapped[0] == serial[0] and mapped[2] == serial[2]
    assert np.array_equal(mapped[1].params, serial[1].params)


def _spied_continual_fit(small_arcs, truth, stages, max_iter):
    """SH 2 fitted continually over ``stages`` (25 % held out per stage); returns the stage
    records and, per stage, the (arcs, train, validation) its LM solver was given."""
    trained = []

    class Spy(LevenbergMarquardt):
        def _iterate(self, problem, theta, train, validation, *rest):
            trained.append((problem.arcs, train, validation))
            return super()._iterate(problem, theta, train, validation, *rest)

    est = GravityEstimator(
        "sh",
        degree=2,
        validation_fraction=0.25,
        select_on_validation=True,  # the solver is given the validation arcs, to check them
        solver=Spy(max_iter=max_iter),
        body=truth.body,
    )
    return fit_continual(est, small_arcs, stages), trained


def test_continual_stages_never_train_on_validation_arcs(small_arcs, synthetic_truth):
    """Arcs held out at a stage stay held out at every later stage, and the warm-started
    fit's training arcs never include them."""
    stages = [np.arange(0, 5), np.arange(5, 9)]
    records, trained = _spied_continual_fit(small_arcs, synthetic_truth, stages, 3)
    assert records[1].warm_started
    assert set(records[0].validation) <= set(records[1].validation)
    assert len(records[0].validation) == 1 and len(records[1].validation) == 2
    for record, (arcs, train, validation) in zip(records, trained, strict=True):
        assert np.array_equal(record.arcs[validation], record.validation)
        assert not set(record.arcs[train]) & set(record.validation)
        assert np.array_equal(arcs.times, small_arcs.times[record.arcs])


def test_a_stage_weighs_its_arcs_as_given(small_arcs, synthetic_truth):
    """``add(new, arc_weights=w)`` (one weight per arc of the run) fits the stage's arcs at
    their weights: the stage's cost is the weighted cost of its arcs; a weight per arc of
    the stage alone is refused."""
    est = GravityEstimator("sh", degree=2, validation_fraction=0.0, body=synthetic_truth.body)
    run = ContinualFit(est, small_arcs)
    run.add(np.arange(0, 5))
    weights = np.where(np.arange(small_arcs.n_arcs) >= 5, 0.1, 1.0)
    with pytest.raises(InputError, match="one weight per arc of the run"):
        run.add(np.arange(5, 9), arc_weights=weights[5:])
    with pytest.raises(InputError, match="finite and >= 0"):
        run.add(np.arange(5, 9), arc_weights=np.where(weights < 1, np.nan, 1.0))
    record = run.add(np.arange(5, 9), arc_weights=weights)
    assert np.array_equal(record.arcs, np.arange(9))  # the refused calls changed nothing
    problem = ArcProblem(est.model_, small_arcs, arc_weights=weights)
    assert record.result.cost == pytest.approx(problem.cost(record.result.params), rel=1e-12)
    assert est.fitted_.solver["arc_weights"]["n_not_one"] == 4


def _record_fits(est: GravityEstimator) -> list:
    """A list that receives (arcs, keyword arguments) of each later ``est.fit`` call, which
    still fits."""
    fitted = []
    fit = est.fit

    def spy(arcs, **kw):
        fitted.append((arcs, kw))
        return fit(arcs, **kw)

    est.fit = spy
    return fitted


def test_a_stage_without_validation_trains_every_new_arc_but_no_earlier_hold_out(
    small_arcs, synthetic_truth
):
    """``add(new, validate=False)``: none of the new arcs is held out, the arcs held out at
    earlier stages are not trained on, the fit has no validation arcs (its last iterate is
    returned) and the given solver runs."""
    est = _two_member_network(synthetic_truth, hidden=4, max_iter=2)
    run = ContinualFit(est, small_arcs)
    first = run.add(np.arange(0, 5))
    assert len(first.validation) == 1
    fitted = _record_fits(est)
    solver = LevenbergMarquardt(max_iter=3, rtol=0.0)
    second = run.add(np.arange(5, 9), validate=False, solver=solver)
    ((arcs, kw),) = fitted
    assert np.array_equal(second.validation, first.validation)
    assert second.warm_started and second.n_arcs == 9
    trained = np.setdiff1d(np.arange(9), first.validation)
    np.testing.assert_array_equal(arcs.times, small_arcs.times[trained])
    assert kw["validation"].size == 0 and kw["solver"] is solver
    assert second.result.solver["max_iter"] == 3
    assert "validation" not in second.result.members[0].history


def test_a_stage_can_be_chosen_by_the_new_arcs_it_holds_out(small_arcs, synthetic_truth):
    """``add(new, validation_arcs=v)``: the arcs ``v`` (among ``new``) are held out and are
    the fit's only validation set; the earlier hold-outs are neither trained on nor vote; each
    member returns the iterate, its start included, with the lowest cost on ``v``."""
    est = _two_member_network(synthetic_truth, hidden=4, max_iter=2)
    run = ContinualFit(est, small_arcs)
    first = run.add(np.arange(0, 5))
    assert len(first.validation) == 1
    fitted = _record_fits(est)
    solver = LevenbergMarquardt(max_iter=4, rtol=0.0)
    voting = np.array([6, 8])
    second = run.add(np.arange(5, 9), validation_arcs=voting, solver=solver)
    ((arcs, kw),) = fitted
    np.testing.assert_array_equal(second.validation, np.union1d(first.validation, voting))
    kept = np.setdiff1d(np.arange(9), first.validation)
    np.testing.assert_array_equal(arcs.times, small_arcs.times[kept])
    np.testing.assert_array_equal(kept[kw["validation"]], voting)
    assert second.checked_on == "validation arcs"
    for member in second.result.members:
        history = member.history["validation"]
        assert len(history) == 5 and member.best_iteration == int(np.argmin(history))
    # the arcs held out must be among the stage's new ones, with validation on
    for bad, validate in (([3], True), ([], True), ([6], False)):
        with pytest.raises(InputError, match="validation_arcs must be a nonempty subset"):
            run.fork().add(np.arange(5, 9), validation_arcs=bad, validate=validate)


def test_a_forked_run_continues_on_its_own(small_arcs, synthetic_truth):
    """``fork()``: a stage added to the fork gives what the same stage added to the run
    gives (same parameters to rounding, same arcs and hold-outs), and neither changes the
    other's stages: the same refit with and without new arcs from one starting point."""
    est = _two_member_network(synthetic_truth, hidden=4, max_iter=2)
    run = ContinualFit(est, small_arcs)
    first = run.add(np.arange(0, 5))
    twin, bare = run.fork(), run.fork()
    assert twin.estimator is not est and twin.records == run.records
    solver = LevenbergMarquardt(max_iter=2, rtol=0.0)
    on_twin = twin.add(np.arange(5, 9), validate=False, solver=solver)
    assert len(run.records) == 1 and np.array_equal(run.params, first.result.params)
    alone = bare.add(np.zeros(0, dtype=int), validate=False, solver=solver)
    on_run = run.add(np.arange(5, 9), validate=False, solver=solver)
    np.testing.assert_allclose(on_twin.result.params, on_run.result.params, rtol=1e-10, atol=0)
    np.testing.assert_array_equal(on_twin.arcs, on_run.arcs)
    np.testing.assert_array_equal(on_twin.validation, on_run.validation)
    # no new arcs: the first stage's arcs, trained on again from its parameters
    assert np.array_equal(alone.arcs, first.arcs) and len(twin.records) == 2
    assert alone.warm_started and alone.result.initial_cost == pytest.approx(
        first.result.params_cost, rel=1e-12
    )


class _OneParameterProblem:
    """Training cost (theta - 1)^2 / 2 in one parameter; the validation cost is the given
    function of theta (arc index 1 is the validation arc, 0 the training arc)."""

    n_params = 1
    model = Model((PointMass(),), None)

    def __init__(self, validation_cost):
        self.validation_cost = validation_cost
        self.normals_at = []  # the iterates whose normal equations were formed

    def objective(self, theta, idx=None):
        return 0.5 * float(theta[0] - 1.0) ** 2

    def cost(self, theta, idx=None):
        if idx is not None and list(idx) == [1]:
            return float(self.validation_cost(float(theta[0])))
        return self.objective(theta)

    def arc_normals(self, theta, idx=None, known=None):
        self.normals_at.append(float(theta[0]))
        r = float(theta[0] - 1.0)
        return ArcNormals(
            theta.copy(), np.array([0]), "", 0.5 * r * r, np.array([r]), np.array([[1.0]])
        )

    def regularise(self, theta, cost, atr, ata):
        return cost, atr, ata

    def prior_diagonal(self):
        return np.zeros(1)


def _patient_fit(validation_cost, patience, problem=None):
    # large initial damping: short steps from 0 towards 1 (theta about 0.09, 0.30, 0.63, ...)
    solver = LevenbergMarquardt(lambda0=10.0, max_iter=8, rtol=0.0, patience=patience)
    problem = problem or _OneParameterProblem(validation_cost)
    return solver.solve(problem, np.zeros(1), train=np.array([0]), validation=np.array([1]))


def test_patience_counts_accepted_steps_without_a_validation_gain_from_the_start():
    # the validation cost rises over the first two accepted steps, then falls below its start
    def rises_then_falls(t):
        return 1.0 + t - 2.0 * t * t

    stopped = _patient_fit(rises_then_falls, 2)
    assert stopped.iterations == 2
    assert stopped.outcome.value == "no improvement"
    np.testing.assert_array_equal(stopped.params, [0.0])
    waited = _patient_fit(rises_then_falls, 3)
    assert waited.iterations == 8
    assert waited.best_iteration > 2
    assert waited.params[0] > 0.6


def test_patience_stops_after_that_many_steps_without_a_gain():
    # the first step lowers the validation cost, the next ones raise it
    problem = _OneParameterProblem(lambda t: (t - 0.1) ** 2)
    result = _patient_fit(None, 2, problem)
    assert result.iterations == 3
    assert result.best_iteration == 1
    assert "validation cost not lowered by 2 accepted steps" in result.message
    np.testing.assert_allclose(result.params, [1 / 11])
    # the cost of the returned (best-validation) iterate, not of the last one
    assert result.params_cost == pytest.approx(0.5 * (1 / 11 - 1) ** 2, rel=1e-12)
    assert result.cost < result.params_cost
    assert result.summary()["params_cost"] == result.params_cost


def test_a_fit_stopping_at_an_iterate_it_does_not_return_forms_no_normals_there():
    problem = _OneParameterProblem(lambda t: (t - 0.1) ** 2)
    result = _patient_fit(None, 2, problem)
    # the start, the best (first) step and the second, which the third step needs; the third
    # ends the fit without a gain and is not returned
    np.testing.assert_allclose(problem.normals_at, [0.0, 1 / 11, *problem.normals_at[2:]])
    assert len(problem.normals_at) == 3
    assert result.normals.params[0] == result.params[0]
    # at the iteration cap the last iterate's are formed only when it is the one returned
    capped = _OneParameterProblem(lambda t: (t - 0.9) ** 2)
    solver = LevenbergMarquardt(lambda0=10.0, max_iter=3, rtol=0.0)
    result = solver.solve(capped, np.zeros(1), train=np.array([0]), validation=np.array([1]))
    assert result.best_iteration == 3
    assert len(capped.normals_at) == 4 and capped.normals_at[-1] == result.params[0]


def test_a_gated_fit_takes_only_steps_that_lower_the_validation_cost():
    # validation cost lowest at 0.12: the second full step (to about 0.30) overshoots it
    def valley(t):
        return (t - 0.12) ** 2

    plain = _patient_fit(valley, 2)
    np.testing.assert_allclose(plain.params, [1 / 11])  # the first step is the best it finds
    problem = _OneParameterProblem(valley)
    solver = LevenbergMarquardt(
        lambda0=10.0, max_iter=8, rtol=0.0, patience=2, validation_gate=True
    )
    gated = solver.solve(problem, np.zeros(1), train=np.array([0]), validation=np.array([1]))
    # from 1/11 at lambda 10/3 the step to about 0.30 is rejected; at lambda 100/3 the
    # shorter one lands at 1/11 + (10/11) / (1 + 100/3) = 0.1174, nearer the valley, and
    # the later ones nearer still
    assert gated.history["accepted"][1:4] == [True, False, True]
    second = 1 / 11 + (10 / 11) / (1 + 100 / 3)
    assert abs(gated.params[0] - 0.12) < abs(second - 0.12)
    # every iterate is the best so far, and normals are formed at those only
    np.testing.assert_allclose(problem.normals_at[:3], [0.0, 1 / 11, second])
    assert problem.normals_at == sorted(problem.normals_at)
    assert gated.best_iteration == max(i for i, a in enumerate(gated.history["accepted"]) if a)


def test_gated_trials_do_not_use_up_the_patience():
    # validation cost lowest at 0.095, just past the first step (1/11): from there the
    # trials at lambda 10/3 (to 0.30) and 100/3 (to 0.117) overshoot it and are gated; the
    # one at 1000/3 lands at 0.0936, nearer. Counted as stale steps, the two gated trials
    # would end a fit of patience 2 at 1/11.
    def valley(t):
        return (t - 0.095) ** 2

    solver = LevenbergMarquardt(
        lambda0=10.0, max_iter=8, rtol=0.0, patience=2, validation_gate=True
    )
    gated = solver.solve(
        _OneParameterProblem(valley), np.zeros(1), train=np.array([0]), validation=np.array([1])
    )
    assert gated.history["accepted"][1:5] == [True, False, False, True]
    assert gated.iterations == 8
    third = 1 / 11 + (10 / 11) / (1 + 1000 / 3)
    assert abs(gated.params[0] - 0.095) <= abs(third - 0.095) < abs(1 / 11 - 0.095)


def test_a_gated_fit_takes_steps_on_the_training_cost_until_its_first_validation_gain():
    # the validation cost rises over the first two steps, then falls: gating those steps
    # would leave the fit at its start
    def rises_then_falls(t):
        return 1.0 + t - 2.0 * t * t

    solver = LevenbergMarquardt(
        lambda0=10.0, max_iter=8, rtol=0.0, patience=3, validation_gate=True
    )
    problem = _OneParameterProblem(rises_then_falls)
    result = solver.solve(problem, np.zeros(1), train=np.array([0]), validation=np.array([1]))
    assert result.history["accepted"][1:3] == [True, True]
    assert result.best_iteration > 2 and result.params[0] > 0.6


def test_after_compile_a_fit_compiles_nothing(small_arcs, synthetic_truth):
    # an ensemble with the harmonic penalty: ensemble, member and sensitivity integrators and
    # the Laplacian function (a hidden size no other test uses: nothing is cached yet)
    est = GravityEstimator(
        "network",
        hidden=(3, 2),
        members=2,
        harmonic=1e-5,
        validation_fraction=0.25,
        solver=LevenbergMarquardt(max_iter=2),
        body=synthetic_truth.body,
    )
    before = cache_info()
    est.compile(small_arcs)
    compiled = cache_info()
    assert sum(compiled.values()) > sum(before.values())
    est.fit(small_arcs)
    assert cache_info() == compiled


def test_lm_step_solve_falls_back_to_least_squares_on_a_singular_matrix():
    """The damped normal matrix is solved by Cholesky; one that is not positive definite (a
    direction no arc sees, undamped) gets the minimum-norm least-squares step instead."""
    rng = np.random.default_rng(3)
    a = rng.normal(size=(40, 6))
    spd = a.T @ a
    rhs = rng.normal(size=6)
    assert np.allclose(_solve_spd(spd, rhs), np.linalg.solve(spd, rhs), rtol=1e-10)
    singular = np.diag([2.0, 0.0, 1.0])
    assert np.allclose(_solve_spd(singular, np.array([4.0, 0.0, 3.0])), [2.0, 0.0, 3.0])


class _LinearProblem(_OneParameterProblem):
    """Training cost |A theta - b|^2 / 2 (arc 0); the validation cost (arc 1) is the given
    function of theta."""

    def __init__(self, a, b, validation_cost=None):
        super().__init__(validation_cost)
        self.a, self.b = np.asarray(a, float), np.asarray(b, float)
        self.n_params = self.a.shape[1]

    def objective(self, theta, idx=None):
        r = self.a @ theta - self.b
        return 0.5 * float(r @ r)

    def arc_normals(self, theta, idx=None, known=None):
        self.normals_at.append(theta.copy())
        r = self.a @ theta - self.b
        return ArcNormals(
            theta.copy(), np.array([0]), "", 0.5 * float(r @ r), self.a.T @ r, self.a.T @ self.a
        )


def test_lm_damping_scales_by_the_normal_diagonal_and_its_floor():
    """Marquardt's damping lambda diag(A^T A): every parameter's first step is the same
    fraction 1 / (1 + lambda) of its Gauss-Newton step, however well the arcs see it. With a
    damping floor, the barely seen parameter (diag 1e-8, below 1e-2 of the largest) is
    damped at the floor instead: its step is a tiny fraction of its Gauss-Newton step."""
    a = np.diag([1.0, 1e-4])
    problem = _LinearProblem(a, a @ [1.0, 1.0])  # minimum at (1, 1), diag(A^T A) = (1, 1e-8)
    solver = LevenbergMarquardt(lambda0=1.0, max_iter=1, rtol=0.0)
    plain = solver.solve(problem, np.zeros(2))
    np.testing.assert_allclose(plain.params, [0.5, 0.5], rtol=1e-12)
    floored = replace(solver, damping_floor=1e-2).solve(problem, np.zeros(2))
    # (1e-8 + lambda max(1e-8, 1e-2 * 1)) dc = 1e-8
    np.testing.assert_allclose(floored.params, [0.5, 1e-8 / (1e-8 + 1e-2)], rtol=1e-12)


def test_lm_rejects_a_step_that_does_not_lower_the_cost():
    # started at the minimum: every step is zero and leaves the cost as it is
    result = LevenbergMarquardt(max_iter=3).solve(_OneParameterProblem(None), np.ones(1))
    assert result.history["accepted"][1:] == [False, False, False]
    assert result.outcome.value == "no improvement"
    np.testing.assert_array_equal(result.params, [1.0])


def test_lm_damping_is_floored_at_lambda_floor():
    # accepted steps divide lambda by 10 down to the floor 1e-3; on (theta - 1)^2 / 2 a step
    # at lambda leaves lambda / (1 + lambda) of the error
    solver = LevenbergMarquardt(
        lambda0=0.1, lambda_down=10.0, lambda_floor=1e-3, max_iter=4, rtol=0.0
    )
    result = solver.solve(_OneParameterProblem(None), np.zeros(1))
    assert all(result.history["accepted"])
    np.testing.assert_allclose(result.history["lambda"], [0.1, 1e-2, 1e-3, 1e-3, 1e-3])
    error = np.prod([lam / (1 + lam) for lam in (0.1, 1e-2, 1e-3, 1e-3)])
    np.testing.assert_allclose(1.0 - result.params, [error], rtol=1e-5)


def test_lm_stops_when_the_damping_passes_its_ceiling():
    # started at the minimum, every trial is rejected and lambda grows 10x per iteration:
    # 1 -> 10 -> 100 -> 1000, past the ceiling of 100 after the third
    solver = LevenbergMarquardt(lambda0=1.0, lambda_ceiling=1e2, max_iter=10)
    result = solver.solve(_OneParameterProblem(None), np.ones(1))
    assert result.iterations == 3 and not any(result.history["accepted"][1:])
    assert result.outcome is Outcome.NO_IMPROVEMENT and "damping saturated" in result.message


def test_lm_a_cost_change_just_above_rtol_does_not_stop_the_fit():
    # lambda 1e6: the first step lowers the cost by a relative 2e-6, above rtol = 1e-6
    solver = LevenbergMarquardt(lambda0=1e6, rtol=1e-6, max_iter=3)
    result = solver.solve(_OneParameterProblem(None), np.zeros(1))
    rel = 1.0 - result.history["cost"][1] / result.history["cost"][0]
    assert 1e-6 < rel < 1e-5
    assert result.iterations == 3 and result.outcome is Outcome.ITERATION_CAP


def test_a_validation_cost_that_does_not_change_is_no_gain():
    # validation arcs the parameter does not affect: no iterate beats the start
    result = _patient_fit(lambda t: 0.25, 2)
    assert result.iterations == 2
    assert result.best_iteration == 0 and result.outcome.value == "no improvement"
    np.testing.assert_array_equal(result.params, [0.0])


def test_a_validation_gain_restarts_the_patience():
    # iterates about 0.09, 0.30, 0.63, 0.90, 0.99, ...: the validation cost rises at the first
    # and third, falls at the second and from the fourth on. With patience 2 no two accepted
    # steps in a row go without a gain, so the fit runs to its iteration cap
    def rises_falls_rises_falls(t):
        if t < 0.05:
            return 1.0
        if t < 0.2:
            return 2.0
        if t < 0.5:
            return 0.5
        if t < 0.8:
            return 1.5
        return 0.2 - 0.1 * t

    result = _patient_fit(rises_falls_rises_falls, 2)
    assert all(result.history["accepted"])
    assert result.iterations == 8 and result.best_iteration == 8
    assert result.params[0] > 0.99


def test_lm_resumes_exactly_from_a_checkpoint():
    solver = LevenbergMarquardt(lambda0=10.0, max_iter=4, rtol=0.0)
    saved = {}

    def keep(theta, state):
        if state["iteration"] == 2:
            saved.update(theta=theta.copy(), state=state)

    full = solver.solve(_OneParameterProblem(None), np.zeros(1), checkpoint=keep)
    assert saved["state"]["lambda"] != solver.lambda0
    resumed = solver.solve(_OneParameterProblem(None), saved["theta"], resume=saved["state"])
    for key in ("cost", "lambda", "accepted"):
        assert resumed.history[key] == full.history[key]
    assert resumed.iterations == full.iterations
    np.testing.assert_array_equal(resumed.params, full.params)
    # a checkpoint of an older hamgrav holds the damping alone: the count starts afresh
    older = {k: saved["state"][k] for k in ("solver", "iteration", "lambda")}
    resumed = replace(solver, max_iter=2).solve(
        _OneParameterProblem(None), saved["theta"], resume=older
    )
    assert resumed.history["lambda"] == full.history["lambda"][2:]
    np.testing.assert_array_equal(resumed.params, full.params)


@pytest.mark.parametrize("gate", [False, True])
def test_lm_with_validation_resumes_from_any_checkpoint_as_if_never_stopped(gate):
    """The whole state is in the checkpoint (iteration count, best validation iterate, stale
    count, history): resumed from any of them, the fit ends where the uninterrupted one
    ends (a checkpoint of the damping alone started the count afresh and forgot the best
    iterate, which a killed fit's kill test found)."""

    def rises_falls_rises_falls(t):
        return 1.0 if t < 0.05 else 2.0 if t < 0.2 else 0.5 if t < 0.5 else 1.5 if t < 0.8 else 0.1

    solver = LevenbergMarquardt(lambda0=10.0, max_iter=8, rtol=0.0, patience=3,
                                validation_gate=gate)  # fmt: skip
    split = {"train": np.array([0]), "validation": np.array([1])}
    saved = []
    full = solver.solve(
        _OneParameterProblem(rises_falls_rises_falls), np.zeros(1), **split,
        checkpoint=lambda theta, state: saved.append((theta.copy(), state)),
    )  # fmt: skip
    assert len(saved) >= 2
    for theta, state in saved:
        resumed = solver.solve(
            _OneParameterProblem(rises_falls_rises_falls), theta, **split, resume=state
        )
        np.testing.assert_array_equal(resumed.params, full.params)
        assert (resumed.iterations, resumed.best_iteration) == (
            full.iterations,
            full.best_iteration,
        )
        assert resumed.history["validation"] == full.history["validation"]
        assert resumed.outcome == full.outcome


def test_a_fit_capped_or_converged_forms_no_normals_at_a_last_iterate_it_does_not_return():
    # validation cost lowest at 0.1: the first step (1/11) is the best, the second (about 0.30)
    # and the third (about 0.63, at the cap) are not; the third step needs the second's normals
    problem = _OneParameterProblem(lambda t: (t - 0.1) ** 2)
    solver = LevenbergMarquardt(lambda0=10.0, max_iter=3, rtol=0.0)
    result = solver.solve(problem, np.zeros(1), train=np.array([0]), validation=np.array([1]))
    assert result.iterations == 3 and all(result.history["accepted"])
    assert result.best_iteration == 1
    np.testing.assert_allclose(result.params, [1 / 11])
    assert result.normals.params[0] == result.params[0]
    assert len(problem.normals_at) == 3 and max(problem.normals_at) < 0.5
    # at lambda 1e6 the first step lowers the cost by 2e-6 of it (below rtol: converged),
    # and it raises the validation cost: the start is returned, with the start's normals
    problem = _OneParameterProblem(lambda t: 1.0 + t)
    solver = LevenbergMarquardt(lambda0=1e6, max_iter=3, rtol=1e-5)
    result = solver.solve(problem, np.zeros(1), train=np.array([0]), validation=np.array([1]))
    assert result.iterations == 1 and result.history["accepted"] == [True, True]
    assert result.outcome.value == "no improvement"
    np.testing.assert_array_equal(result.params, [0.0])
    assert problem.normals_at == [0.0] and result.normals.params[0] == 0.0


def test_lm_with_a_kaula_weight_minimises_the_regularised_cost(sh_world):
    """From the unregularised minimum (the truth, noiseless arcs) the Kaula term pulls the
    coefficients in: the fit ends where the regularised gradient A^T r + alpha K c vanishes,
    with a smaller penalty c^T K c than the truth's (J + alpha c^T K c / 2 is lower there,
    and J is not below the truth's 0)."""
    model, c_true, arcs = sh_world
    problem = ArcProblem(model, arcs)
    alpha = 1.0
    k = alpha * kaula_diagonal(problem)

    def gradient(c):
        return problem.normal_equations(c)[1] + k * c

    regularised = problem.with_regulariser(KaulaPrior(model, alpha))
    np.testing.assert_array_equal(regularised.prior_diagonal(), k)
    assert regularised.objective(c_true) == pytest.approx(
        problem.cost(c_true) + 0.5 * c_true @ (k * c_true), rel=1e-14
    )
    result = LevenbergMarquardt(rtol=1e-12, max_iter=20).solve(regularised, c_true)
    assert result.outcome.value == "converged" and result.best_iteration > 0
    c = result.params
    assert np.linalg.norm(gradient(c)) < 1e-8 * np.linalg.norm(gradient(c_true))
    assert c @ (k * c) < c_true @ (k * c_true)


def test_continual_validation_arcs_are_the_held_out_ones_whatever_order_arcs_arrive_in(
    small_arcs, synthetic_truth
):
    """Stages need not bring the arcs in index order (a campaign picks its next arcs): the
    fit's validation arcs are those held out, and it never trains on them."""
    stages = [np.array([6, 2, 8, 0]), np.array([1, 7, 3, 5, 4])]
    records, trained = _spied_continual_fit(small_arcs, synthetic_truth, stages, 2)
    assert len(records[0].validation) == 1 and len(records[1].validation) == 2
    for record, (arcs, train, validation) in zip(records, trained, strict=True):
        np.testing.assert_array_equal(arcs.times, small_arcs.times[record.arcs])
        assert sorted(record.arcs[validation]) == sorted(record.validation)
        assert not set(record.arcs[train]) & set(record.validation)
        assert len(train) + len(validation) == record.n_arcs


def test_a_restarted_stage_keeps_the_held_out_arcs(small_arcs, synthetic_truth, monkeypatch):
    """A stage whose warm start does not propagate is fitted again from scratch on the same
    split: the arcs held out so far are its validation arcs, not trained on."""
    est = GravityEstimator("sh", degree=2, validation_fraction=0.25, body=synthetic_truth.body)
    run = ContinualFit(est, small_arcs)
    run.add(np.arange(0, 5))
    fit = est.fit

    def fit_unless_warm(subset, *, init=None, **kw):
        if init is not None:
            raise PropagationError("arcs [6] did not propagate to the end")
        return fit(subset, init=init, **kw)

    monkeypatch.setattr(est, "fit", fit_unless_warm)
    second = run.add(np.arange(5, 9))
    assert not second.warm_started and len(second.validation) == 2
    assert sorted(second.arcs[est.validation_]) == sorted(second.validation)
    assert not set(second.arcs[est.train_]) & set(second.validation)


def test_every_warm_stage_adds_to_the_previous_stages_normal_equations(
    small_arcs, synthetic_truth, monkeypatch
):
    """Three stages of a single SH fit: each warm stage's first normal equations are the
    previous stage's (at its returned parameters) plus the new arcs'; only the new arcs are
    propagated for them."""
    stages = [np.arange(0, 3), np.arange(3, 6), np.arange(6, 9)]
    est = GravityEstimator(
        "sh",
        degree=2,
        validation_fraction=0.0,
        solver=LevenbergMarquardt(max_iter=3),
        body=synthetic_truth.body,
    )
    run = ContinualFit(est, small_arcs)
    arc_normals, normal_equations = ArcProblem.arc_normals, ArcProblem.normal_equations
    formed, starts = [], []

    def spy(problem, theta, arc_indices=None, *, known=None, **kw):
        formed.clear()
        normals = arc_normals(problem, theta, arc_indices, known=known, **kw)
        starts.append((known, sorted(np.concatenate(formed))))
        return normals

    def spy_formed(problem, theta, arc_indices=None, *args, **kw):
        formed.append(np.asarray(arc_indices))
        return normal_equations(problem, theta, arc_indices, *args, **kw)

    monkeypatch.setattr(ArcProblem, "arc_normals", spy)
    monkeypatch.setattr(ArcProblem, "normal_equations", spy_formed)
    for k, new in enumerate(stages):
        before = run.records[-1].result.normals if run.records else None
        starts.clear()
        record = run.add(new)
        known, propagated = starts[0]  # the stage's first normal equations
        if k == 0:
            assert known is None and propagated == [0, 1, 2]
        else:
            assert record.warm_started
            assert before is not None and known is before
            assert propagated == list(new)


def test_each_stage_holds_out_its_own_seeded_split_of_its_arriving_arcs(
    small_arcs, synthetic_truth
):
    """Stage k holds out ``validation_split(n_new, fraction, seed + k)`` of its new arcs (so
    stages of the same size do not all hold out the same positions); the arcs held out are
    all those held out so far."""
    stages = [np.array([0, 1, 2]), np.array([3, 4, 5]), np.array([6, 7, 8])]
    est = GravityEstimator(
        "sh",
        degree=2,
        validation_fraction=0.4,
        seed=3,
        solver=LevenbergMarquardt(max_iter=1),
        body=synthetic_truth.body,
    )
    records = fit_continual(est, small_arcs, stages)
    held_out = []
    for k, (new, record) in enumerate(zip(stages, records, strict=True)):
        _, val = split_validation(len(new), 0.4, 3 + k)
        held_out.extend(new[val])
        assert sorted(record.validation) == sorted(held_out)


def test_kaula_prior_applies_to_sh_only(small_arcs, synthetic_truth):
    from hamgrav.errors import InputError

    network = GravityEstimator("network", hidden=(4,), body=synthetic_truth.body)
    model, _ = network.build_model(small_arcs)
    with pytest.raises(InputError, match="Kaula's rule applies to spherical harmonics"):
        KaulaPrior(model, 1e-6)
    sh = GravityEstimator("sh", degree=2, kaula=1e-6, body=synthetic_truth.body)
    model, _ = sh.build_model(small_arcs)
    with pytest.raises(InputError, match="alpha must be >= 0"):
        KaulaPrior(model, -1.0)
    # the estimator adds the term's natural regulariser at its weight, and records it
    prior = sh.regulariser(model, small_arcs)
    assert isinstance(prior, KaulaPrior) and prior.alpha == 1e-6
    assert GravityEstimator("sh", degree=2, kaula=0.0).regulariser(model, small_arcs) is None
    # Adam's gradient leaves a prior out: it is neither added nor recorded there
    adam = GravityEstimator("sh", degree=2, kaula=1e-6, solver="adam")
    assert adam.regulariser(model, small_arcs) is None
    assert sh.fit(small_arcs).fitted_.solver["kaula_alpha"] == 1e-6
