"""Tiny configurations of each experiment, through the command line and the runner."""

import json
import re

import numpy as np
import pytest
from typer.testing import CliRunner

from hamgrav.cli import app

from .snapshot import check_snapshot

runner = CliRunner()

TINY_CAMPAIGN = [
    "--body", "synthetic", "--n-mascons", "60", "--orbits", "2", "--arcs-per-orbit", "2",
    "--window-spin-periods", "0.5", "--min-radius-rb", "1.0",
]  # fmt: skip
#: A swarm of three particles on the synthetic body with a tiny network, for the swarm tests.
TINY_SWARM = [
    "--body", "synthetic", "--n-mascons", "60", "--particles", "3", "--samples-per-arc", "10",
    "--window-s", "2400", "--gravity-only-degree", "2", "--hidden", "4",
]  # fmt: skip


def test_descent_tiny(tmp_path):
    out = tmp_path / "descent"
    args = [
        "experiment", "descent", *TINY_CAMPAIGN, "--descents", "3", "--sh-degrees", "2",
        "--hidden", "4", "--adam-steps", "3", "--lm-iterations", "6", "--repeat", "2",
        "-o", str(out),
    ]  # fmt: skip
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    check_snapshot("descent", out / "results.json")
    data = json.loads((out / "results.json").read_text())
    assert data["command"].startswith("hamgrav experiment descent")
    assert data["seeds"] == [0, 1] and len(data["repetitions"]) == 2
    assert data["config"]["sh_degrees"] == [2] and data["config"]["lm_iterations"] == 6
    for rep in data["repetitions"]:
        assert set(rep["models"]) == {"point-mass", "sh2", "network", "network-best"}
        for stats in rep["models"].values():
            assert stats["total"] == rep["truth_landed"] == 3
        fits = rep["fits"]
        # each row is fitted as its name says, and the fit moved from its start
        assert fits["network"]["solver"] == "adam" and fits["network"]["iterations"] == 3
        assert fits["network-best"]["solver"] == "levenberg-marquardt"
        assert fits["network-best"]["cost"] < 0.9 * fits["network-best"]["initial_cost"]
        assert fits["network-best"]["damping_floor"] == 1e-8
        assert fits["sh2"]["solver"] == "levenberg-marquardt"
        assert fits["point-mass"]["n_params"] == 0
        # degree-2 SH learned the body's elongation: far better than no correction outside
        assert rep["field_error"]["sh2"]["r1.5"] < 0.5
        # the ensemble: three members, each fitted with its own initialisation
        assert [m["init_seed"] for m in fits["network-best"]["members"]] == [
            rep["seed"] + k for k in range(3)
        ]
        surface, tracked = rep["radius_rb"]["surface_set"], rep["radius_rb"]["arcs"]
        assert surface == sorted(surface) and tracked == sorted(tracked)
        assert surface[0] < 1.0 < tracked[0]  # the 30 m set reaches inside the data
    agg = data["aggregate"]["models"]["sh2"]["median_m"]
    medians = [r["models"]["sh2"]["median_m"] for r in data["repetitions"]]
    assert agg["min"] == min(medians) and agg["max"] == max(medians)
    readme = (out / "README.md").read_text()
    assert "| sh2 |" in readme and "2 repetition(s)" in readme
    assert "- `touchdown.png`: for each planning model" in readme
    assert "surface-following set lies at" in readme
    # the README can be written again from results.json, with hand-written notes carried in
    (out / "NOTES.md").write_text("Seed 1 is the hard draw.\n")
    again = runner.invoke(app, ["experiment", "readme", str(out)])
    assert again.exit_code == 0, again.output
    rerendered = (out / "README.md").read_text()
    assert "## Notes\n\nSeed 1 is the hard draw." in rerendered
    assert rerendered.replace("## Notes\n\nSeed 1 is the hard draw.\n\n", "") == readme
    assert (out / "touchdown.png").stat().st_size > 1000


def test_solvers_tiny(tmp_path):
    out = tmp_path / "solvers"
    args = [
        "experiment", "solvers", *TINY_CAMPAIGN, "--orbits", "4", "--hidden", "4",
        "--adam-steps", "4", "--lm-iterations", "3", "--stages", "2", "--picks", "3",
        "-o", str(out),
    ]  # fmt: skip
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    check_snapshot("solvers", out / "results.json")
    data = json.loads((out / "results.json").read_text())
    rep = data["repetitions"][0]
    assert set(rep["fits"]) == {
        "sh4-lm",
        "sh8-lm",
        "network-adam-unweighted",
        "network-lm-unweighted",
        "network-adam-weighted",
        "network-lm-weighted",
    }
    assert rep["fits"]["network-lm-weighted"]["weighted"] is True
    assert rep["fits"]["network-adam-unweighted"]["solver"] == "adam"
    stages = rep["continual"]["sh8-lm"]["warm"]
    assert [s["n_arcs"] for s in stages] == [4, 8]
    assert (
        stages[1]["warm_started"] and not rep["continual"]["sh8-lm"]["scratch"][1]["warm_started"]
    )
    readme = (out / "README.md").read_text()
    assert "| network-lm-weighted | levenberg-marquardt | weighted |" in readme
    assert (out / "d_optimal.png").stat().st_size > 1000
    d = rep["d_optimal"]
    assert d["greedy_logdet"][0] >= max(r[0] for r in d["random_logdet"])


def test_experiment_option_errors(tmp_path):
    result = runner.invoke(
        app, ["experiment", "descent", "--interior", "solid", "-o", str(tmp_path / "x")]
    )
    assert result.exit_code == 2
    assert "interior must be one of" in result.output
    assert not (tmp_path / "x").exists()


def test_continual_tiny(tmp_path, monkeypatch):
    from hamgrav.experiments import continual

    warm_solvers = []

    fit_staged = continual.fit_staged

    def spy(*args, **kwargs):
        estimator, run = fit_staged(*args, **kwargs)
        warm_solvers.append(estimator.warm_solver)
        return estimator, run

    monkeypatch.setattr(continual, "fit_staged", spy)
    out = tmp_path / "continual"
    args = [
        "experiment", "continual", *TINY_CAMPAIGN, "--orbits", "4", "--hidden", "4",
        "--stages", "2", "--sh-degree", "2", "--no-warm-gate", "-o", str(out),
    ]  # fmt: skip
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    check_snapshot("continual", out / "results.json")
    # the network's warm stages run the warm solver without its gate (on by default; SH
    # has no warm solver), and the reproducing command says so
    gates = [s.validation_gate for s in warm_solvers if s is not None]
    assert gates == [False, False]
    data = json.loads((out / "results.json").read_text())
    assert " --no-warm-gate " in data["command"]
    rep = data["repetitions"][0]
    assert [s["n_arcs"] for s in rep["stages"]] == [4, 8]
    for stage in rep["stages"]:
        for mode in ("warm", "scratch"):
            assert set(stage[mode]) == {"network-best", "sh2"}
            for values in stage[mode].values():
                assert {"r1.05", "r1.2", "r1.5", "h30m", "iterations", "wall_s"} <= set(values)
                assert values["relative_cost"] > 0  # of no correction's cost
    assert rep["stages"][1]["warm"]["sh2"]["warm_started"]
    assert not rep["stages"][1]["scratch"]["sh2"]["warm_started"]
    summary = rep["summary"]["sh2"]
    assert summary["final_r1.2_warm"] == rep["stages"][-1]["warm"]["sh2"]["r1.2"]
    assert "## Against the targets" in (out / "README.md").read_text()
    assert (out / "continual.png").stat().st_size > 1000


def test_descent_with_the_shape_prior_tiny(tmp_path):
    common = [
        "experiment", "descent", *TINY_CAMPAIGN, "--descents", "3", "--sh-degrees", "2",
        "--hidden", "4", "--lm-iterations", "2", "--adam-steps", "2",
    ]  # fmt: skip
    plain = tmp_path / "plain"
    assert runner.invoke(app, [*common, "-o", str(plain)]).exit_code == 0
    out = tmp_path / "residual"
    args = [*common, "--prior", "shape", "--compare-with", str(plain), "-o", str(out)]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert json.loads((out / "results.json").read_text())["config"]["compare_with"] == str(plain)
    # a comparison that is not a descent run without the prior is refused up front
    wrong = runner.invoke(app, [*common, "--compare-with", str(out), "-o", str(tmp_path / "x")])
    assert wrong.exit_code == 2 and "not a descent run without the prior" in wrong.output
    missing = runner.invoke(
        app, [*common, "--compare-with", str(tmp_path / "nowhere"), "-o", str(tmp_path / "y")]
    )
    assert missing.exit_code == 2 and "cannot read" in missing.output
    rep = json.loads((out / "results.json").read_text())["repetitions"][0]
    assert set(rep["models"]) == {"shape", "shape+sh2", "shape+network"}
    errors = rep["field_error"]
    # the prior alone is a real model: it explains part of the perturbation, not all of it
    assert 0.0 < errors["shape"]["r1.5"] < 1.0
    assert rep["fits"]["shape+network"]["members"]
    readme = (out / "README.md").read_text()
    assert "residual on the constant-density shape prior" in readme
    assert "| shape+network |" in readme and "against the shape model alone" in readme


def test_descent_with_both_blocks_tiny(tmp_path):
    out = tmp_path / "both"
    args = [
        "experiment", "descent", *TINY_CAMPAIGN, "--descents", "2", "--sh-degrees", "2",
        "--hidden", "4", "--lm-iterations", "2", "--adam-steps", "2", "--prior", "both",
        "--harmonic", "1e-3", "-o", str(out),
    ]  # fmt: skip
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    rep = json.loads((out / "results.json").read_text())["repetitions"][0]
    tracking_alone = {"point-mass", "sh2", "network", "network-best"}
    assert set(rep["models"]) == tracking_alone | {"shape", "shape+sh2", "shape+network"}
    assert rep["fits"]["shape+network"]["members"]
    # the harmonic penalty reaches the network-best rows, and only them
    for row in ("network-best", "shape+network"):
        assert rep["fits"][row]["harmonic"] == {"weight": 1e-3, "collocation_points": 1500}
    assert "harmonic" not in rep["fits"]["network"] and "harmonic" not in rep["fits"]["sh2"]
    readme = (out / "README.md").read_text()
    assert "the rows named `shape...`" in readme and "harmonic penalty of weight 0.001" in readme
    # both blocks carry the paper's numbers, each its own
    assert "| point-mass |" in readme and "| shape+sh2 |" in readme


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["descent", "--prior", "polyhedron"], "--prior must be 'none', 'shape' or 'both'"),
        (["interiors", "--truths", "marble"], "--truths must be among"),
        (["deep", "--deep-bins-rb", "0.9,0.5"], "--deep-bins-rb must be two or more increasing"),
        (["deep", "--stages", "19"], "--stages must lie between 1 and --orbits (18)"),
        (["deep", "--descent-span", "all"], "--descent-span must be one of end, whole"),
        (["deep", "--prior", "mascons"], "--prior must be one of none, shape, got 'mascons'"),
        (["deep", "--descent-iterations", "-1"], "--descent-iterations must be at least 0, got -1"),
        (["deep", "--descent-share", "1"], "--descent-share must be 0 (unweighted) or lie in"),
        (
            ["deep", "--descents", "0", "--descent-share", "0.2"],
            "--descent-share weighs the descents",
        ),
        (
            ["deep", "--descent-validation", "0.2"],
            "--descent-validation holds out a fraction in (0, 0.5) of the descents of a "
            "fixed-budget refit: give --descent-iterations above 0",
        ),
        (
            ["deep", "--descent-iterations", "5", "--descent-validation", "0.5"],
            "--descent-validation holds out a fraction in (0, 0.5)",
        ),
        (
            ["deep", "--descents", "2", "--descent-iterations", "5", "--descent-validation", "0.1"],
            "--descent-validation 0.1 of 2 descents holds none out",
        ),
        (
            ["deep", "--descents", "0", "--descent-anchor", "0.1"],
            "--descent-anchor holds the descent refit near the stage-6 fit: give --descents",
        ),
        (["deep", "--descent-anchor", "-0.1"], "--descent-anchor must be at least 0"),
        (
            ["deep", "--descent-anchor-on", "geoid"],
            "--descent-anchor-on must be one of acceleration, potential, got 'geoid'",
        ),
        (
            ["deep", "--prior", "shape", "--prior-placement", "moved"],
            "--prior-placement must be one of centred, in-place, got 'moved'",
        ),
        (["deep", "--prior-placement", "in-place"], "--prior-placement needs --prior shape"),
        (["deep", "--descent-noise", "-1"], "--descent-noise must be at least 0"),
        (["deep", "--envelope-softening-rb", "-0.1"], "--envelope-softening-rb must be at least 0"),
        (["descent", "--sh-degrees", "4,1"], "of --sh-degrees must be at least 2, got 4,1"),
        (["descent", "--shells-rb", "0.5"], "every value of --shells-rb must be at least 1.0"),
        (["descent", "--altitude-m", "-5"], "--altitude-m must be above 0, got -5.0"),
        (["continual", "--stages", "0"], "--stages must be at least 1, got 0"),
        (["uncertainty", "--thresholds", "5"], "every value of --thresholds must be at most 1"),
        (["swarm", "--hidden", "0"], "every value of --hidden must be at least 1, got 0"),
        (["descent", "--hidden", ""], "--hidden needs at least one value"),
        (["descent", "--radius-rb", "1.5,30"], "every value of --radius-rb must be at most 20.0"),
        (["descent", "--n-mascons", "5"], "--n-mascons must be at least 10, got 5"),
        (["deep", "--shells-rb", "1.0"], "every value of --shells-rb must be above 1.0"),
        (["deep", "--map-degrees", "5"], "--map-degrees must be among --sh-degrees"),
    ],
)
def test_experiment_rejects_an_unknown_choice(tmp_path, args, message):
    result = runner.invoke(app, ["experiment", *args, "-o", str(tmp_path / "x")])
    assert result.exit_code == 2 and message in result.output


def test_interiors_tiny(tmp_path):
    out = tmp_path / "interiors"
    args = [
        "experiment", "interiors", *TINY_CAMPAIGN, "--sh-degrees", "2", "--hidden", "4",
        "--lm-iterations", "3", "--truths", "head-tail,void", "-o", str(out),
    ]  # fmt: skip
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    check_snapshot("interiors", out / "results.json")
    rep = json.loads((out / "results.json").read_text())["repetitions"][0]
    assert set(rep["truths"]) == {"head-tail", "void"}
    for truth in rep["truths"].values():
        errors = truth["field_error"]
        assert set(errors) == {"shape", "network-scratch", "shape+network", "shape+sh2"}
        # the shape alone misses part of the perturbation, not all of it
        missed = truth["missed_fraction"]
        assert set(missed) == {"r1.05", "r1.1", "r1.2", "r1.5"}
        assert all(0.0 < v < 1.0 for v in missed.values())
        assert missed == {k: errors["shape"][k] for k in missed}
    readme = (out / "README.md").read_text()
    assert "### Truth: void" in readme and "(paper, head/tail: 15-21 %)" in readme
    assert (out / "residuals.png").stat().st_size > 1000


def test_anomalies_tiny(tmp_path):
    out = tmp_path / "anomalies"
    args = [
        "experiment", "anomalies", *TINY_CAMPAIGN, "--interior", "anomalies",
        "--arcs-per-orbit", "5",
        "--sh-degrees", "2,3", "--kaula-degrees", "3", "--hidden", "4", "--lm-iterations", "3",
        "-o", str(out),
    ]  # fmt: skip
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    check_snapshot("anomalies", out / "results.json")
    rep = json.loads((out / "results.json").read_text())["repetitions"][0]
    names = {"shape", "shape+sh2", "shape+sh3", "shape+sh3-kaula", "shape+sh3-kaula-holdout"}
    assert set(rep["field_error"]) == names | {"shape+network"}
    assert set(rep["kaula_alpha"]) == {"shape+sh3-kaula", "shape+sh3-kaula-holdout"}
    # the holdout choice never saw its validation arcs; the truth choice trained on all
    assert rep["fits"]["shape+sh3-kaula-holdout"]["n_validation"] > 0
    assert rep["fits"]["shape+sh3-kaula"]["n_validation"] == 0
    assert rep["best_sh"] in names - {"shape"}
    readme = (out / "README.md").read_text()
    assert "| shape+network |" in readme and "Kaula alpha chosen" in readme
    assert (out / "maps.png").stat().st_size > 1000


def test_anomalies_tiny_cv_rows(tmp_path):
    """--cv-sh adds SH rows chosen from the arcs alone; the other rows are those without."""
    out = tmp_path / "anomalies"
    args = [
        "experiment", "anomalies", *TINY_CAMPAIGN, "--interior", "anomalies",
        "--arcs-per-orbit", "5", "--sh-degrees", "2,3", "--kaula-degrees", "3", "--hidden", "4",
        "--lm-iterations", "3", "--cv-sh", "-o", str(out),
    ]  # fmt: skip
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    rep = json.loads((out / "results.json").read_text())["repetitions"][0]
    assert {"shape+sh3-kaula-cv", "shape+sh-cv"} <= set(rep["field_error"])
    assert rep["cv_degree"]["shape+sh-cv"] in (2, 3)
    degree, alpha = rep["fits"]["shape+sh-cv"]["selection"]
    assert degree["candidates"] == [2, 3] and alpha["name"] == "kaula_alpha"
    assert rep["kaula_alpha"]["shape+sh-cv"] == alpha["chosen"]
    (alpha,) = rep["fits"]["shape+sh3-kaula-cv"]["selection"]
    assert rep["kaula_alpha"]["shape+sh3-kaula-cv"] == alpha["chosen"]
    assert rep["fits"]["shape+sh3-kaula-cv"]["n_validation"] == 0  # folds of all the arcs


#: A tiny deep campaign: 4 orbits in 2 stages, a 4-unit network, short fits.
TINY_DEEP = [
    "experiment", "deep", *TINY_CAMPAIGN, "--orbits", "4", "--radius-rb", "1.2,1.8",
    "--stages", "2", "--hidden", "4", "--lm-iterations", "3", "--warm-iterations", "2",
    "--altitude-m", "30", "--descents", "2",
]  # fmt: skip


def test_deep_tiny(tmp_path):
    out = tmp_path / "deep"
    args = [
        *TINY_DEEP, "--sh-degrees", "2,3", "--map-degrees", "2,3", "--map-points", "31",
        "--descent-degrees", "3", "--random-orders", "2", "-o", str(out),
    ]  # fmt: skip
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    check_snapshot("deep", out / "results.json")
    data = json.loads((out / "results.json").read_text())
    rep = data["repetitions"][0]
    # network-best's warm stages gate their steps on validation by default
    assert rep["fits"]["network-best"]["validation_gate"] is True
    models = {"sh2", "sh3", "network-best"}
    # the tracked samples: all of them, ordered quartiles, none below the redraw floor
    radii = rep["radius_rb"]
    assert radii["n_samples"] == rep["n_arcs"] * 40 == 8 * 40
    quartiles = [radii[k] for k in ("min", "q1", "median", "q3", "max")]
    assert quartiles == sorted(quartiles) and radii["min"] >= 1.0 and radii["below_floor"] == 0
    # every model evaluated: exterior shells, the deep set as a whole and by bin, the patches
    for key in ("exterior_error", "deep_error", "patch_median"):
        assert set(rep[key]) == models
        assert all(v is not None and 0.0 < v < 1e6 for v in rep[key].values()), key
    labels = list(rep["deep_bin_points"])
    assert labels == ["0.25-0.45", "0.45-0.55", "0.55-0.65", "0.65-0.75", "0.75-0.85", "0.85-0.95"]
    assert all(re.fullmatch(r"\d\.\d\d-\d\.\d\d", k) for k in labels)
    assert all(n > 0 for n in rep["deep_bin_points"].values())
    assert set(rep["deep_bins"]) == models
    for by_bin in rep["deep_bins"].values():
        assert list(by_bin) == labels and all(0.0 < v < 1e6 for v in by_bin.values())
    # degree 2 learned the elongation outside the data ...
    assert rep["exterior_error"]["sh2"] < 0.5
    # ... and inside the Brillouin sphere the same coefficients are amplified
    assert rep["deep_error"]["sh2"] > rep["exterior_error"]["sh2"]
    assert rep["patch_points"] > 0 and 0.0 < rep["patch_inside_brillouin"] <= 1.0
    net = rep["summary"]["network-best"]
    assert net["deepest_bin"] == rep["deep_bins"]["network-best"]["0.25-0.45"]
    assert net["worst_bin"] == max(rep["deep_bins"]["network-best"].values())
    # the stages: the orbits arrive once each, every model warm-started after the first
    stages = rep["stages"]
    assert [s["n_arcs"] for s in stages] == [4, 8]
    assert sorted(k for s in stages for k in s["orbits"]) == [0, 1, 2, 3]
    assert all(not f["warm_started"] for f in stages[0]["fits"].values())
    assert all(f["warm_started"] for f in stages[1]["fits"].values())
    assert stages[1]["exterior_error"] == rep["exterior_error"]
    agg = data["aggregate"]
    assert agg["deep_bins"]["sh2"]["0.25-0.45"]["median"] == rep["deep_bins"]["sh2"]["0.25-0.45"]
    assert agg["summary"]["network-best"]["patch_median"]["n"] == 1
    readme = (out / "README.md").read_text()
    assert "| quantity | ours | paper | target | met |" in readme
    assert "| 0.65 / 1.34 / 45 |" in readme and "| <= 0.29 | " in readme and " of 1 |" in readme
    assert "| network-best |" in readme and "| 0.25-0.45 |" in readme
    for name in ("geometry.png", "deep_bins.png", "maps.png"):
        assert (out / name).stat().st_size > 1000
        assert f"- `{name}`: " in readme
    # the descents: two arcs added, the network and SH 3 refitted, bins after for both
    desc = rep["descents"]
    assert desc["n"] == 2 and all(r < 1.0 for r in desc["contact_radius_rb"])
    assert set(desc["fits"]) == set(rep["deep_bins_after_descents"]) == {"sh3", "network-best"}
    assert all(f["n_arcs"] == 10 and f["warm_started"] for f in desc["fits"].values())
    # each refit says what it left of no correction's cost: the network's on its hold-out
    # (one descent), SH's (no hold-out) on its training arcs
    assert desc["fits"]["network-best"]["checked_on"] == "validation arcs"
    assert desc["fits"]["sh3"]["checked_on"] == "training arcs"
    assert all(0 < f["relative_cost"] < 1e6 for f in desc["fits"].values())
    for by_bin in rep["deep_bins_after_descents"].values():
        assert list(by_bin) == labels and all(0.0 < v < 1e6 for v in by_bin.values())
    after = rep["descents_summary"]["network-best"]
    assert after["deepest_bin_before"] == net["deepest_bin"]
    assert (
        after["deepest_bin_after"] == rep["deep_bins_after_descents"]["network-best"]["0.25-0.45"]
    )
    # what the refit did on the deep set, told without the truth: for the ensemble only
    assert after["deep_change"] > 0
    assert after["deep_spread_before"] > 0 and after["deep_spread_after"] > 0
    assert "deep_change" not in rep["descents_summary"]["sh3"]
    assert (
        f"- seed 0, network-best: change {after['deep_change']:.3g}, spread "
        f"{after['deep_spread_before']:.3g} -> {after['deep_spread_after']:.3g}" in readme
    )
    # the truth's error of the acceleration on the deep set, for every refitted model
    for m in ("network-best", "sh3"):
        s = rep["descents_summary"][m]
        assert 0 < s["deep_acceleration_before"] < 1e6 and 0 < s["deep_acceleration_after"] < 1e6
    assert (
        f"(of the acceleration, what the descents observe: {after['deep_acceleration_before']:.3g}"
        f" -> {after['deep_acceleration_after']:.3g})" in readme
    )
    # the orders: two random permutations of the same orbits, D-optimal flies each once
    orders = rep["orders"]
    assert orders["n_orbits"] == [2, 4] and orders["fixed"] == [
        s["exterior_error"]["network-best"] for s in stages
    ]
    assert len(orders["random"]) == len(orders["random_orbits"]) == 2
    for stage_orbits, curve in zip(orders["random_orbits"], orders["random"], strict=True):
        assert [len(g) for g in stage_orbits] == [2, 2] and len(curve) == 2
        assert sorted(k for g in stage_orbits for k in g) == [0, 1, 2, 3]
    flown = [p["orbit"] for stage in rep["d_optimal_picks"] for p in stage]
    assert sorted(flown) == [0, 1, 2, 3] and len(orders["d-optimal"]) == 2
    assert rep["d_optimal_first_picks"] == [
        [p["radius_rb"], p["inclination_deg"]] for p in rep["d_optimal_picks"][0]
    ]
    assert all(v > 0 for v in orders["d-optimal"] + orders["random"][0])
    parts = rep["wall_parts_s"]
    assert {"simulate", "fixed_order", "descent_refits", "random_orders", "d_optimal"} <= set(parts)
    assert all(v >= 0 for v in parts.values())
    assert "| network, deepest bin (0.25-0.45) after the descents |" in readme
    assert "| D-optimal after 15 orbits | - | 0.14 | <= 0.14 | - |" in readme
    assert "## Arrival orders and the D-optimal campaign" in readme
    for name in ("descents.png", "orders.png"):
        assert (out / name).stat().st_size > 1000 and f"- `{name}`: " in readme
    again = runner.invoke(app, ["experiment", "readme", str(out)])
    assert again.exit_code == 0 and (out / "README.md").read_text() == readme


def test_deep_tiny_with_whole_descents_all_trained(tmp_path):
    out = tmp_path / "deep"
    args = [
        *TINY_DEEP, "--sh-degrees", "2", "--map-degrees", "2", "--map-points", "11",
        "--descent-degrees", "2", "--descent-span", "whole", "--descent-iterations", "3",
        "--descent-share", "0.2", "--random-orders", "0", "--no-d-optimal", "--no-warm-gate",
        "--descent-control", "-o", str(out),
    ]  # fmt: skip
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    data = json.loads((out / "results.json").read_text())
    rep = data["repetitions"][0]
    # the control: the network's same refit with no descent arcs, scored beside it (SH not)
    summary = rep["descents_summary"]
    net = summary["network-best"]
    assert "deep_control" not in summary["sh2"]
    assert set(rep["deep_bins_descent_control"]) == {"network-best"}
    assert (
        net["deepest_bin_control"] == rep["deep_bins_descent_control"]["network-best"]["0.25-0.45"]
    )
    assert net["exterior_control"] != net["exterior_after"]  # the descents moved the refit
    assert net["deep_control"] != net["deep_before"]  # the refit alone moved the fit
    # the warm stages ran without the validation gate (on by default), and the command says so
    assert rep["fits"]["network-best"]["validation_gate"] is False
    assert " --no-warm-gate " in data["command"]
    descents = rep["descents"]
    # the arcs start at release and end at contact
    assert descents["arc_start_radius_rb"] == [1.3, 1.3]
    assert descents["arc_radius_rb"]["max"] == 1.3
    # the network ran its fixed budget on every member (3 members x 3 iterations)
    fits = descents["fits"]
    assert fits["network-best"]["iterations"] == 9 and fits["network-best"]["warm_started"]
    assert fits["sh2"]["warm_started"]
    # no descent is held out: the refits are judged on their training arcs
    assert all(f["checked_on"] == "training arcs" for f in fits.values())
    assert set(rep["deep_bins_after_descents"]) == {"sh2", "network-best"}
    # the descents weigh as a set at the share asked for, the orbital arcs 1: the refits'
    # records carry the weight, and their solver records the weights they ran with
    for f in fits.values():
        assert 0 < f["descent_weight"] < 1
        assert f["arc_weights"]["max"] == 1.0 and f["arc_weights"]["n_not_one"] == 2
        assert f["arc_weights"]["min"] == pytest.approx(f["descent_weight"], rel=1e-3)
    readme = (out / "README.md").read_text()
    assert "the descent arcs weigh as a set 0.2 of the cost" in readme
    assert "40 samples spread evenly from release to contact" in readme
    assert "the network runs 3 LM iterations per member" in readme
    assert (
        f"| network-best | the same refit, no descents | {net['exterior_control']:.3g} | "
        f"{net['deep_control']:.3g} | {net['deepest_bin_control']:.3g} |"
    ) in readme
    # the control's own fit is recorded: the orbital arcs only, the same budget
    control = fits["network-best"]["control"]
    assert control["n_arcs"] == fits["network-best"]["n_arcs"] - 2 and control["iterations"] == 9
    assert "its control (no descents):" in readme and "control" not in fits["sh2"]
    assert "without --descent-iterations it validates on the orbital hold-outs" in readme
    assert "--descent-validation" not in readme
    # the control needs descents to leave out
    refused = runner.invoke(app, [*args[:-2], "--descents", "0", "-o", str(tmp_path / "x")])
    assert refused.exit_code == 2 and "--descent-control refits without the descents" in (
        refused.output
    )


def _deep_tiny_descent_refits(tmp_path, *options) -> tuple[dict, dict, dict, str]:
    """The tiny deep run with three descents, each model refitted by 3 iterations and a
    control, and ``options``: (its config, the network's and SH 2's descent refit records,
    its README)."""
    out = tmp_path / "deep"
    args = [
        *TINY_DEEP, "--descents", "3", "--sh-degrees", "2", "--map-degrees", "2",
        "--map-points", "11", "--descent-degrees", "2", "--descent-iterations", "3",
        "--random-orders", "0", "--no-d-optimal", "--descent-control", *options,
        "-o", str(out),
    ]  # fmt: skip
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    data = json.loads((out / "results.json").read_text())
    fits = data["repetitions"][0]["descents"]["fits"]
    readme = (out / "README.md").read_text()
    return data["config"], fits["network-best"], fits["sh2"], readme


def test_deep_tiny_with_descents_held_out_to_choose_the_refit(tmp_path):
    config, net, sh, readme = _deep_tiny_descent_refits(
        tmp_path, "--descent-share", "0.2", "--descent-validation", "0.34"
    )
    assert config["descent_validation"] == 0.34
    # one descent of three held out of every refit, and the refits judged on it alone
    for f in (net, sh):
        assert f["n_validation_descents"] == 1 and f["checked_on"] == "validation arcs"
    # the network ran its full budget (no patience) and each member returned its best iterate
    assert net["iterations"] == 9 and len(net["best_iterations"]) == 3
    assert all(0 <= b <= 3 for b in net["best_iterations"])
    # the control trains on the orbital arcs alone, and the held-out descent chooses its iterate
    control = net["control"]
    assert control["n_arcs"] == net["n_arcs"] - 2 and control["checked_on"] == "validation arcs"
    assert control["iterations"] == 9 and len(control["best_iterations"]) == 3
    # the training descents weigh at the share, the held-out one as they do
    assert 0 < net["descent_weight"] < 1 and net["arc_weights"]["n_not_one"] == 3
    assert "1 of the descents (seeded) held out of every refit, the rest trained" in readme
    assert "SH its own solver" in readme and "best_iterations" not in sh
    # the iterates chosen, by repetition, and the first repetition's refit and control
    its = ", ".join(map(str, net["best_iterations"]))
    assert f"- network-best: {its}\n" in readme
    assert f"iterate returned {its} (by member); its control" in readme
    assert "with --descent-validation it trains on no descent" in readme
    sh_line = next(line for line in readme.splitlines() if line.startswith("- sh2: "))
    assert "iterate returned" not in sh_line and "held-out" not in sh_line


def test_deep_tiny_with_the_descent_refit_anchored(tmp_path):
    config, net, sh, readme = _deep_tiny_descent_refits(
        tmp_path,
        *("--descent-anchor", "0.1", "--descent-anchor-clearance-rb", "0.2"),
        *("--descent-anchor-on", "potential"),
        *("--envelope-softening-rb", "0.3"),
    )
    assert config["descent_anchor"] == 0.1 and config["descent_anchor_on"] == "potential"
    # the network rows' envelope softened, said where the README describes the network
    assert config["envelope_softening_rb"] == 0.3
    assert "hidden layers 4, its envelope softened at r_c = 0.3 R_B" in readme
    # the network's refit is anchored away from the descents, its control (no new arcs) at
    # the same points, and SH not at all
    assert net["anchor"]["weight"] == 0.1 and 0 < net["anchor"]["points"] < 1500
    assert net["anchor"]["quantity"] == "potential"
    assert net["control"]["anchor"] == net["anchor"]
    assert "anchor" not in sh
    assert "holds its learned potential near the stage-6 fit's, with the weight 0.1" in readme
    assert "farther than 0.2 R_B from every descent sample (--descent-anchor)" in readme
    assert f"anchored at {net['anchor']['points']} points; its control" in readme
    assert readme.count(f"anchored at {net['anchor']['points']} points") == 2


def test_deep_tiny_without_the_later_parts(tmp_path):
    out = tmp_path / "deep"
    args = [
        "experiment", "deep", *TINY_CAMPAIGN, "--stages", "2", "--sh-degrees", "2",
        "--map-degrees", "2", "--hidden", "4", "--lm-iterations", "2",
        "--warm-iterations", "1", "--altitude-m", "30", "--map-points", "11", "--descents", "0",
        "--random-orders", "0", "--no-d-optimal", "-o", str(out),
    ]  # fmt: skip
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    data = json.loads((out / "results.json").read_text())
    # the command that reproduces the run names the switch turned off
    assert " --no-d-optimal " in data["command"] and "--d-optimal" not in data["command"]
    rep = data["repetitions"][0]
    assert "deep_bins_after_descents" not in rep and "d_optimal_picks" not in rep
    assert rep["orders"]["random"] == [] and "d-optimal" not in rep["orders"]
    assert not (out / "orders.png").exists() and not (out / "descents.png").exists()


def test_deep_tiny_on_the_shape_prior(tmp_path):
    # every model sits on the constant-density shape; the synthetic truth is homogeneous, so
    # the prior alone is far below no correction (1), and SH 2 on it far below SH 2 alone
    args = [
        "experiment", "deep", *TINY_CAMPAIGN, "--stages", "2", "--sh-degrees", "2",
        "--map-degrees", "2", "--hidden", "4", "--lm-iterations", "2",
        "--warm-iterations", "1", "--altitude-m", "30", "--map-points", "11", "--descents", "0",
        "--random-orders", "0", "--no-d-optimal",
    ]  # fmt: skip
    reps = {}
    for prior in ("none", "shape"):
        out = tmp_path / prior
        result = runner.invoke(app, [*args, "--prior", prior, "-o", str(out)])
        assert result.exit_code == 0, result.output
        data = json.loads((out / "results.json").read_text())
        reps[prior] = data["repetitions"][0]
    assert " --prior shape " in data["command"] + " "
    assert "prior_alone" not in reps["none"]
    rep = reps["shape"]
    alone = rep["prior_alone"]["shape"]
    assert set(rep["summary"]) == {"sh2", "network-best"}  # the prior is not a fitted row
    assert alone["exterior"] < 0.01 and alone["deep"] < 0.1
    assert alone["deepest_bin"] == alone["0.25-0.45"]
    for key in ("exterior_error", "deep_error"):
        assert rep[key]["sh2"] < 0.2 * reps["none"][key]["sh2"], key
    assert data["aggregate"]["prior_alone"]["shape"]["deep"]["median"] == alone["deep"]
    readme = (tmp_path / "shape" / "README.md").read_text()
    assert "every model on the imaged shape at constant density" in readme
    assert f"| the shape prior alone | {alone['exterior']:.3g} | {alone['deep']:.3g} |" in readme
    assert "| the shape prior alone |" not in (tmp_path / "none" / "README.md").read_text()
    assert "network_start" not in rep["fits"]["network-best"]
    # the network can start on the prior alone: its output weights zero at the first stage
    out = tmp_path / "zero"
    result = runner.invoke(
        app, [*args, "--prior", "shape", "--network-start", "zero-output", "-o", str(out)]
    )
    assert result.exit_code == 0, result.output
    data = json.loads((out / "results.json").read_text())
    assert data["config"]["network_start"] == "zero-output"
    assert data["repetitions"][0]["fits"]["network-best"]["network_start"] == "zero-output"
    assert data["repetitions"][0]["prior_alone"] == rep["prior_alone"]
    # the prior left where the shape is: another known part, said in the README
    out = tmp_path / "in-place"
    result = runner.invoke(
        app, [*args, "--prior", "shape", "--prior-placement", "in-place", "-o", str(out)]
    )
    assert result.exit_code == 0, result.output
    data = json.loads((out / "results.json").read_text())
    assert data["config"]["prior_placement"] == "in-place"
    # a uniform truth: the centres of mass nearly agree, and the prior in place (with its
    # dipole) is as good a known part on the shells (the scoring of the placed prior itself:
    # tests/experiments/test_deep.py)
    in_place = data["repetitions"][0]["prior_alone"]["shape"]
    assert in_place["exterior"] < 0.01 and in_place["deep"] < 0.1
    assert "the shape left where it is, with the point dipole" in (out / "README.md").read_text()


def test_swarm_tiny(tmp_path):
    out = tmp_path / "swarm"
    args = [
        "experiment", "swarm", *TINY_SWARM, "--arcs", "5", "--sh-degrees", "2,3",
        "--lm-iterations", "3", "--harmonic-scan", "", "-o", str(out),
    ]  # fmt: skip
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    check_snapshot("swarm", out / "results.json")
    data = json.loads((out / "results.json").read_text())
    rep = data["repetitions"][0]
    assert rep["n_arcs"] == 5 and rep["n_particles"] == 3
    assert rep["draws"]["total"] == 3 + rep["draws"]["rejected"]
    true = rep["area_to_mass"]["true"]
    assert len(true) == 3 and all(0.055 <= v <= 0.825 for v in true)
    assert "harmonic_scan" not in rep  # "" turns the default scan off
    assert set(rep["area_to_mass"]) == {"true", "sh2", "sh3", "network"}
    assert set(rep["area_to_mass_median_error"]) == {"sh2", "sh3", "network"}
    # the joint SH fits moved every A/m from its start at zero
    assert all(v != 0.0 for v in rep["area_to_mass"]["sh2"])
    assert set(rep["field_error"]) == {"joint", "gravity-only"}
    assert set(rep["field_error"]["joint"]) == {"sh2", "sh3", "network"}
    assert set(rep["field_error"]["gravity-only"]) == {"sh2", "network"}
    assert set(rep["field_error"]["joint"]["sh2"]) == {"r1.05", "r1.2", "h30m"}
    # joint fits carry one A/m per particle, gravity-only fits none
    fits = rep["fits"]
    assert (
        fits["joint"]["sh2"]["n_params"] == 5 + 3 and fits["gravity-only"]["sh2"]["n_params"] == 5
    )
    assert fits["joint"]["network"]["n_params"] == fits["gravity-only"]["network"]["n_params"] + 3
    assert set(rep["wall_s_stages"]) == {
        "simulation", "joint/sh2", "joint/sh3", "joint/network", "gravity-only/sh2",
        "gravity-only/network",
    }  # fmt: skip
    agg = data["aggregate"]
    assert agg["field_error"]["gravity-only"]["sh2"]["h30m"]["median"] == pytest.approx(
        rep["field_error"]["gravity-only"]["sh2"]["h30m"]
    )
    assert agg["area_to_mass_median_error"]["sh2"]["n"] == 1
    readme = (out / "README.md").read_text()
    assert "hamgrav experiment swarm --body synthetic" in readme
    assert "| A/m median relative error, network joint | 3.5 % |" in readme
    assert "| gravity-only | sh2 |" in readme
    assert (out / "swarm.png").stat().st_size > 1000


def test_swarm_tiny_paper_network(tmp_path, monkeypatch):
    from hamgrav.fit.estimator import PRESETS

    # the paper's protocol with a few Adam steps: the rows, not the fit's quality
    monkeypatch.setitem(PRESETS["network"], "adam_steps", 12)
    out = tmp_path / "swarm"
    args = [
        "experiment", "swarm", *TINY_SWARM, "--arcs", "5", "--sh-degrees", "2",
        "--lm-iterations", "2", "--harmonic-scan", "", "--paper-network", "-o", str(out),
    ]  # fmt: skip
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    data = json.loads((out / "results.json").read_text())
    assert " --paper-network " in data["command"]
    rep = data["repetitions"][0]
    assert set(rep["field_error"]["joint"]) == {"sh2", "network", "network-adam"}
    assert set(rep["field_error"]["gravity-only"]) == {"sh2", "network", "network-adam"}
    fits = rep["fits"]
    assert fits["joint"]["network-adam"]["solver"] == "adam"
    assert fits["gravity-only"]["network-adam"]["solver"] == "adam"
    n_free = fits["gravity-only"]["network-adam"]["n_params"]
    assert fits["joint"]["network-adam"]["n_params"] == n_free + 3
    # the joint Adam fit trained (its training cost fell) and reports one A/m per particle
    joint = fits["joint"]["network-adam"]
    assert joint["cost"] < joint["initial_cost"]
    assert len(rep["area_to_mass"]["network-adam"]) == 3
    readme = (out / "README.md").read_text()
    assert "paper-protocol network gravity-only" in readme


def test_swarm_tiny_harmonic_scan(tmp_path):
    out = tmp_path / "swarm"
    args = [
        "experiment", "swarm", *TINY_SWARM, "--arcs", "6", "--sh-degrees", "2",
        "--lm-iterations", "3", "--harmonic-scan", "0,10,1e3", "-o", str(out),
    ]  # fmt: skip
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    data = json.loads((out / "results.json").read_text())
    assert " --harmonic-scan 0,10,1e3 " in data["command"]
    rep = data["repetitions"][0]
    assert set(rep["harmonic_scan"]) == {"joint", "gravity-only"}
    for kind, scan in rep["harmonic_scan"].items():
        assert scan["weights"] == [0.0, 10.0, 1000.0] and scan["rule"] == "one-standard-error"
        costs = scan["held_out_cost"]
        # the weight changes the fit; the default rule keeps the lowest held-out cost's weight
        # or a stronger one, and the kept fit is the one of the chosen weight
        assert len(set(costs)) == 3
        assert scan["chosen"] >= scan["weights"][costs.index(min(costs))]
        k = scan["weights"].index(scan["chosen"])
        kept = rep["fits"][kind]["network"]
        assert kept["diagnostics"]["relative_cost"] == pytest.approx(costs[k], rel=1e-5)
        assert kept.get("harmonic", {}).get("weight", 0.0) == scan["chosen"]
        # every scanned fit's field error is recorded; the kept row's is the chosen weight's
        assert len(scan["field_error"]) == 3
        assert scan["field_error"][k] == rep["field_error"][kind]["network"]
    readme = (out / "README.md").read_text()
    best = min(e["h30m"] for e in rep["harmonic_scan"]["gravity-only"]["field_error"])
    assert f"best scanned {best:.3f}" in readme
    assert "harmonic penalty weight chosen per fit from 0, 10, 1000" in readme
    assert "(the strongest within one standard error of the lowest)" in readme
    assert "- gravity-only network: " in readme


def test_swarm_tiny_harmonic_weight_by_k_folds(tmp_path):
    out = tmp_path / "swarm"
    args = [
        "experiment", "swarm", *TINY_SWARM, "--arcs", "12", "--sh-degrees", "2",
        "--lm-iterations", "3", "--harmonic-scan", "0,10,1e3", "--harmonic-scan-folds", "2",
        "-o", str(out),
    ]  # fmt: skip
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    rep = json.loads((out / "results.json").read_text())["repetitions"][0]
    for kind, scan in rep["harmonic_scan"].items():
        table = scan["selection"]
        # strongest (simplest) first, whatever the order given; 2 folds of the training arcs
        assert table["candidates"] == [1000.0, 10.0, 0.0] and table["folds"] == 2
        assert scan["chosen"] == table["chosen"] and "field_error" not in scan
        assert (
            rep["fits"][kind]["network"].get("harmonic", {}).get("weight", 0.0) == (scan["chosen"])
        )
    assert "- gravity-only network: " in (out / "README.md").read_text()
    one = runner.invoke(app, [*args[:-2], "--harmonic-scan-folds", "1", "-o", str(tmp_path / "x")])
    assert one.exit_code == 2 and "harmonic_scan_folds" in " ".join(one.output.split()).replace(
        "-", "_"
    )


def test_choose_weight_rules():
    from hamgrav.experiments.swarm import choose_weight

    weights = [1e-3, 1e-1, 1e-2]  # the rule ranks weights by value, not by position
    base = np.linspace(1.0, 2.0, 40)
    # 1e-2 is lowest, but 1e-1 is above it by 0.01 on average against +-0.2 arc to arc
    # (standard error 0.2 / sqrt(40) = 0.03): the arcs cannot tell them apart
    close = np.stack([base + 0.5, base + 0.01 + 0.2 * (-1.0) ** np.arange(40), base])
    assert choose_weight(weights, close, "lowest") == 2
    assert choose_weight(weights, close, "one-standard-error") == 1
    # clearly worse on every arc: the strongest weight is not kept
    apart = np.stack([base + 0.5, base + 0.3, base])
    assert choose_weight(weights, apart, "one-standard-error") == 2
    # a single held-out arc has no standard error: the lowest is kept
    assert choose_weight(weights, close[:, :1], "one-standard-error") == int(np.argmin(close[:, 0]))
    # a fit whose cost is not finite is never kept, by either rule
    failed = close.copy()
    failed[1, 3] = np.nan
    assert choose_weight(weights, failed, "one-standard-error") == 2
    failed[2, 0] = np.inf
    assert choose_weight(weights, failed, "lowest") == 0
    with pytest.raises(ValueError, match="finite"):
        choose_weight(weights, np.full((3, 4), np.nan), "lowest")
    with pytest.raises(ValueError, match="unknown rule"):
        choose_weight(weights, close, "median")


def test_swarm_option_errors(tmp_path):
    args = ["experiment", "swarm", "--window-s", "100", "-o", str(tmp_path / "x")]
    result = runner.invoke(app, args)
    assert result.exit_code == 2
    assert "raise window_s to at least" in result.output
    assert not (tmp_path / "x").exists()
    args = ["experiment", "swarm", "--harmonic-scan", "1e-3", "-o", str(tmp_path / "x")]
    result = runner.invoke(app, args)
    assert result.exit_code == 2
    assert "--harmonic-scan needs two or more weights" in result.output
    assert not (tmp_path / "x").exists()
    args = ["experiment", "swarm", "--harmonic-scan-rule", "best", "-o", str(tmp_path / "x")]
    result = runner.invoke(app, args)
    assert result.exit_code == 2
    assert "--harmonic-scan-rule must be one of one-standard-error, lowest" in result.output
    assert not (tmp_path / "x").exists()


def test_uncertainty_tiny(tmp_path):
    out = tmp_path / "uncertainty"
    args = [
        "experiment", "uncertainty", *TINY_CAMPAIGN, "--sh-degrees", "2", "--hidden", "3",
        "--lm-iterations", "3", "--shells-rb", "1.2", "--redraws", "1", "-o", str(out),
    ]  # fmt: skip
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    check_snapshot("uncertainty", out / "results.json")
    data = json.loads((out / "results.json").read_text())
    rep = data["repetitions"][0]
    assert set(rep["covariance"]) == {"sh2", "network-best", "network-best+penalty"}
    assert rep["covariance"]["sh2"]["ranks"] == [5]  # SH: every direction constrained
    net = rep["covariance"]["network-best"]
    assert net["members"] == 3 and all(0 < r <= 16 for r in net["ranks"])
    # the penalty's rows constrain directions the arcs leave free
    penalised = rep["covariance"]["network-best+penalty"]["ranks"]
    assert all(p >= r for p, r in zip(penalised, net["ranks"], strict=True))
    models = ("sh2", "network-best", "network-best+penalty")
    assert set(rep["calibration"]) == {f"{m} {s}" for m in models for s in ("r1.2", "h30m")}
    row = rep["calibration"]["sh2 r1.2"]
    assert 0 <= row["within_1_sigma"] <= row["within_2_sigma"] <= 1 and row["rms_sigma_m2_s2"] > 0
    assert list(rep["thresholds"]["network-best"]) == ["1e-12", "1e-09", "1e-06"]
    assert set(rep["network"]["spread"]) == {"r1.2", "h30m"}
    # one redraw: the spread of two fits of the same arcs with other noise
    assert set(rep["redraws"]) == set(rep["calibration"])
    assert rep["redraws"]["sh2 r1.2"]["rms_spread_m2_s2"] > 0
    assert "### The noise response: refits to noise redraws" in (out / "README.md").read_text()
    readme = (out / "README.md").read_text()
    assert "| sh2 | shell 1.2 R_B |" in readme and "hamgrav experiment uncertainty" in readme
    assert (out / "maps.png").stat().st_size > 1000 and (out / "calibration.png").is_file()
