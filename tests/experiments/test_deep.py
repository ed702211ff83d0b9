"""The deep-region experiment's pieces: its default campaign, the stage orders, the tracked
descents and their report (the D-optimal choice: tests/fit/test_d_optimal.py)."""

from dataclasses import replace

import numpy as np
import pytest
import trimesh

from hamgrav.core.geometry import points_inside
from hamgrav.errors import InputError
from hamgrav.experiments.deep import (
    DeepExperimentConfig,
    arrival_stages,
    random_orders,
)
from hamgrav.report.deep import _descents_section
from hamgrav.sim.descent import DescentConfig, tracked_descents
from hamgrav.sim.tracking import TrackingConfig


def test_default_campaign_is_the_papers_grid():
    config = DeepExperimentConfig()
    families = config.campaign(0).families
    assert len(families) == 18 and config.arcs_per_orbit == 7 and config.n_mascons == 240
    assert sorted({f.radius_rb for f in families}) == [1.1, 1.8, 2.5]
    inclinations = sorted({f.inclination_deg for f in families})
    assert len(inclinations) == 6 and inclinations[0] == 10.0 and inclinations[-1] == 80.0


def test_every_stage_spans_the_radii_at_different_inclinations():
    families = DeepExperimentConfig().campaign(0).families
    radius = np.array([f.radius_rb for f in families])
    incl = np.array([f.inclination_deg for f in families])
    stages = arrival_stages(radius, incl, 6)
    assert [len(g) for g in stages] == [3] * 6
    assert sorted(np.concatenate(stages).tolist()) == list(range(18))
    for group in stages:
        assert sorted(radius[group]) == [1.1, 1.8, 2.5]
        assert len(set(incl[group])) == 3
    # the order is fixed: the first stage is 10 deg at 1.1, 38 at 1.8, 66 at 2.5 R_B
    assert list(zip(radius[stages[0]], incl[stages[0]], strict=True)) == [
        (1.1, 10.0),
        (1.8, 38.0),
        (2.5, 66.0),
    ]
    # fewer stages: the same order, split into larger groups
    assert np.array_equal(np.concatenate(arrival_stages(radius, incl, 2)), np.concatenate(stages))


def test_random_orders_permute_the_same_orbits_into_the_same_stage_sizes():
    orders = random_orders(18, 5, 6, seed=3)
    assert len(orders) == 5
    for stages in orders:
        assert [len(g) for g in stages] == [3] * 6
        assert sorted(np.concatenate(stages).tolist()) == list(range(18))
    # seeded by the repetition's seed: the same seed repeats them, another changes them
    again = random_orders(18, 5, 6, seed=3)
    assert all(
        np.array_equal(np.concatenate(a), np.concatenate(b))
        for a, b in zip(orders, again, strict=True)
    )
    other = random_orders(18, 5, 6, seed=4)
    assert not np.array_equal(np.concatenate(orders[0]), np.concatenate(other[0]))
    assert len({tuple(np.concatenate(s)) for s in orders}) == 5


def test_tracked_descents_end_at_the_surface(synthetic_truth):
    body = synthetic_truth.body
    tracking = TrackingConfig(samples_per_arc=40, cadence_s=14.0)
    arcs = tracked_descents(synthetic_truth, 3, DescentConfig(), tracking, seed=2)
    assert arcs.n_arcs == 3 and arcs.samples_per_arc == 40
    assert set(arcs.trajectory_kind) == {"descent"}
    dt = np.diff(arcs.times, axis=1) * body.units.time_s
    assert np.allclose(dt, 14.0)
    # the last sample is the contact point, on the surface (the contact time is refined to
    # 1 ms, a fall of well under 1 m); the first is outside the body
    length = body.units.length_m
    last = arcs.true_states[:, -1, :3]
    contact = arcs.trajectory_info["contact_point"]
    assert np.all(np.linalg.norm(last - contact, axis=1) * length < 0.01)
    _, distance, _ = trimesh.proximity.closest_point(body.mesh, last)
    assert np.all(distance * length < 0.5)
    triangles = np.asarray(body.mesh.triangles)
    assert not points_inside(triangles, arcs.true_states[:, 0, :3]).any()
    # the arcs carry the orbital arcs' noise level
    noise = (arcs.states - arcs.true_states)[..., :3] * length
    assert 0.02 < noise.std() < 0.1
    assert np.all(arcs.trajectory_info["duration_s"] >= 39 * 14.0)


def test_a_whole_descent_arc_spans_release_to_contact(synthetic_truth):
    """With span "whole" the same descents are tracked from their release state to their
    contact, samples evenly spaced; the truth's states are the same trajectory."""
    body = synthetic_truth.body
    tracking = TrackingConfig(samples_per_arc=40, cadence_s=14.0)
    end = tracked_descents(synthetic_truth, 2, DescentConfig(), tracking, seed=2)
    whole = tracked_descents(synthetic_truth, 2, DescentConfig(), tracking, seed=2, span="whole")
    assert whole.samples_per_arc == 40 and whole.config["span"] == "whole"
    np.testing.assert_allclose(whole.times[:, 0], 0.0)
    duration = whole.trajectory_info["duration_s"] / body.units.time_s
    np.testing.assert_allclose(whole.times[:, -1], duration, rtol=1e-12)
    steps = np.diff(whole.times, axis=1)
    np.testing.assert_allclose(steps, np.repeat(duration[:, None] / 39, 39, axis=1), rtol=1e-9)
    np.testing.assert_allclose(
        whole.true_states[:, 0], whole.trajectory_info["initial_state"], atol=1e-12
    )
    length = body.units.length_m
    contact = whole.trajectory_info["contact_point"]
    assert np.all(np.linalg.norm(whole.true_states[:, -1, :3] - contact, axis=1) * length < 0.01)
    np.testing.assert_allclose(whole.true_states[:, -1], end.true_states[:, -1], atol=1e-9)
    with pytest.raises(InputError, match="span must be one of end, whole"):
        tracked_descents(synthetic_truth, 1, span="all")


def _descent_report(fits_by_rep: list[dict]) -> dict:
    """A minimal deep report whose repetitions hold the given descent refit records."""
    descents = {
        "n": 2,
        "duration_s": {"min": 100.0, "max": 200.0},
        "arc_radius_rb": {"min": 0.3, "max": 0.9},
        "contact_radius_rb": [0.3, 0.5],
    }
    reps = [
        {"deep_bin_points": {"0.25-0.45": 3}, "descents": {**descents, "fits": fits}}
        for fits in fits_by_rep
    ]
    reps.append({"deep_bin_points": {"0.25-0.45": 3}})  # a repetition without descents
    aggregate = {"deep_bins": {}, "deep_bins_after_descents": {}, "descents_summary": {}}
    return {"repetitions": reps, "aggregate": aggregate, "config": {}}


def test_the_descent_report_says_which_refits_restarted_and_what_they_left():
    def fit(warm, **more):
        record = {"n_arcs": 10, "outcome": "converged", "iterations": 3, "wall_s": 1.0}
        return {**record, "warm_started": warm, **more}

    restarted = fit(False, relative_cost=0.3, checked_on="training arcs")
    report = _descent_report(
        [
            {"sh8": restarted, "network-best": fit(True)},
            {"sh8": fit(True), "network-best": fit(True)},
        ]
    )
    text = "\n".join(_descents_section(report, "network-best"))
    assert (
        "- sh8: 10 arcs, converged, 3 iterations, 1.0 s, restarted from its initialisation, "
        "cost on the training arcs 0.3 of no correction's" in text
    )
    # a record written before relative costs were kept reads as before
    assert "- network-best: 10 arcs, converged, 3 iterations, 1.0 s\n" in text + "\n"
    # counted over the repetitions that have descents
    assert "so it was in sh8: 1 of 2, network-best: 0 of 2 repetitions." in text
    # no restart anywhere: no such paragraph
    quiet = _descent_report([{"sh8": fit(True)}])
    assert "refitted from its initialisation" not in "\n".join(_descents_section(quiet, "x"))


def test_descent_noise_scales_the_descents_noise_only(synthetic_truth):
    """--descent-noise scales the descents' position noise (0: their states are the truth's)
    and leaves the same descents: the same true states, the noise drawn the same way."""
    from hamgrav.experiments.deep import campaign_descents

    config = DeepExperimentConfig(body="synthetic", descents=2)
    nominal = campaign_descents(synthetic_truth, config, 3)
    quiet = campaign_descents(synthetic_truth, replace(config, descent_noise=0.0), 3)
    half = campaign_descents(synthetic_truth, replace(config, descent_noise=0.5), 3)
    np.testing.assert_array_equal(quiet.true_states, nominal.true_states)
    np.testing.assert_allclose(quiet.states, quiet.true_states, rtol=0, atol=1e-14)
    noise = nominal.states - nominal.true_states
    assert np.abs(noise[..., :3]).max() > 0
    np.testing.assert_allclose(half.states - half.true_states, 0.5 * noise, atol=1e-15)


def test_the_prior_alone_is_scored_where_the_rows_place_it(synthetic_truth, small_arcs):
    """The deep experiment scores the same prior its rows are fitted on: in place or centred
    (the synthetic truth's head is denser, so the two differ)."""
    from types import SimpleNamespace

    from hamgrav.experiments.common import sets_for
    from hamgrav.experiments.deep import _prior_alone

    shells = sets_for(synthetic_truth, (1.2,), (), 0)
    ctx = SimpleNamespace(seed=0)
    config = DeepExperimentConfig(body="synthetic", prior="shape", altitude_m=30.0)
    centred = _prior_alone(small_arcs, synthetic_truth, shells, config, ctx)["shape"]
    moved = replace(config, prior_placement="in-place")
    in_place = _prior_alone(small_arcs, synthetic_truth, shells, moved, ctx)["shape"]
    assert in_place["exterior"] != centred["exterior"] and in_place["deep"] != centred["deep"]
