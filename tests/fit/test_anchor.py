import numpy as np
import pytest

from hamgrav.core.model import Model, evaluate_field
from hamgrav.core.terms import NeuralPotential, PointMass
from hamgrav.errors import InputError
from hamgrav.fit.adam import Adam
from hamgrav.fit.anchor import AnchorSettings, FieldAnchor, RowRegularisers, points_clear_of
from hamgrav.fit.continual import ContinualFit
from hamgrav.fit.estimator import GravityEstimator
from hamgrav.fit.harmonic import HarmonicPenalty
from hamgrav.fit.kaula import KaulaPrior
from hamgrav.fit.lm import LevenbergMarquardt

NET = Model((PointMass(),), NeuralPotential((5, 4), envelope_radius=0.8))
POINTS = np.array([[1.3, 0.2, -0.4], [-0.7, 1.1, 0.5], [0.3, -0.9, 1.6], [2.0, 0.1, 0.0]])


@pytest.fixture(scope="module")
def start():
    return NET.learnable.initial_params(3) * 3.0


@pytest.fixture(scope="module")
def moved(start):
    return start + 0.05 * np.random.default_rng(4).normal(size=start.shape)


def test_anchor_rows_are_the_weighted_change_of_the_field(start, moved):
    """Rows: sqrt(w) (r/R_w)^4 (a(p) - a(p0)); checked against the field function (the path
    the dynamics use), not the anchor's own."""
    anchor = FieldAnchor(NET, POINTS, start, 0.2)
    rows, _ = anchor.terms(start)
    assert np.array_equal(rows, np.zeros(12))
    weight = np.sqrt(0.2) * (np.linalg.norm(POINTS, axis=1) / 0.8) ** 4
    a0 = evaluate_field(NET, start, POINTS)[1]
    a1 = evaluate_field(NET, moved, POINTS)[1]
    expected = (weight[:, None] * (a1 - a0)).reshape(-1)
    rows, _ = anchor.terms(moved)
    np.testing.assert_allclose(rows, expected, rtol=1e-10, atol=1e-14)
    assert np.abs(rows).max() > 1e-3  # the parameters moved the field: not vacuous
    assert anchor.record() == {"anchor": {"weight": 0.2, "points": 4}}


def test_the_potential_anchor_rows_are_the_unweighted_change_of_the_potential(start, moved):
    """Rows: sqrt(w) (N(p) - N(p0)), no radial factor; the learned potential from the field
    function (the dynamics' path), not the anchor's own."""
    anchor = FieldAnchor(NET, POINTS, start, 0.2, quantity="potential")
    assert np.array_equal(anchor.terms(start)[0], np.zeros(4))
    v0 = evaluate_field(NET, start, POINTS)[0]
    v1 = evaluate_field(NET, moved, POINTS)[0]
    rows, jac = anchor.terms(moved)
    np.testing.assert_allclose(rows, np.sqrt(0.2) * (v1 - v0), rtol=1e-10, atol=1e-14)
    assert np.abs(rows).max() > 1e-4
    assert jac.shape == (4, NET.n_learn)
    assert anchor.record() == {"anchor": {"weight": 0.2, "points": 4, "quantity": "potential"}}


@pytest.mark.parametrize("quantity", ["acceleration", "potential"])
def test_anchor_jacobian_matches_finite_differences(start, moved, quantity):
    anchor = FieldAnchor(NET, POINTS, start, 0.1, quantity=quantity)
    _, jac = anchor.terms(moved)
    assert jac.shape == (12 if quantity == "acceleration" else 4, NET.n_learn)
    for j in (0, 9, NET.n_learn - 2, NET.n_learn - 1):
        step = np.zeros_like(moved)
        step[j] = 1e-6
        fd = (anchor.terms(moved + step)[0] - anchor.terms(moved - step)[0]) / 2e-6
        np.testing.assert_allclose(jac[:, j], fd, rtol=1e-5, atol=1e-7 * np.abs(fd).max())


def test_anchor_refuses_what_it_cannot_hold(start):
    with pytest.raises(InputError, match="weight must be positive"):
        FieldAnchor(NET, POINTS, start, 0.0)
    with pytest.raises(InputError, match="nonempty"):
        FieldAnchor(NET, np.zeros((0, 3)), start, 0.1)
    with pytest.raises(InputError, match="weight must be positive"):
        AnchorSettings(-1.0, 0.1)
    with pytest.raises(InputError, match="clearance must be >= 0"):
        AnchorSettings(0.1, -1.0)
    with pytest.raises(InputError, match="acceleration or potential, got 'geoid'"):
        AnchorSettings(0.1, 0.1, quantity="geoid")
    with pytest.raises(InputError, match="acceleration or potential"):
        FieldAnchor(NET, POINTS, start, 0.1, quantity="geoid")


def test_points_clear_of_keeps_exactly_the_points_beyond_the_clearance():
    rng = np.random.default_rng(0)
    points = rng.uniform(-2, 2, size=(700, 3))
    samples = rng.uniform(-2, 2, size=(3, 40, 3))
    samples[1, 30:] = np.nan  # a shorter arc's padding
    finite = samples.reshape(-1, 3)[np.isfinite(samples.reshape(-1, 3)).all(axis=1)]
    distance = np.linalg.norm(points[:, None, :] - finite[None, :, :], axis=-1).min(axis=1)
    kept = points_clear_of(points, samples, 0.3)
    np.testing.assert_array_equal(kept, points[distance > 0.3])
    assert 0 < len(kept) < len(points)
    assert len(points_clear_of(points, samples, 0.0)) == len(points)
    with pytest.raises(InputError, match="positions"):
        points_clear_of(points, np.zeros((2, 6)), 0.3)


def test_row_regularisers_stack_their_parts_and_refuse_a_diagonal_prior(start, moved):
    penalty = HarmonicPenalty(NET, POINTS[:3], 1e-3)
    anchor = FieldAnchor(NET, POINTS, start, 0.1)
    both = RowRegularisers(penalty, None, anchor)
    rows, jac = both.terms(moved)
    np.testing.assert_array_equal(rows[:3], penalty.terms(moved)[0])
    np.testing.assert_array_equal(jac[3:], anchor.terms(moved)[1])
    assert set(both.record()) == {"harmonic", "anchor"}
    from hamgrav.core.terms import SphericalHarmonics

    kaula = KaulaPrior(Model((PointMass(),), SphericalHarmonics(3, 1.0)), 1e-3)
    with pytest.raises(InputError, match="does not combine"):
        RowRegularisers(penalty, kaula)


def _network(truth, members: int = 2) -> GravityEstimator:
    return GravityEstimator(
        "network",
        hidden=(4,),
        members=members,
        validation_fraction=0.25,
        solver=LevenbergMarquardt(max_iter=2),
        body=truth.body,
    )


@pytest.mark.parametrize(
    "members, quantity", [(1, "acceleration"), (2, "acceleration"), (2, "potential")]
)
def test_an_anchored_stage_holds_the_field_where_its_new_arcs_do_not_reach(
    small_arcs, synthetic_truth, members, quantity
):
    """A warm stage with a tight anchor keeps each member's field (or the one network's) at
    the points clear of its new arcs, where the same stage without it moves it by far more;
    the anchor's points are the collocation points the clearance leaves, and the fit
    records them."""
    run = ContinualFit(_network(synthetic_truth, members), small_arcs)
    first = run.add(np.arange(0, 5))
    free, held = run.fork(), run.fork()
    solver = LevenbergMarquardt(max_iter=10, rtol=0.0)
    new = np.arange(5, 9)
    free.add(new, validate=False, solver=solver)
    settings = AnchorSettings(1e3, clearance=0.3, quantity=quantity)
    held.add(new, validate=False, solver=solver, anchor=settings)
    est = held.estimator
    subset = small_arcs.subset(np.setdiff1d(np.arange(9), first.validation))
    points = points_clear_of(est.collocation_points(subset), small_arcs.states[new][..., :3], 0.3)
    assert 0 < len(points) < 1500
    named = {"quantity": "potential"} if quantity == "potential" else {}
    assert est.fitted_.solver["anchor"] == {"weight": 1e3, "points": len(points), **named}
    stage = {"weight": 1e3, "clearance": 0.3, "points": len(points), **named}
    assert held.records[-1].summary()["anchor"] == stage
    assert "anchor" not in free.records[-1].summary()
    term = est.model_.learnable
    member = est.model_.member() if members > 1 else est.model_
    column = 0 if quantity == "potential" else 1
    for k in range(members):
        start, after_free, after_held = (
            evaluate_field(member, term.split_members(fit.params)[k], points)[column]
            if members > 1
            else evaluate_field(member, fit.params, points)[column]
            for fit in (run, free, held)
        )
        size = np.abs(start).max()
        assert np.abs(after_free - start).max() > 0.1 * size
        assert np.abs(after_held - start).max() < 1e-3 * size


def test_an_anchor_needs_a_previous_stage_a_network_and_lm(small_arcs, synthetic_truth):
    run = ContinualFit(_network(synthetic_truth), small_arcs)
    with pytest.raises(InputError, match="fit a first stage"):
        run.add(np.arange(0, 5), anchor=AnchorSettings(0.1, 0.1))
    run.add(np.arange(0, 5))
    # Adam's gradient leaves regularisers out: an anchor there would not act
    with pytest.raises(InputError, match="fit with LM"):
        run.fork().add(np.arange(5, 9), solver=Adam(steps=2), anchor=AnchorSettings(0.1, 0.1))
    sh = ContinualFit(
        GravityEstimator("sh", degree=2, body=synthetic_truth.body, validation_fraction=0.25),
        small_arcs,
    )
    sh.add(np.arange(0, 5))
    with pytest.raises(InputError, match="needs a network"):
        sh.add(np.arange(5, 9), anchor=AnchorSettings(0.1, 0.1))
    est = _network(synthetic_truth)
    with pytest.raises(InputError, match="give init"):
        est.fit(small_arcs, anchor=(np.ones((2, 3)), 0.1))
    with pytest.raises(InputError, match="do not resume"):
        est.fit(small_arcs, init=np.zeros(3), resume={}, anchor=(np.ones((2, 3)), 0.1))


def test_a_continued_fit_is_held_near_the_model_it_continues_not_near_its_start(
    small_arcs, synthetic_truth
):
    """``continue_fit(previous, arcs, anchor=...)`` holds the field near ``previous``'s even
    when the fit starts elsewhere (a resumed checkpoint's parameters, as ``init``): the
    anchored stage ends far nearer ``previous``'s field than its start was, and than the same
    stage without the anchor; the stage records the anchor."""
    est = _network(synthetic_truth)
    est.fit(small_arcs.subset(range(5)))
    previous = est.fitted_
    moved = previous.params + 0.05 * np.random.default_rng(1).normal(size=previous.params.shape)
    settings = AnchorSettings(1e3, clearance=0.3)
    fits = {}
    for name, anchor in (("held", settings), ("free", None)):
        # no hold-out: the returned iterate is the last, not the one the held-out arcs like
        again = _network(synthetic_truth)
        again.validation_fraction = 0.0
        again.solver = LevenbergMarquardt(max_iter=10, rtol=0.0)
        again.continue_fit(previous, small_arcs, anchor=anchor, init=moved)
        fits[name] = again
    held = fits["held"].continuation_anchor(previous, small_arcs, settings)
    assert np.array_equal(held.target, previous.params)
    assert fits["held"].fitted_.stages[-1]["anchor"] == {
        "weight": 1e3,
        "points": len(held.points),
        "clearance": 0.3,
    }
    assert "anchor" not in fits["free"].fitted_.stages[-1]
    term = previous.model.learnable
    member = previous.model.member()

    def field(p, k):
        return evaluate_field(member, term.split_members(p[: term.n_params])[k], held.points)[1]

    for k in range(term.members):
        start = field(previous.params, k)
        moved_by, held_by, free_by = (
            np.sqrt(np.mean((field(p, k) - start) ** 2))
            for p in (moved, fits["held"].fitted_.params, fits["free"].fitted_.params)
        )
        assert held_by < 0.1 * moved_by and held_by < 0.1 * free_by
