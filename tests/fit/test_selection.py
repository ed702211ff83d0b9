"""Truth-free model selection: the rule, the folds, cross-validation and the estimator's
choices and hold-out checks."""

import math
import warnings
from dataclasses import replace

import numpy as np
import pytest

from hamgrav.core.arcs import NO_TRUTH
from hamgrav.core.mascons import MasconSet
from hamgrav.errors import HamgravWarning, InputError, PropagationError
from hamgrav.fit.diagnostics import OVERFIT_FACTOR
from hamgrav.fit.estimator import (
    CV_KAULA_ALPHAS,
    MIN_ARCS_TO_HOLD_OUT,
    GravityEstimator,
    default_holdout,
    validation_split,
)
from hamgrav.fit.selection import choose, cross_validate, fold_assignment, paired_excess
from hamgrav.sim.tracking import OrbitFamily, TrackingConfig, simulate_orbits

# ----------------------------------------------------------------------------- the rule
# three candidates (simplest first) on four held-out arcs; candidate 2 is the lowest
TABLE = np.array(
    [
        [1.2, 1.0, 1.4, 1.0],  # excess 0.2, 0, 0.4, 0: mean 0.15, se 0.0957
        [1.0, 1.2, 0.9, 1.1],  # excess 0, 0.2, -0.1, 0.1: mean 0.05, se 0.0645
        [1.0, 1.0, 1.0, 1.0],
    ]
)


def test_paired_standard_error_by_hand():
    excess, se = paired_excess(TABLE, 2)
    np.testing.assert_allclose(excess, [0.15, 0.05, 0.0], rtol=1e-12)
    # sample standard deviation of the per-arc differences over sqrt(4)
    np.testing.assert_allclose(se, [math.sqrt(0.11 / 3) / 2, math.sqrt(0.05 / 3) / 2, 0.0])
    # paired, not the spread of each candidate's own costs: an offset shared by every
    # candidate on an arc (a hard arc) does not enter
    hard = TABLE + np.array([0.0, 5.0, 0.0, 9.0])
    np.testing.assert_allclose(paired_excess(hard, 2)[1], se, rtol=1e-12)


def test_one_standard_error_keeps_the_simplest_within_one_se_of_the_lowest():
    assert choose(TABLE, "lowest") == 2
    # candidate 0 exceeds the lowest by 0.15 > its se 0.096; candidate 1 by 0.05 <= 0.065
    assert choose(TABLE, "one-standard-error") == 1
    # when the simplest is within too, it is kept (first within, not the closest)
    close = TABLE.copy()
    close[0] = [1.0, 1.0, 1.2, 1.0]  # mean excess 0.05, se 0.05
    assert choose(close, "one-standard-error") == 0
    # one held-out unit has no standard error: the lowest (1.4, 0.9, 1.0)
    assert choose(TABLE[:, 2:3], "one-standard-error") == 1


def test_a_candidate_with_a_non_finite_cost_is_never_kept():
    failed = TABLE.copy()
    failed[0] = [1.0, 0.9, 1.0, 1.0]  # the simplest and the lowest, but one arc's cost is NaN
    failed[0, 1] = np.nan
    assert choose(failed, "lowest") == 2
    assert choose(failed, "one-standard-error") == 1
    failed[2, 1] = np.inf  # the lowest fails too: 1 is left
    assert choose(failed, "lowest") == choose(failed, "one-standard-error") == 1
    failed[1, 3] = np.inf
    with pytest.raises(PropagationError, match="finite"):
        choose(failed)


# ----------------------------------------------------------------------------- folds
def test_folds_by_trajectory_never_split_a_trajectory():
    trajectory = np.repeat(np.arange(7), 3)  # 7 orbits of 3 arcs
    arcs = np.setdiff1d(np.arange(21), [4, 11])  # the estimator's validation arcs left out
    folds = fold_assignment(trajectory, arcs, 3, "trajectory", seed=5)
    assert len(folds) == 3
    assert sorted(np.concatenate(folds).tolist()) == arcs.tolist()  # each arc once
    for held in folds:
        assert not set(trajectory[held]) & set(trajectory[np.setdiff1d(arcs, held)])
    # whole trajectories, dealt evenly: 7 orbits into 3, 3, 2 (nearly even)
    assert sorted(len(set(trajectory[f])) for f in folds) == [2, 2, 3]
    again = fold_assignment(trajectory, arcs, 3, "trajectory", seed=5)  # seeded
    assert all(np.array_equal(a, b) for a, b in zip(folds, again, strict=True))
    by_arc = fold_assignment(trajectory, arcs, 4, "arc", seed=5)
    assert sorted(len(f) for f in by_arc) == [4, 5, 5, 5]  # 19 arcs
    with pytest.raises(InputError, match="two folds or more"):
        fold_assignment(trajectory, np.arange(3), 5, "trajectory")


def test_folds_by_altitude_are_contiguous_bands_lowest_first():
    radius = np.array([1.9, 1.2, 1.5, 1.3, 1.8, 1.2, 1.7, 1.4, 1.6])
    trajectory = np.zeros(9, dtype=int)  # one trajectory: altitude folds ignore it
    arcs = np.setdiff1d(np.arange(9), [7])  # 1.4 is a validation arc, not folded
    folds = fold_assignment(trajectory, arcs, 3, "altitude", seed=5, radius=radius)
    assert [f.tolist() for f in folds] == [[1, 3, 5], [2, 6, 8], [0, 4]]
    assert [sorted(radius[f].tolist()) for f in folds] == [
        [1.2, 1.2, 1.3],
        [1.5, 1.6, 1.7],
        [1.8, 1.9],
    ]
    assert all(np.array_equal(f, np.sort(f)) for f in folds)
    # the seed does not move a band
    other = fold_assignment(trajectory, arcs, 3, "altitude", seed=6, radius=radius)
    assert all(np.array_equal(a, b) for a, b in zip(folds, other, strict=True))
    with pytest.raises(InputError, match="two folds or more"):
        fold_assignment(trajectory, arcs[:1], 3, "altitude", radius=radius)


def test_cross_validate_scores_every_candidate_on_the_same_held_out_arcs():
    trajectory = np.arange(10)
    calls = []

    def score(candidate, train, held):
        calls.append((candidate, set(train.tolist()), set(held.tolist())))
        if candidate == "broken":
            raise PropagationError("arcs did not propagate")
        return {"simple": 1.05, "flexible": 1.0}[candidate] + 0.01 * held

    selection = cross_validate(
        score, ["simple", "broken", "flexible"], trajectory, np.arange(10), folds=5, seed=1
    )
    assert len(calls) == 15
    for _, train, held in calls:
        assert not train & held and train | held == set(range(10))
    held = {c: sorted(a for k, _, h in calls if k == c for a in h) for c in ("simple", "flexible")}
    assert held["simple"] == held["flexible"] == list(range(10))
    # 0.05 above on every arc: no spread, so "simple" is not within one standard error
    assert selection.chosen == "flexible" and selection.candidates[selection.lowest] == "flexible"
    assert np.isinf(selection.unit_costs[1]).all()
    record = selection.describe()
    assert record["held_out_cost"][1] is None and record["chosen"] == "flexible"
    assert record["rule"] == "one-standard-error" and record["folds"] == 5


# ----------------------------------------------------------------------------- the estimator
@pytest.fixture(scope="module")
def structured_arcs(synthetic_truth):
    """16 arcs of the head-tail truth from four orbits: enough for SH above degree 2."""
    families = [
        OrbitFamily(1.4, 20.0),
        OrbitFamily(1.6, 75.0),
        OrbitFamily(1.8, 45.0),
        OrbitFamily(2.0, 110.0),
    ]
    return simulate_orbits(synthetic_truth, families, TrackingConfig(arcs_per_orbit=4), seed=3)


def test_nothing_to_learn_keeps_the_lowest_degree_and_the_strongest_alpha(
    point_mass_arcs, synthetic_truth
):
    body = synthetic_truth.body
    by_degree = GravityEstimator("sh", degree=(4, 2, 3), body=body).fit(point_mass_arcs)
    (table,) = by_degree.selection_
    assert table.candidates == (2, 3, 4) and table.chosen == 2
    assert by_degree.model_.learnable.degree == 2
    by_alpha = GravityEstimator("sh", degree=3, kaula="cv", body=body).fit(point_mass_arcs)
    (table,) = by_alpha.selection_
    assert table.candidates == CV_KAULA_ALPHAS and table.chosen == max(CV_KAULA_ALPHAS)
    assert by_alpha.fitted_.solver["kaula_alpha"] == max(CV_KAULA_ALPHAS)
    assert by_alpha.fitted_.solver["selection"][0]["chosen"] == max(CV_KAULA_ALPHAS)


def test_a_field_with_structure_keeps_a_higher_degree(structured_arcs, synthetic_truth):
    est = GravityEstimator("sh", degree=(2, 3, 4, 5), body=synthetic_truth.body)
    est.fit(structured_arcs)
    (table,) = est.selection_
    assert table.chosen > 2
    mean, se = table.summary()
    assert mean[0] - mean[table.lowest] > se[0]  # degree 2 is clearly worse on held-out arcs
    # the folds are the training arcs, each once: the fit's own validation arcs never
    assert sorted(np.concatenate(table.folds).tolist()) == est.train_.tolist()
    assert not set(np.concatenate(table.folds)) & set(est.validation_)


def test_folds_by_trajectory_in_the_estimator(structured_arcs, synthetic_truth):
    est = GravityEstimator(
        "sh", degree=(2, 3), cv_group="trajectory", folds=4, body=synthetic_truth.body
    )
    est.fit(structured_arcs)
    (table,) = est.selection_
    trajectory = structured_arcs.trajectory
    for held in table.folds:
        rest = np.setdiff1d(est.train_, held)
        assert not set(trajectory[held]) & set(trajectory[rest])
    assert table.unit_costs.shape[1] == len(set(trajectory[est.train_]))  # units: orbits


def test_folds_by_altitude_in_the_estimator(structured_arcs, synthetic_truth):
    est = GravityEstimator(
        "sh", degree=(2, 3), cv_group="altitude", folds=3, body=synthetic_truth.body
    )
    est.fit(structured_arcs)
    (table,) = est.selection_
    lowest = np.linalg.norm(structured_arcs.states[..., :3], axis=-1).min(axis=1)
    bands = [lowest[held] for held in table.folds]
    # the lowest band first
    assert all(a.max() <= b.min() for a, b in zip(bands[:-1], bands[1:], strict=True))
    assert table.unit_costs.shape[1] == len(est.train_)  # units: arcs
    assert "bands of altitude" in table.lines()[0]


def test_kaula_cv_needs_no_truth(small_arcs, synthetic_truth):
    imported = replace(
        small_arcs, truth=MasconSet(np.zeros((0, 3)), np.zeros(0)), interior=NO_TRUTH
    )
    assert not imported.has_truth
    est = GravityEstimator("sh", degree=3, kaula="cv", folds=3, body=synthetic_truth.body)
    est.fit(imported)
    (table,) = est.selection_
    assert table.chosen in CV_KAULA_ALPHAS and len(table.folds) == 3
    assert est.fitted_.training["truth_sha256"] is None


def test_default_hold_out():
    assert default_holdout(MIN_ARCS_TO_HOLD_OUT - 1) == 0.0
    for n, held in ((6, 2), (9, 2), (16, 2), (17, 2), (25, 3), (112, 13)):
        assert len(validation_split(n, default_holdout(n), 0)[1]) == held


def test_sh_holds_out_arcs_by_default_and_only_checks_them(small_arcs, synthetic_truth):
    est = GravityEstimator("sh", degree=2, body=synthetic_truth.body).fit(small_arcs)
    assert len(est.validation_) == 2 and est.diagnostics_["checked_on"] == "validation arcs"
    assert est.fitted_.solver["select_on_validation"] is False
    # the fit is the fit of its training arcs alone: the held-out arcs did not steer it
    alone = GravityEstimator("sh", degree=2, validation_fraction=0.0, body=synthetic_truth.body)
    alone.fit(small_arcs.subset(est.train_))
    np.testing.assert_allclose(est.params_, alone.params_, rtol=1e-10, atol=1e-14)
    ratio = est.diagnostics_["held_out_to_training"]
    per_arc = est.checked_arc_costs_.fitted.mean() / (est.result_.params_cost / len(est.train_))
    assert ratio == pytest.approx(per_arc, rel=1e-12)


def test_too_few_arcs_hold_out_none_and_say_so(small_arcs, synthetic_truth):
    est = GravityEstimator("sh", degree=2, body=synthetic_truth.body)
    with pytest.warns(HamgravWarning, match="only 5 arcs: none held out"):
        est.fit(small_arcs.subset(range(5)))
    assert est.validation_ is None and est.diagnostics_["checked_on"] == "training arcs"


def test_an_overfit_fit_is_flagged_on_its_held_out_arcs(point_mass_arcs, synthetic_truth):
    """The issue's failure in miniature: SH 8 (77 coefficients) on 12 arcs of a point mass
    converges on its 10 training arcs; the 2 held out show it is worse than no correction."""
    est = GravityEstimator("sh", degree=8, body=synthetic_truth.body)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", HamgravWarning)
        est.fit(point_mass_arcs)
    diagnostics = est.diagnostics_
    assert diagnostics["checked_on"] == "validation arcs"
    assert diagnostics["held_out_to_training"] > OVERFIT_FACTOR and diagnostics["overfit"]
    assert not diagnostics["improved"] and est.result_.outcome.value == "no improvement"
    assert any("looks overfit" in str(w.message) for w in caught)
    # the same fit with the degree chosen from the arcs is not
    chosen = GravityEstimator("sh", degree=(2, 4, 8), body=synthetic_truth.body)
    chosen.fit(point_mass_arcs)
    assert chosen.selection_[0].chosen == 2 and not chosen.diagnostics_["overfit"]


def test_choices_are_checked(small_arcs, synthetic_truth):
    body = synthetic_truth.body
    with pytest.raises(InputError, match="kaula applies to spherical harmonics"):
        GravityEstimator("network", kaula="cv", body=body).fit(small_arcs)
    with pytest.raises(InputError, match="cv_rule"):
        GravityEstimator("sh", kaula="cv", cv_rule="median", body=body).fit(small_arcs)
    with pytest.raises(InputError, match="per-trajectory"):
        GravityEstimator(
            "sh", degree="auto", cv_group="trajectory", estimate_trajectory_params=True, body=body
        ).choices()
    with pytest.raises(InputError, match="'altitude' can hold a trajectory's arcs out whole"):
        GravityEstimator(
            "sh", degree="auto", cv_group="altitude", estimate_trajectory_params=True, body=body
        ).choices()
    with pytest.raises(InputError, match="one integer degree"):
        GravityEstimator("sh", degree="auto", body=body).build_model(small_arcs)


def test_cross_validation_on_a_dask_client_equals_builtin_map(point_mass_arcs, synthetic_truth):
    import pickle

    from distributed import Client

    from hamgrav.fit.estimator import _cv_score

    settings = {"term": "sh", "degree": (2, 3), "folds": 3, "body": synthetic_truth.body}
    serial = GravityEstimator(**settings).fit(point_mass_arcs)
    # a work unit is plain data: it survives pickling (Dask workers in other processes)
    unit = pickle.loads(pickle.dumps(_cv_score))
    assert unit is _cv_score
    pickle.dumps((GravityEstimator(**settings).get_params(), point_mass_arcs))
    with Client(processes=False, n_workers=2, threads_per_worker=1, dashboard_address=":0") as c:
        mapper = lambda f, xs: c.gather(c.map(f, list(xs)))  # noqa: E731
        mapped = GravityEstimator(**settings, mapper=mapper).fit(point_mass_arcs)
    np.testing.assert_array_equal(mapped.selection_[0].unit_costs, serial.selection_[0].unit_costs)
    np.testing.assert_array_equal(mapped.params_, serial.params_)


def test_each_choice_has_its_own_cross_validation_unless_told(synthetic_truth):
    body = synthetic_truth.body
    est = GravityEstimator("network", harmonic="cv", body=body)
    assert est.cv_setting("harmonic") == ("altitude", "lowest")
    assert est.cv_setting("degree") == est.cv_setting("kaula") == ("arc", "one-standard-error")
    told = GravityEstimator("network", harmonic="cv", cv_group="trajectory", cv_rule="lowest")
    assert told.cv_setting("harmonic") == told.cv_setting("degree") == ("trajectory", "lowest")
    # bands could hold a trajectory's arcs out whole, leaving its parameters unfitted
    srp = GravityEstimator("network", harmonic="cv", estimate_trajectory_params=True)
    assert srp.cv_setting("harmonic") == ("arc", "lowest")


def test_a_checkpoint_records_each_choices_cross_validation_as_resolved(
    small_arcs, synthetic_truth
):
    """A checkpoint resumes only under the same cross-validation: the resolved group and rule
    of each choice (not None, whose meaning CV_DEFAULTS fixes), and none without a choice."""
    body = synthetic_truth.body
    cv = GravityEstimator("network", harmonic="cv", solver="lm", body=body)
    settings = cv.checkpoint_identity(small_arcs, cv.make_solver())["settings"]
    assert settings["cross_validation"] == {"harmonic": ["altitude", "lowest"]}
    assert "cv_group" not in settings and "cv_rule" not in settings
    told = GravityEstimator("network", harmonic="cv", solver="lm", cv_rule="one-standard-error")
    told.body = body
    other = told.checkpoint_identity(small_arcs, told.make_solver())["settings"]
    assert other["cross_validation"] == {"harmonic": ["altitude", "one-standard-error"]}
    plain = GravityEstimator("sh", degree=3, body=body)
    assert (
        "cross_validation"
        not in plain.checkpoint_identity(small_arcs, plain.make_solver())["settings"]
    )
