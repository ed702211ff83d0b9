"""The deep-region ladder: its oracle fits, and the experiment end to end on a tiny campaign."""

import json
from dataclasses import replace

import numpy as np
import pytest

from hamgrav.core.fields import field_errors, shell_points
from hamgrav.errors import InputError
from hamgrav.experiments.ladder import DEFAULT_RUNGS, DeepLadderConfig, oracle_fit
from hamgrav.experiments.runner import run_experiment
from hamgrav.fit.estimator import GravityEstimator

from .snapshot import check_snapshot


@pytest.mark.parametrize("prior", [None, "shape"])
def test_oracle_fit_carries_the_field_beside_the_known_part(prior, synthetic_truth, small_arcs):
    """SH 6 fitted to the truth's field on exterior shells matches it on a shell between them,
    with the point mass or the shape prior as the known part (the target is the truth minus
    what the known part already carries: a sign or offset slip shows up as a large error)."""
    body = synthetic_truth.body
    r_b = body.brillouin_radius
    points = np.concatenate([shell_points(s * r_b, 300, seed=k) for k, s in enumerate((1.2, 1.5))])
    est = GravityEstimator(term="sh", degree=6, body=body, prior=prior, prior_mascons=50)
    model, params, info = oracle_fit(est, small_arcs, points, synthetic_truth)
    if prior is None:  # then the target is the truth's perturbing potential itself
        own = field_errors(model, params, synthetic_truth.mascons, {"p": points})["p"]
        assert info["on_points"] == pytest.approx(own, rel=1e-3) and own < 0.02
    error = field_errors(
        model, params, synthetic_truth.mascons, {"r": shell_points(1.35 * r_b, 200)}
    )
    assert error["r"] < 0.02
    # no correction is 1 with the point mass; the shape prior alone is somewhere below it
    unfitted = field_errors(
        model, 0 * params, synthetic_truth.mascons, {"r": shell_points(1.35 * r_b, 200)}
    )
    assert error["r"] < 0.1 * unfitted["r"]


def test_oracle_fit_of_a_network_lowers_its_error_where_it_is_sampled(synthetic_truth, small_arcs):
    body = synthetic_truth.body
    points = shell_points(1.3 * body.brillouin_radius, 400, seed=3)
    est = GravityEstimator(term="network", hidden=(8,), members=2, body=body, seed=1, solver="lm")
    model, params, _ = oracle_fit(est, small_arcs, points, synthetic_truth)
    start = est.initial_params(model, small_arcs)
    before = field_errors(model, start, synthetic_truth.mascons, {"p": points})["p"]
    after = field_errors(model, params, synthetic_truth.mascons, {"p": points})["p"]
    assert after < 0.3 * before and len(params) == len(start)
    _, penalised, _ = oracle_fit(est, small_arcs, points, synthetic_truth, harmonic=1e-4)
    assert np.all(np.isfinite(penalised))


#: The tiny campaign of the end-to-end ladder tests (a synthetic body, 6 arcs, 2 descents).
TINY = dict(
    body="synthetic",
    n_mascons=60,
    orbits=2,
    arcs_per_orbit=3,
    window_spin_periods=0.5,
    radius_rb=(1.3, 1.9),
    min_radius_rb=1.0,
    hidden=(4,),
    descents=2,
    sh_degree=2,
    altitude_m=40.0,
    shells_rb=(1.3,),
    deep_bins_rb=(0.5, 0.95),
)


def test_the_ladder_runs_every_rung_and_writes_its_tables(tmp_path):
    config = DeepLadderConfig(
        **TINY,
        lm_iterations=2,
        oracle_altitudes_m=(20.0, 60.0),
        oracle_harmonic=(0.0, 1e-4),
        adam_rungs=("tracking",),
        oracle_balance=True,
        adam_steps=3,
    )
    report, _ = run_experiment("deep-ladder", config, seed=2, output=tmp_path, verbose=False)
    check_snapshot("deep-ladder", tmp_path / "results.json")
    ladder = report["repetitions"][0]["ladder"]
    expected = {f"network/{r}" for r in DEFAULT_RUNGS if r != "oracle-arcs"} | {
        "network/oracle-arcs:0",
        "network/oracle-arcs:0.0001",
    }
    expected |= {f"sh2/{r}" for r in DEFAULT_RUNGS} | {"network-adam/tracking"}
    assert all("on_points" in ladder[k] for k in expected if "oracle" in k)
    assert set(ladder) == expected
    assert all(np.isfinite(v["exterior"]) for v in ladder.values())
    readme = (tmp_path / "README.md").read_text()
    assert (
        "### network" in readme
        and "### sh2" in readme
        and readme.count("| (e)") == 4
        and readme.count("| (a+b)") == 2
    )
    assert (tmp_path / "ladder.png").stat().st_size > 0
    assert json.loads((tmp_path / "results.json").read_text())["config"]["sh_degree"] == 2


def test_descents_rung_fits_the_arcs_and_the_descents_points(tmp_path):
    # (b+e): rung (b) with the descents' true positions added, each set weighed alike
    config = DeepLadderConfig(
        **TINY,
        oracle_altitudes_m=(20.0,),
        oracle_harmonic=(1e-4,),
        rungs=("oracle-arcs", "oracle-descents"),
        oracle_balance=True,
    )
    report, _ = run_experiment("deep-ladder", config, seed=2, output=tmp_path, verbose=False)
    rep = report["repetitions"][0]
    points = rep["oracle_points"]
    assert points["descents"] > 0 and points["arcs"] == 2 * 3 * 40
    assert set(rep["ladder"]) == {
        "network/oracle-arcs",
        "network/oracle-descents",
        "sh2/oracle-arcs",
        "sh2/oracle-descents",
    }
    assert all(np.isfinite(v["on_points"]) for v in rep["ladder"].values())
    # (b+e) is fitted on more points than (b): its fit differs
    on_points = {k: v["on_points"] for k, v in rep["ladder"].items()}
    assert on_points["network/oracle-descents"] != on_points["network/oracle-arcs"]
    readme = (tmp_path / "README.md").read_text()
    assert readme.count("| (b+e)") == 2 and f"the descents' {points['descents']}" in readme


def test_the_deep_share_and_the_iteration_cap_reach_the_oracle_fits(tmp_path):
    # the same (b+e) fit with the descents' share of the cost at 0.1 instead of 0.5, and a
    # cap of 3 LM iterations a member
    on_points = {}
    for share in (0.5, 0.1):
        config = DeepLadderConfig(
            **TINY,
            oracle_altitudes_m=(20.0,),
            oracle_harmonic=(1e-4,),
            rungs=("oracle-descents",),
            oracle_balance=True,
            oracle_deep_share=share,
            oracle_iterations=3,
        )
        out = tmp_path / str(share)
        report, _ = run_experiment("deep-ladder", config, seed=2, output=out, verbose=False)
        rep = report["repetitions"][0]
        members = rep["fits"]["network/oracle-descents"]["members"]
        assert all(m["iterations"] <= 3 for m in members)
        on_points[share] = rep["ladder"]["network/oracle-descents"]["on_points"]
    assert on_points[0.1] != on_points[0.5]


def test_a_deep_share_without_balance_is_refused():
    with pytest.raises(InputError, match="oracle_deep_share weighs the sets of a balanced fit"):
        DeepLadderConfig(body="synthetic", oracle_deep_share=0.2).check()


def test_descents_rung_without_descents_is_refused():
    with pytest.raises(InputError, match="oracle-descents fits the descents' points"):
        DeepLadderConfig(body="synthetic", descents=0, rungs=("oracle-descents",)).check()


def test_oracle_altitudes_above_the_brillouin_sphere_are_refused(tmp_path):
    config = DeepLadderConfig(body="synthetic", n_mascons=60, orbits=2, oracle_altitudes_m=(300.0,))
    with pytest.raises(InputError, match="no point 300 m above synthetic's surface"):
        run_experiment("deep-ladder", config, output=tmp_path, verbose=False)


def test_oracle_fit_refuses_a_first_order_solver(synthetic_truth, small_arcs):
    est = GravityEstimator(term="network", hidden=(4,), solver="adam", body=synthetic_truth.body)
    with pytest.raises(InputError, match="runs Levenberg-Marquardt"):
        oracle_fit(est, small_arcs, np.ones((3, 3)), synthetic_truth)


def test_unknown_rung_refused():
    with pytest.raises(InputError, match="unknown rung"):
        DeepLadderConfig.from_dict({"rungs": ["oracle-deep", "oracle-everything"]})
    with pytest.raises(InputError, match="oracle-deep is not a tracking rung"):
        DeepLadderConfig.from_dict({"adam_rungs": ["oracle-deep"]})


def test_with_the_shape_prior_every_model_sits_on_it_and_the_prior_is_scored_alone(tmp_path):
    # the tiny campaign's truth is homogeneous, so the constant-density shape prior alone is
    # far below no correction (1); the rows fitted on it must not be worse than it outside
    config = DeepLadderConfig(
        **TINY, oracle_altitudes_m=(20.0,), oracle_harmonic=(1e-4,), rungs=("oracle-arcs",)
    )
    out = {}
    for prior in ("none", "shape"):
        report, _ = run_experiment(
            "deep-ladder",
            replace(config, prior=prior),
            seed=2,
            output=tmp_path / prior,
            verbose=False,
        )
        out[prior] = report["repetitions"][0]["ladder"]
    assert set(out["none"]) == {"network/oracle-arcs", "sh2/oracle-arcs"}
    assert set(out["shape"]) == {"shape/prior-alone", *out["none"]}
    alone = out["shape"]["shape/prior-alone"]
    assert alone["exterior"] < 0.2 and alone["deep"] < 0.5
    # on the prior, SH 2 fits the rest: better than the prior alone, and than SH 2 without it
    assert out["shape"]["sh2/oracle-arcs"]["exterior"] < alone["exterior"]
    assert out["shape"]["sh2/oracle-arcs"]["exterior"] < out["none"]["sh2/oracle-arcs"]["exterior"]
    readme = (tmp_path / "shape" / "README.md").read_text()
    assert "### shape" in readme and "| the shape prior alone (no correction) |" in readme


def test_an_unknown_prior_is_refused():
    with pytest.raises(InputError, match="prior must be one of none, shape, got 'mascons'"):
        DeepLadderConfig(body="synthetic", prior="mascons").check()
