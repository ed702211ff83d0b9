"""The D-optimal choice of the next orbits (fit.design): it never reads the truth, picks each
orbit once, and a staged campaign flies every orbit."""

import inspect
from dataclasses import replace

import numpy as np
import pytest

from hamgrav.bodies.interiors import build_truth
from hamgrav.core.model import Model
from hamgrav.core.terms import NeuralPotential, PointMass
from hamgrav.errors import InputError
from hamgrav.fit.design import choose_from_plans, d_optimal_campaign, greedy_d_optimal, orbit_plans
from hamgrav.fit.estimator import GravityEstimator
from hamgrav.sim.tracking import OrbitFamily, TrackingConfig, simulate_orbits


@pytest.fixture(scope="module")
def campaign(synthetic_truth):
    families = [OrbitFamily(r, i) for r in (1.3, 1.9) for i in (10.0, 45.0, 80.0)]
    tracking = TrackingConfig(arcs_per_orbit=2, window_spin_periods=0.5)
    return simulate_orbits(synthetic_truth, families, tracking, seed=5)


def _network():
    return Model((PointMass(),), NeuralPotential((4,), members=2))


def _choose(model, theta, plans, truth_body, **kwargs):
    body = truth_body
    return choose_from_plans(
        model,
        theta,
        plans,
        brillouin_radius=body.brillouin_radius,
        body_name=body.name,
        gm_m3_s2=body.gm_m3_s2,
        spin_period_s=body.spin_period_s,
        **kwargs,
    )


def test_d_optimal_choice_never_reads_the_truth(campaign, synthetic_truth):
    model = _network()
    theta = model.learnable.initial_params(2)
    plans = orbit_plans(campaign)
    chosen = _choose(model, theta, plans, synthetic_truth.body, pool=range(6), picks=3)
    # the same campaign with another truth and other measurements: the plans (initial
    # states, sample times) are the same, and so is the choice
    other = build_truth(synthetic_truth.body, "uniform", n_mascons=30, seed=9)
    swapped = replace(
        campaign,
        truth=other.mascons,
        interior=other.interior,
        states=campaign.states[::-1].copy(),
        true_states=np.zeros_like(campaign.true_states),
    )
    again = _choose(
        model, theta, orbit_plans(swapped), synthetic_truth.body, pool=range(6), picks=3
    )
    assert again["picked"] == chosen["picked"] and again["gains"] == chosen["gains"]
    assert "truth" not in inspect.signature(choose_from_plans).parameters
    # the picks depend on the model's parameters
    shifted = _choose(model, 3.0 * theta, plans, synthetic_truth.body, pool=range(6), picks=3)
    assert shifted["gains"] != chosen["gains"]


def test_d_optimal_picks_from_the_pool_once_each(campaign, synthetic_truth):
    model = _network()
    theta = model.learnable.initial_params(0)
    plans = orbit_plans(campaign)
    first = _choose(model, theta, plans, synthetic_truth.body, pool=[0, 2, 3, 5], picks=3)
    assert len(set(first["picked"])) == 3 and set(first["picked"]) <= {0, 2, 3, 5}
    # greedy gains shrink as the accumulated information grows; one block per member
    assert first["gains"] == sorted(first["gains"], reverse=True)
    assert len(first["L_acc"]) == 2 and first["L_acc"][0].shape == (21, 21)
    rest = [k for k in range(6) if k not in first["picked"]]
    second = _choose(
        model, theta, plans, synthetic_truth.body, pool=rest, picks=5, L_acc=first["L_acc"]
    )
    assert sorted(first["picked"] + second["picked"]) == list(range(6))
    with pytest.raises(InputError, match="lists an orbit twice"):
        _choose(model, theta, plans, synthetic_truth.body, pool=[1, 1], picks=1)


def test_one_block_is_the_plain_information_matrix(rng):
    infos = [(a := rng.normal(size=(5, 4))) @ a.T for _ in range(4)]
    plain = greedy_d_optimal(infos, 3)
    blocks = greedy_d_optimal([(m,) for m in infos], 3)
    assert plain[0] == blocks[0] and np.allclose(plain[1], blocks[1])
    # two independent blocks: the gain is the sum of the blocks' gains
    pair = greedy_d_optimal([(m, m) for m in infos], 1)
    assert pair[0] == plain[0][:1] and pair[2][0] == pytest.approx(2 * plain[2][0])


def test_d_optimal_campaign_flies_every_orbit_once(campaign, synthetic_truth):
    est = GravityEstimator(
        body=synthetic_truth.body, hidden=(4,), members=2, solver="lm", lm_max_iter=2, seed=1
    )
    run, choices = d_optimal_campaign(
        est,
        campaign,
        orbit_plans(campaign),
        [2, 2, 2],
        brillouin_radius=synthetic_truth.body.brillouin_radius,
    )
    flown = [k for c in choices for k in c["picked"]]
    assert sorted(flown) == list(range(6)) and [len(c["picked"]) for c in choices] == [2, 2, 2]
    assert [r.n_arcs for r in run.records] == [4, 8, 12]
    assert not run.records[0].warm_started and all(r.warm_started for r in run.records[1:])
    # each stage brings the arcs of its picks
    for record, before, choice in zip(run.records[1:], run.records[:-1], choices[1:], strict=True):
        new = np.setdiff1d(record.arcs, before.arcs)
        assert sorted(set(campaign.trajectory[new])) == sorted(choice["picked"])
