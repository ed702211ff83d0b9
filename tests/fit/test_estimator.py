"""The estimator: the one fit path (noise weighting, shape prior, Kaula scan, known part)."""

import math
import warnings
from dataclasses import replace

import numpy as np
import pytest

from hamgrav.core.model import Model, evaluate_field
from hamgrav.core.problem import ArcProblem
from hamgrav.core.terms import MasconTerm, PointMass, SphericalHarmonics
from hamgrav.errors import HamgravWarning, InputError
from hamgrav.fit.base import Outcome, SolveResult
from hamgrav.fit.covariance import sample_covariance
from hamgrav.fit.estimator import (
    MIN_VALIDATION_ARCS,
    GravityEstimator,
    default_holdout,
    noise_sigmas,
    noise_whitening,
    validation_split,
)
from hamgrav.fit.lm import LevenbergMarquardt
from hamgrav.sim.tracking import observe


def test_noise_whitening_whitens_the_sample_covariance(small_arcs):
    """W S W^T = I for the (q, p) sample covariance, and W is the inverse of its Cholesky
    factor (lower triangular)."""
    sigmas = noise_sigmas(small_arcs)
    assert sigmas[0] > 0 and sigmas[3] > 0
    s = sample_covariance(sigmas[0], sigmas[3])
    w = noise_whitening(small_arcs)
    np.testing.assert_allclose(w @ s @ w.T, np.eye(6), rtol=0, atol=1e-12)
    # the reference inverse carries rounding of order eps |W| in the entries that are zero in
    # W (2e-13 against 8.5e3 was seen), so they are compared on the scale of W
    reference = np.linalg.inv(np.linalg.cholesky(s))
    np.testing.assert_allclose(w, reference, rtol=1e-12, atol=1e-15 * np.abs(w).max())
    # the momenta carry the position noise: omega sigma_r = 10 sigma_v at the default ratio
    assert np.sqrt(s[3, 3]) == pytest.approx(np.hypot(sigmas[0], sigmas[3]), rel=1e-12)


def test_whitened_noise_of_the_true_states_is_white(small_arcs):
    """Observations of the exact states drawn with the simulator's noise model: the whitened
    residuals against the true states have the identity as covariance. n = 50 draws x 9 arcs
    x 40 samples = 18000 per component: the sample variance's standard error is sqrt(2 / n)
    = 0.011, a covariance's 1 / sqrt(n) = 0.007; the tolerance is 5 x 0.011."""
    sigmas = noise_sigmas(small_arcs)
    true = np.broadcast_to(small_arcs.true_states, (50, *small_arcs.true_states.shape))
    noisy = observe(true, sigmas[0], sigmas[3], np.random.default_rng(11))
    r = (noisy - true).reshape(-1, 6)
    n = len(r)
    assert n == 18000
    white = r @ noise_whitening(small_arcs).T
    cov = white.T @ white / n  # the noise has mean zero
    # (dividing (q, p) by noise_sigmas instead gives p_x, p_y a variance of about 101 and a
    # covariance of about 10 with y, x)
    np.testing.assert_allclose(np.diag(cov), np.ones(6), rtol=0, atol=5 * np.sqrt(2 / n))
    np.testing.assert_allclose(cov, np.eye(6), rtol=0, atol=5 * np.sqrt(2 / n))


def test_whitening_needs_positive_noise(small_arcs):
    with pytest.raises(InputError, match=r"whitening by the noise \(--weighted\) needs the arcs'"):
        noise_whitening(replace(small_arcs, sigma_v_m_s=0.0))
    with pytest.raises(InputError, match="sigma_r nan m"):
        noise_whitening(replace(small_arcs, sigma_r_m=float("nan")))
    with pytest.raises(InputError, match="sigma_r inf m"):
        noise_whitening(replace(small_arcs, sigma_r_m=float("inf")))


def test_weighted_fit_whitens_the_residuals(small_arcs, synthetic_truth):
    weighted = GravityEstimator(
        "sh", degree=2, weighted=True, validation_fraction=0.0, body=synthetic_truth.body
    )
    weighted.fit(small_arcs)
    problem = ArcProblem(weighted.model_, small_arcs, whitening=noise_whitening(small_arcs))
    assert weighted.result_.initial_cost == pytest.approx(problem.cost(np.zeros(5)), rel=1e-12)
    assert weighted.result_.cost == pytest.approx(problem.cost(weighted.params_), rel=1e-12)
    whitened = problem.residuals(weighted.params_)
    raw = ArcProblem(weighted.model_, small_arcs).residuals(weighted.params_)
    np.testing.assert_allclose(whitened, raw @ noise_whitening(small_arcs).T, rtol=1e-12)
    assert weighted.fitted_.solver["weighted"] is True
    plain = GravityEstimator(
        "sh", degree=2, validation_fraction=0.0, body=synthetic_truth.body
    ).fit(small_arcs)
    assert plain.result_.initial_cost == pytest.approx(
        ArcProblem(plain.model_, small_arcs).cost(np.zeros(5)), rel=1e-12
    )
    assert plain.fitted_.solver["weighted"] is False


def test_a_fit_with_arc_weights_minimises_the_weighted_cost(small_arcs, synthetic_truth):
    """arc_weights reach the fit's problem: its costs are the weighted ones, the fit differs
    from the unweighted one, and the record holds the weights."""
    weights = np.where(np.arange(small_arcs.n_arcs) < 3, 0.05, 1.0)
    est = GravityEstimator("sh", degree=2, validation_fraction=0.0, body=synthetic_truth.body)
    est.fit(small_arcs, arc_weights=weights)
    problem = ArcProblem(est.model_, small_arcs, arc_weights=weights)
    assert est.result_.initial_cost == pytest.approx(problem.cost(np.zeros(5)), rel=1e-12)
    assert est.result_.cost == pytest.approx(problem.cost(est.params_), rel=1e-12)
    assert est.fitted_.solver["arc_weights"] == {
        "min": 0.05,
        "max": 1.0,
        "n_not_one": 3,
        "values": weights.tolist(),
    }
    plain = GravityEstimator(
        "sh", degree=2, validation_fraction=0.0, body=synthetic_truth.body
    ).fit(small_arcs)
    assert "arc_weights" not in plain.fitted_.solver
    assert np.abs(est.params_ - plain.params_).max() > 1e-3 * np.abs(plain.params_).max()
    # the weighted fit's cost is the lower of the two on the weighted problem
    assert problem.cost(est.params_) <= problem.cost(plain.params_)


@pytest.mark.parametrize(
    "weights, message",
    [
        (np.ones(3), "one weight per arc"),
        (-np.ones(9), "finite and >= 0: arc 0 has -1.0 \\(9 arcs in all\\)"),
        (np.r_[np.ones(4), np.nan, np.ones(4)], "finite and >= 0: arc 4 has nan$"),
        (np.zeros(9), "all zero"),
    ],
)
def test_bad_arc_weights_are_refused(small_arcs, synthetic_truth, weights, message):
    est = GravityEstimator("sh", degree=2, body=synthetic_truth.body)
    with pytest.raises(InputError, match=message):
        est.fit(small_arcs, arc_weights=weights)


def test_arc_weights_are_refused_with_hyperparameters_to_choose(small_arcs, synthetic_truth):
    est = GravityEstimator("sh", degree=2, kaula="cv", body=synthetic_truth.body)
    with pytest.raises(InputError, match="arc weights and hyperparameters to choose"):
        est.fit(small_arcs, arc_weights=np.ones(small_arcs.n_arcs))


def test_shape_prior_is_centred_on_its_own_centre_of_mass(small_arcs, synthetic_truth):
    est = GravityEstimator(
        "sh", degree=2, prior="shape", prior_mascons=30, body=synthetic_truth.body
    )
    model, info = est.build_model(small_arcs)
    (prior,) = model.known
    assert isinstance(prior, MasconTerm)
    assert np.linalg.norm(prior.mascons.centre_of_mass) < 1e-12
    assert prior.mascons.total_mass == pytest.approx(1.0, rel=1e-12)
    assert info["kind"] == "shape" and info["n_requested"] == 30
    # the head lobe is denser in this truth: the constant-density centre of mass is elsewhere,
    # so a prior left in the shape's frame would be off-centre by a measurable amount
    assert np.linalg.norm(synthetic_truth.body.constant_density_centre_of_mass) > 1e-3


def test_shape_prior_in_place_keeps_the_shape_and_takes_its_dipole_out(small_arcs, synthetic_truth):
    from hamgrav.core.fields import shell_points
    from hamgrav.core.model import evaluate_field
    from hamgrav.core.terms import PointDipole

    body = synthetic_truth.body
    centred, _ = GravityEstimator("none", prior="shape", prior_mascons=30, body=body).build_model(
        small_arcs
    )
    model, info = GravityEstimator(
        "none", prior="shape", prior_mascons=30, prior_placement="in-place", body=body
    ).build_model(small_arcs)
    prior, dipole = model.known
    offset = np.asarray(body.constant_density_centre_of_mass)
    # the mascons where the shape is (their centre of mass at the constant-density one) ...
    np.testing.assert_allclose(prior.mascons.centre_of_mass, offset, atol=1e-12)
    np.testing.assert_allclose(
        prior.mascons.positions - offset, centred.known[0].mascons.positions, atol=1e-12
    )
    # ... and the dipole that brings the known part's centre of mass back to the origin
    assert isinstance(dipole, PointDipole) and np.allclose(dipole.moment, -offset, rtol=1e-15)
    assert info["placement"] == "in-place"
    np.testing.assert_allclose(info["offset_m"], offset * body.units.length_m, rtol=1e-12)
    # far out the two known parts agree to second order in the offset (no dipole in either)
    far = shell_points(30.0, 200, seed=2)
    v_place, _ = evaluate_field(model, np.zeros(0), far, which="total")
    v_centre, _ = evaluate_field(centred, np.zeros(0), far, which="total")
    gap = np.abs(v_place - v_centre).max()
    assert gap < 5 * (offset @ offset) / 30.0**3
    # without the dipole they would differ at first order
    assert gap < 0.01 * np.abs(far @ offset).max() / 30.0**3
    with pytest.raises(InputError, match="prior_placement must be 'centred' or 'in-place'"):
        GravityEstimator("none", prior="shape", prior_placement="moved", body=body).build_model(
            small_arcs
        )


def test_known_part_alone(small_arcs, synthetic_truth):
    est = GravityEstimator("none", body=synthetic_truth.body).fit(small_arcs)
    assert est.params_.size == 0 and est.model_.learnable is None
    assert est.result_.outcome.value == "converged"
    assert est.result_.cost > 0


def test_kaula_scan_keeps_the_best_alpha(small_arcs, synthetic_truth):
    calls = []

    def metric(params, model):
        calls.append(float(np.linalg.norm(params)))
        return calls[-1]

    est = GravityEstimator(
        "sh", degree=3, kaula="truth-scan", kaula_metric=metric, body=synthetic_truth.body
    ).fit(small_arcs)
    scan = est.fitted_.solver["kaula_scan"]
    assert [a for a, _ in scan] == [1e-8, 1e-7, 1e-6, 1e-5, 1e-4]
    best = min(scan, key=lambda s: s[1])
    assert est.fitted_.solver["kaula_alpha"] == best[0]
    assert np.linalg.norm(est.params_) == pytest.approx(best[1])


def test_kaula_scan_without_the_truth_chooses_on_held_out_arcs(small_arcs, synthetic_truth):
    held_out = np.array([2, 6])
    est = GravityEstimator(
        "sh", degree=3, kaula="holdout-scan", validation_fraction=0.2, body=synthetic_truth.body
    )
    est.fit(small_arcs, validation=held_out)
    scan = est.fitted_.solver["kaula_scan"]
    best = min(scan, key=lambda s: s[1])
    assert est.fitted_.solver["kaula_alpha"] == best[0]
    # the score is the held-out cost, and the fits never saw those arcs
    problem = ArcProblem(est.model_, small_arcs)
    assert best[1] == pytest.approx(problem.cost(est.params_, held_out), rel=1e-12)
    train = np.setdiff1d(np.arange(small_arcs.n_arcs), held_out)
    alone = GravityEstimator(
        "sh", degree=3, kaula=best[0], validation_fraction=0.2, body=synthetic_truth.body
    ).fit(small_arcs, validation=held_out)
    assert np.allclose(alone.params_, est.params_, rtol=1e-10, atol=0)
    assert est.train_.tolist() == train.tolist()


def test_kaula_scan_needs_a_metric_or_held_out_arcs(small_arcs, synthetic_truth):
    est = GravityEstimator(
        "sh", degree=3, kaula="holdout-scan", validation_fraction=0.0, body=synthetic_truth.body
    )
    with pytest.raises(InputError, match="validation arcs"):
        est.fit(small_arcs)
    # the truth scan is named as such: the old name says where each option went
    with pytest.raises(InputError, match="'truth-scan' .* 'holdout-scan' .* 'cv'"):
        GravityEstimator("sh", degree=3, kaula="scan", body=synthetic_truth.body).fit(small_arcs)


def test_validation_split_is_decided_once(small_arcs, synthetic_truth):
    est = GravityEstimator("network", hidden=(4,), adam_steps=3, body=synthetic_truth.body)
    est.fit(small_arcs)
    # 12 % of 9 arcs rounds to 1: the default holds out its minimum of 2
    train, val = validation_split(small_arcs.n_arcs, default_holdout(small_arcs.n_arcs), 0)
    assert len(val) == MIN_VALIDATION_ARCS
    assert np.array_equal(est.validation_, val) and np.array_equal(est.train_, train)
    fixed = np.array([0, 5])
    est.fit(small_arcs, validation=fixed)
    assert np.array_equal(est.validation_, fixed)
    assert not set(est.train_) & set(fixed)


def test_warm_start_of_another_structure_is_refused(small_arcs, synthetic_truth):
    est = GravityEstimator("sh", degree=3, body=synthetic_truth.body)
    with pytest.raises(InputError, match="this model needs 12"):
        est.fit(small_arcs, init=np.zeros(5))


def test_solver_object_is_used_as_given(small_arcs, synthetic_truth):
    lm = LevenbergMarquardt(max_iter=3)
    est = GravityEstimator("sh", degree=2, solver=lm, body=synthetic_truth.body).fit(small_arcs)
    assert est.make_solver() is lm
    assert est.result_.solver["max_iter"] == 3
    r_b = synthetic_truth.body.brillouin_radius
    assert est.model_.key() == Model((PointMass(),), SphericalHarmonics(2, r_b)).key()


@pytest.mark.parametrize(
    "settings",
    [
        {"term": "sh", "degree": 2},
        {"term": "network", "hidden": (4,), "solver": LevenbergMarquardt(max_iter=5)},
    ],
)
def test_a_fit_with_nothing_to_learn_says_so(point_mass_arcs, synthetic_truth, settings):
    est = GravityEstimator(body=synthetic_truth.body, **settings).fit(point_mass_arcs)
    assert est.result_.outcome.value == "no improvement"
    assert not est.diagnostics_["improved"]
    assert est.diagnostics_["relative_cost"] > 0.9
    assert est.fitted_.solver["diagnostics"]["improved"] is False


def test_a_fit_that_learns_says_so(small_arcs, synthetic_truth):
    est = GravityEstimator("sh", degree=2, body=synthetic_truth.body).fit(small_arcs)
    diag = est.diagnostics_
    assert diag["improved"] and diag["relative_cost"] < 0.1
    assert diag["constrained_parameters"] == 5 == diag["n_params"]
    assert est.result_.outcome.value == "converged"


def test_the_checked_arc_costs_add_up_to_the_relative_cost(small_arcs, synthetic_truth):
    held_out = np.array([6, 1, 4])
    est = GravityEstimator("sh", degree=2, body=synthetic_truth.body)
    est.fit(small_arcs, validation=held_out)
    costs = est.checked_arc_costs_
    assert costs.fitted.shape == costs.none.shape == (3,)
    assert costs.fitted.sum() / costs.none.sum() == pytest.approx(
        est.diagnostics_["relative_cost"], rel=1e-12
    )
    assert "arc_costs" not in est.diagnostics_  # kept out of what is reported
    # each is the cost of that arc alone, at the fitted parameters
    problem = est._problem(est.model_, small_arcs)
    for k, arc in enumerate(est.validation_):
        assert costs.fitted[k] == pytest.approx(problem.cost(est.params_, [arc]), rel=1e-12)


def test_an_ensemble_is_the_mean_of_members_fitted_on_their_own(small_arcs, synthetic_truth):
    settings = {"term": "network", "hidden": (4,), "solver": LevenbergMarquardt(max_iter=3)}
    held_out = np.array([2, 6])
    one = [
        GravityEstimator(body=synthetic_truth.body, seed=s, **settings).fit(
            small_arcs, validation=held_out
        )
        for s in (7, 8)
    ]
    both = GravityEstimator(body=synthetic_truth.body, seed=7, members=2, **settings)
    both.fit(small_arcs, validation=held_out)
    members = both.fitted_.solver["members"]
    assert [m["init_seed"] for m in members] == [7, 8]
    # each member is exactly the single fit from its seed
    assert np.array_equal(both.params_, np.concatenate([e.params_ for e in one]))
    assert not np.array_equal(one[0].params_, one[1].params_)
    # and the ensemble's potential is their mean
    points = np.array([[1.5, 0.2, -0.3], [0.1, -2.0, 0.7]])
    mean = np.mean([e.field(points)[1] for e in one], axis=0)
    assert np.allclose(both.field(points)[1], mean, rtol=1e-12, atol=0)
    assert both.result_.iterations == sum(e.result_.iterations for e in one)
    # the ensemble's wall time spans its members' (the summaries round to 1 ms, so the
    # unrounded member results are compared)
    assert both.result_.wall_s >= sum(r.wall_s for r in both.result_.members)
    assert [m["wall_s"] for m in members] == [round(r.wall_s, 3) for r in both.result_.members]
    ranks = [e.diagnostics_["constrained_parameters"] for e in one]
    assert both.diagnostics_["constrained_parameters_per_member"] == ranks
    assert both.diagnostics_["n_params"] == 2 * one[0].diagnostics_["n_params"]


def test_an_ensemble_warm_starts_each_member_from_its_block(small_arcs, synthetic_truth):
    settings = {"term": "network", "hidden": (4,), "solver": LevenbergMarquardt(max_iter=2)}
    held_out = np.array([2, 6])
    first = GravityEstimator(body=synthetic_truth.body, seed=3, members=2, **settings)
    first.fit(small_arcs.subset(np.arange(6)), validation=held_out[:1])
    again = GravityEstimator(body=synthetic_truth.body, seed=3, members=2, **settings)
    again.fit(small_arcs, init=first.params_, validation=held_out)
    single = GravityEstimator(body=synthetic_truth.body, seed=3, **settings)
    half = first.params_.size // 2
    single.fit(small_arcs, init=first.params_[half:], validation=held_out)
    assert np.array_equal(again.params_[half:], single.params_)


def test_a_warm_member_that_keeps_its_block_does_not_speak_for_the_ensemble(
    small_arcs, synthetic_truth
):
    """On a warm start, one member that no step improves keeps its block; the ensemble,
    whose other member moved, reports that member's outcome, not "kept the starting model"."""
    settings = {"term": "network", "hidden": (4,), "members": 2}
    held_out = np.array([2, 6])
    first = GravityEstimator(
        body=synthetic_truth.body, seed=3, solver=LevenbergMarquardt(max_iter=1), **settings
    )
    first.fit(small_arcs.subset(np.arange(6)), validation=held_out[:1])
    stuck, free = LevenbergMarquardt(max_iter=2), LevenbergMarquardt(max_iter=6)
    calls = []

    class NoTrialLowersTheCost:
        # the first member's problem: every trial step raises the training cost (a heavily
        # damped real step can be accepted on a rounding-level decrease)
        def __init__(self, problem):
            self._problem = problem

        def __getattr__(self, name):
            return getattr(self._problem, name)

        def objective(self, theta, idx=None):
            return math.inf

    class FirstMemberStuck(LevenbergMarquardt):
        def _iterate(self, problem, *args):
            calls.append(1)
            if len(calls) == 1:
                return stuck._iterate(NoTrialLowersTheCost(problem), *args)
            return free._iterate(problem, *args)

    warm = GravityEstimator(
        body=synthetic_truth.body, seed=3, solver=FirstMemberStuck(), **settings
    )
    warm.fit(small_arcs, init=first.params_, validation=np.array([], dtype=int))
    half = first.params_.size // 2
    assert np.array_equal(warm.params_[:half], first.params_[:half])
    assert not np.array_equal(warm.params_[half:], first.params_[half:])
    members = warm.fitted_.solver["members"]
    assert [m["outcome"] for m in members] == ["converged", "iteration cap"]
    assert "member 0: kept its starting block" in warm.result_.message
    assert "kept the starting model" not in warm.result_.message


def test_an_ensemble_cannot_estimate_per_trajectory_parameters(small_arcs, synthetic_truth):
    from hamgrav.core.terms import SolarRadiationPressure

    est = GravityEstimator(
        body=synthetic_truth.body,
        members=2,
        per_trajectory=(SolarRadiationPressure(1e-3),),
        estimate_trajectory_params=True,
    )
    with pytest.raises(InputError, match="members=1"):
        est.fit(small_arcs)


def test_a_warm_start_no_step_improves_keeps_the_starting_model(small_arcs, synthetic_truth):
    held_out = np.array([2, 6])
    good = GravityEstimator("sh", degree=2, body=synthetic_truth.body)
    good.fit(small_arcs, validation=held_out)
    # a solver that can take no step: every trial is rejected
    stuck = LevenbergMarquardt(max_iter=1, lambda0=1e20)
    warm = GravityEstimator("sh", degree=2, body=synthetic_truth.body, solver=stuck)
    warm.fit(small_arcs, init=good.params_, validation=held_out)
    assert warm.result_.outcome.value == "converged"
    assert "kept the starting model" in warm.result_.message
    assert np.array_equal(warm.params_, good.params_)
    # the same solver from scratch learns nothing and says so
    scratch = GravityEstimator("sh", degree=2, body=synthetic_truth.body, solver=stuck)
    scratch.fit(small_arcs, validation=held_out)
    assert scratch.result_.outcome.value == "no improvement"
    # a warm start from a model that does not beat no correction is not "kept": it failed
    poor = GravityEstimator("sh", degree=2, body=synthetic_truth.body, solver=stuck)
    poor.fit(small_arcs, init=np.zeros(5), validation=held_out)
    assert poor.result_.outcome.value == "no improvement"
    assert "kept the starting model" not in poor.result_.message


def test_warm_starts_run_the_warm_solver(small_arcs, synthetic_truth):
    est = GravityEstimator(
        "sh",
        degree=2,
        body=synthetic_truth.body,
        solver=LevenbergMarquardt(max_iter=4),
        warm_solver=LevenbergMarquardt(max_iter=1),
    )
    est.fit(small_arcs)
    assert est.fitted_.solver["max_iter"] == 4
    est.fit(small_arcs, init=est.params_)
    assert est.fitted_.solver["max_iter"] == 1 and est.result_.iterations == 1
    # a solver given to fit() wins over both
    est.fit(small_arcs, init=est.params_, solver=LevenbergMarquardt(max_iter=2))
    assert est.fitted_.solver["max_iter"] == 2


def test_an_ensemble_resumes_at_the_member_it_was_fitting(small_arcs, synthetic_truth):
    solver = LevenbergMarquardt(max_iter=6, lambda0=1e2, damping_floor=1e-8)
    # a resumed fit from scratch is not a warm start: the warm solver must not run
    warm_solver = LevenbergMarquardt(max_iter=1)
    settings = {"term": "network", "hidden": (4,), "solver": solver, "warm_solver": warm_solver}
    saved = []
    full = GravityEstimator(body=synthetic_truth.body, seed=2, members=2, **settings)
    full.fit(small_arcs, checkpoint=lambda th, st: saved.append((th.copy(), dict(st))))
    assert {st["member"] for _, st in saved} == {0, 1}
    theta, state = next((th, st) for th, st in saved if st["member"] == 1)
    half = theta.size // 2
    # member 0 was done when member 1 saved its first checkpoint: its block is final
    assert np.array_equal(theta[:half], full.params_[:half])
    again = GravityEstimator(body=synthetic_truth.body, seed=2, members=2, **settings)
    again.fit(small_arcs, init=theta, resume=state)
    assert np.array_equal(again.params_[:half], full.params_[:half])
    members = again.fitted_.solver["members"]
    assert members[0]["message"] == "restored from the checkpoint"
    assert members[1]["iterations"] >= 1
    assert again.fitted_.solver["max_iter"] == 6


def _scripted_member_fits(small_arcs, synthetic_truth, outcomes, *, warm=False):
    """A two-member ensemble fitted by a solver whose k-th member result has
    ``outcomes[k]`` (its parameters: half its starting block); the estimator's ensemble
    result and the ensemble problem, training and starting parameters."""
    est = GravityEstimator("network", hidden=(4,), members=2, body=synthetic_truth.body)
    model, _ = est.build_model(small_arcs)
    problem = est._problem(model, small_arcs)
    init = est.initial_params(model, small_arcs)
    train, validation = np.arange(7), np.array([7, 8])
    script = list(outcomes)

    class Scripted(LevenbergMarquardt):
        def _iterate(self, problem, theta, *rest):
            return SolveResult(0.5 * theta, 1.0, 2.0, 1, 1, script.pop(0), "scripted")

    result, summaries = est._fit_members(
        problem, init, Scripted(), train, validation, None, None, None, None, warm
    )
    assert not script  # one solve per member
    return result, summaries, ArcProblem(model, small_arcs), train, init


@pytest.mark.parametrize(
    "outcomes, ensemble",
    [
        (("converged", "converged"), "converged"),
        (("iteration cap", "iteration cap"), "iteration cap"),
        # members that both end normally but not alike: the weaker outcome
        (("converged", "iteration cap"), "iteration cap"),
        (("iteration cap", "converged"), "iteration cap"),
        # a member that fails fails the ensemble
        (("converged", "diverged"), "diverged"),
        (("damping saturated", "converged"), "damping saturated"),
        # from scratch, a member that no step improves is a failure too
        (("no improvement", "converged"), "no improvement"),
    ],
)
def test_an_ensemble_outcome_comes_from_its_members(
    small_arcs, synthetic_truth, outcomes, ensemble
):
    result, summaries, problem, train, init = _scripted_member_fits(
        small_arcs, synthetic_truth, [Outcome(o) for o in outcomes]
    )
    assert result.outcome.value == ensemble
    assert [m["outcome"] for m in summaries] == list(outcomes)
    # the ensemble's costs are those of its mean model on the training arcs, not the members'
    np.testing.assert_array_equal(result.params, 0.5 * init)
    assert result.cost == pytest.approx(problem.cost(result.params, train), rel=1e-12)
    assert result.initial_cost == pytest.approx(problem.cost(init, train), rel=1e-12)


def test_unfit_members_are_those_far_above_the_best_members_cost():
    from hamgrav.fit.estimator import UNFIT_MEMBER_FACTOR, unfit_members

    assert UNFIT_MEMBER_FACTOR == 10.0
    assert unfit_members([1.0, 12.0, None, 9.0]) == {1: 12.0}
    assert unfit_members([2.0, 20.0]) == {}  # exactly the factor: not above it
    assert unfit_members([3.0]) == {} and unfit_members([None, None]) == {}
    assert unfit_members([0.0, 1.0]) == {}  # no scale to compare with


def test_an_ensemble_names_a_member_that_did_not_fit(small_arcs, synthetic_truth):
    est = GravityEstimator("network", hidden=(4,), members=2, body=synthetic_truth.body)
    model, _ = est.build_model(small_arcs)
    problem = est._problem(model, small_arcs)
    init = est.initial_params(model, small_arcs)
    costs = [1e-4, 5e-2]  # the second member returned a block 500 times costlier

    class Scripted(LevenbergMarquardt):
        def _iterate(self, problem, theta, *rest):
            return SolveResult(
                0.5 * theta, 1e-4, 2.0, 3, 1, Outcome.ITERATION_CAP, "capped",
                params_cost=costs.pop(0),
            )  # fmt: skip

    result, _ = est._fit_members(
        problem, init, Scripted(), np.arange(7), np.array([7, 8]), None, None, None, None, False
    )
    assert "member 1 did not fit the training arcs" in result.message
    assert "500x the best member's" in result.message
    assert "member 0 did not fit" not in result.message


def test_a_fit_warns_of_and_records_a_member_that_did_not_fit(
    small_arcs, synthetic_truth, monkeypatch
):
    costs = [5e-2, 1e-4]

    def scripted(self, problem, theta, *rest):
        return SolveResult(
            0.5 * theta, 1e-4, 2.0, 3, 1, Outcome.ITERATION_CAP, "capped", params_cost=costs.pop(0)
        )

    monkeypatch.setattr(LevenbergMarquardt, "_iterate", scripted)
    est = GravityEstimator(
        "network", hidden=(4,), members=2, solver="lm", body=synthetic_truth.body
    )
    with pytest.warns(HamgravWarning, match=r"member\(s\) 0 did not fit the training arcs"):
        est.fit(small_arcs)
    assert est.diagnostics_["unfit_members"] == [0]
    assert est.fitted_.solver["diagnostics"]["unfit_members"] == [0]


def test_a_warm_member_no_step_improves_keeps_its_block_but_a_scratch_one_fails(
    small_arcs, synthetic_truth
):
    stuck = [Outcome.NO_IMPROVEMENT, Outcome.ITERATION_CAP]
    warm, summaries, *_ = _scripted_member_fits(small_arcs, synthetic_truth, stuck, warm=True)
    assert [m["outcome"] for m in summaries] == ["converged", "iteration cap"]
    assert warm.outcome.value == "iteration cap"
    assert "member 0: kept its starting block" in warm.message
    scratch, summaries, *_ = _scripted_member_fits(small_arcs, synthetic_truth, stuck)
    assert [m["outcome"] for m in summaries] == ["no improvement", "iteration cap"]
    assert scratch.outcome.value == "no improvement"
    assert "kept" not in scratch.message


@pytest.fixture(scope="module")
def checkpointed_ensemble(small_arcs, synthetic_truth):
    """A two-member ensemble fit without validation arcs (each member returns its last
    iterate), its settings and every checkpoint it saved."""
    settings = {
        "term": "network",
        "hidden": (4,),
        "members": 2,
        "validation_fraction": 0.0,
        # heavily damped: every step is accepted (and checkpointed)
        "solver": LevenbergMarquardt(max_iter=3, rtol=0.0, lambda0=1e2),
        "seed": 5,
        "body": synthetic_truth.body,
    }
    saved = []
    full = GravityEstimator(**settings)
    full.fit(small_arcs, checkpoint=lambda th, st: saved.append((th.copy(), dict(st))))
    return full, settings, saved


def test_an_ensemble_checkpoint_holds_the_current_block_of_the_member_being_fitted(
    checkpointed_ensemble, small_arcs
):
    full, _, saved = checkpointed_ensemble
    half = full.params_.size // 2
    blocks = (slice(None, half), slice(half, None))
    start = full.initial_params(full.model_, small_arcs)
    for k in (0, 1):
        mine = [th for th, st in saved if st["member"] == k]
        assert mine, f"member {k} saved no checkpoint"
        # without validation and rtol 0, a member's last checkpoint is its last iterate
        np.testing.assert_array_equal(mine[-1][blocks[k]], full.params_[blocks[k]])
        assert not np.array_equal(mine[0][blocks[k]], start[blocks[k]])
        # the other member's block: final before it, still its start after it
        other = blocks[1 - k]
        expected = full.params_[other] if k == 1 else start[other]
        for theta in mine:
            np.testing.assert_array_equal(theta[other], expected)


def test_resuming_an_ensemble_at_its_first_member_fits_the_next_from_scratch_settings(
    checkpointed_ensemble, small_arcs
):
    """The checkpoint's state (its damping) continues the member it was saved from only:
    the later members start as in the uninterrupted fit and end where it ended."""
    full, settings, saved = checkpointed_ensemble
    theta, state = next((th, st) for th, st in saved if st["member"] == 0)
    assert state["lambda"] != settings["solver"].lambda0
    again = GravityEstimator(**settings)
    again.fit(small_arcs, init=theta, resume=state)
    half = full.params_.size // 2
    np.testing.assert_array_equal(again.params_[half:], full.params_[half:])
    assert again.result_.members[1].history["lambda"][0] == settings["solver"].lambda0


@pytest.mark.filterwarnings("ignore::hamgrav.errors.HamgravWarning")
def test_a_term_object_fits_as_its_spelling_does(small_arcs, synthetic_truth):
    """GravityEstimator takes the term as an object: the same fit, to the last bit, as the
    spelling "sh" / "network" builds (the defaults of solver and hold-out come from the
    term)."""
    from hamgrav.core.terms import NeuralPotential

    body = synthetic_truth.body
    lm = LevenbergMarquardt(max_iter=3)
    r_b = body.brillouin_radius
    pairs = [
        (GravityEstimator("sh", degree=3), GravityEstimator(SphericalHarmonics(3, r_b))),
        (
            GravityEstimator("network", hidden=(4,), members=2, solver=lm),
            GravityEstimator(NeuralPotential((4,), members=2), solver=lm),
        ),
    ]
    for by_name, by_object in pairs:
        assert by_object.solver_name == by_name.solver_name
        assert by_object.solver_sees_validation == by_name.solver_sees_validation
        assert by_object.holdout_for(small_arcs.n_arcs) == by_name.holdout_for(small_arcs.n_arcs)
        a, b = by_name.fit(small_arcs), by_object.fit(small_arcs)
        assert b.model_.key() == a.model_.key() and np.array_equal(b.params_, a.params_)
        assert np.array_equal(b.validation_, a.validation_)
    # the public spelling of the issue: a term object and nothing else
    sh = GravityEstimator(SphericalHarmonics(2, r_b)).fit(small_arcs)
    assert sh.model_.learnable == SphericalHarmonics(2, r_b)
    assert sh.result_.solver["name"] == "levenberg-marquardt" and sh.diagnostics_["improved"]
    assert GravityEstimator(None).holdout_for(small_arcs.n_arcs) == 0.0


def test_a_term_object_is_checked(small_arcs):
    with pytest.raises(InputError, match="must have parameters shared by all arcs"):
        GravityEstimator(PointMass()).fit(small_arcs)
    with pytest.raises(InputError, match="has its own structure"):
        GravityEstimator(SphericalHarmonics(3, 1.0), degree="auto").choices()
    with pytest.raises(InputError, match="kaula applies to spherical harmonics"):
        GravityEstimator("network", kaula="cv").choices()
    with pytest.raises(InputError, match="term must be one of network, sh, none or a GravityTerm"):
        GravityEstimator("mascons").fit(small_arcs)


def test_arcs_inside_the_series_sphere_are_flagged(small_arcs, synthetic_truth):
    """SH need not converge inside its reference sphere: a fit whose arcs dip inside it
    says how many and how deep; one whose arcs stay outside says nothing."""
    body = synthetic_truth.body
    lowest = np.linalg.norm(small_arcs.states[..., :3], axis=-1).min(axis=1)
    assert lowest.min() > body.brillouin_radius  # this campaign flies outside
    with warnings.catch_warnings():
        warnings.simplefilter("error", HamgravWarning)
        outside = GravityEstimator("sh", degree=2, body=body).fit(small_arcs)
    assert "inside_expansion" not in outside.diagnostics_
    # the same arcs against a series about a sphere through the middle of the campaign
    radius = float(np.median(lowest))
    with pytest.warns(HamgravWarning, match=r"arcs fly inside the SH series' reference sphere"):
        inside = GravityEstimator(SphericalHarmonics(2, radius), body=body).fit(small_arcs)
    flagged = inside.diagnostics_["inside_expansion"]
    assert flagged["of"] == small_arcs.n_arcs
    assert flagged["arcs"] == np.count_nonzero(lowest < radius)
    assert flagged["lowest"] == pytest.approx(lowest.min() / radius)


def test_a_network_can_start_at_no_correction(small_arcs, synthetic_truth):
    settings = {
        "term": "network",
        "hidden": (4, 3),
        "members": 2,
        "solver": LevenbergMarquardt(max_iter=2),
        "body": synthetic_truth.body,
        "validation_fraction": 0.0,
    }
    zero = GravityEstimator(network_start="zero-output", **settings)
    model, _ = zero.build_model(small_arcs)
    random = GravityEstimator(**settings).initial_params(model, small_arcs)
    start = zero.initial_params(model, small_arcs)
    # the same seeded hidden layers; each member's 3 output weights zero, nothing else changed
    term = model.learnable
    outputs = [k * term.member_params + term.n_weights - 3 + j for k in (0, 1) for j in range(3)]
    assert np.flatnonzero(start != random).tolist() == outputs
    assert np.all(start[outputs] == 0.0) and np.all(random[outputs] != 0.0)
    points = np.array([[1.5, 0.2, -0.3], [0.1, -2.0, 0.7], [0.0, 0.9, 1.1]])
    potential, acceleration = evaluate_field(model, start, points)
    assert np.all(potential == 0.0) and np.all(acceleration == 0.0)
    assert np.all(evaluate_field(model, random, points)[0] != 0.0)
    # so the fit starts at the known part's own cost, and its first step moves the outputs
    zero.fit(small_arcs)
    problem = zero._problem(model, small_arcs)
    assert zero.result_.initial_cost == pytest.approx(
        problem.cost(np.zeros(problem.n_params)), rel=1e-12
    )
    assert zero.result_.cost < zero.result_.initial_cost
    assert np.all(zero.params_[outputs] != 0.0)
    assert zero.fitted_.solver["network_start"] == "zero-output"


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"term": "network", "network_start": "zeros"}, "must be one of random, zero-output"),
        ({"term": "sh", "degree": 2, "network_start": "zero-output"}, "leave network_start"),
    ],
)
def test_a_network_start_that_does_not_apply_is_refused(small_arcs, settings, message):
    est = GravityEstimator(**settings)
    model, _ = est.build_model(small_arcs)
    with pytest.raises(InputError, match=message):
        est.initial_params(model, small_arcs)
