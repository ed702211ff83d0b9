"""Tiny configurations of the experiments of the user's path: own-body (a body from an ICQ file
and a TOML, an SPK in and out) and selection (cross-validated choices against the truth's)."""

import json

from typer.testing import CliRunner

from hamgrav.cli import app

from .snapshot import check_snapshot

runner = CliRunner()


def test_own_body_tiny(tmp_path, monkeypatch):
    # no catalogue: the body comes from the files the experiment writes
    monkeypatch.setenv("HAMGRAV_BODIES", str(tmp_path / "none"))
    out = tmp_path / "own"
    args = [
        "experiment", "own-body", "--orbits", "4", "--arcs-per-orbit", "3", "--icq-q", "8",
        "--n-mascons", "60", "--window-spin-periods", "0.5", "--rows", "sh-auto,sh8",
        "--max-degree", "4", "--folds", "3", "-o", str(out),
    ]  # fmt: skip
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    check_snapshot("own_body", out / "results.json")
    data = json.loads((out / "results.json").read_text())
    rep = data["repetitions"][0]
    assert rep["body"]["mesh_vertices"] == 6 * 8**2 + 2  # the ICQ grid, edges merged
    assert rep["n_arcs"] == 12 and rep["centroid_offset_m"] < 1.0
    auto = rep["fits"]["sh-auto"]
    assert 2 <= auto["chosen"]["degree"] <= 4 and auto["degree"] == auto["chosen"]["degree"]
    # the exported coefficients are the fitted field outside R_B (an exact SH export)
    for row in ("sh-auto", "sh8"):
        for shell, error in rep["export_error"][row].items():
            assert abs(error - rep["field_error"][row][shell]) < 1e-3, (row, shell)
    assert max(rep["field_error"]["sh-auto"][s] for s in ("r1.2", "r1.5")) < 1.0
    readme = (out / "README.md").read_text()
    assert "chosen by cross-validation: degree" in readme and "| sh-auto |" in readme


def test_selection_tiny(tmp_path):
    out = tmp_path / "selection"
    args = [
        "experiment", "selection", "--body", "synthetic", "--n-mascons", "60", "--orbits", "4",
        "--arcs-per-orbit", "3", "--window-spin-periods", "0.5", "--min-radius-rb", "1.0",
        "--sh-degrees", "3", "--hidden", "4", "--lm-iterations", "3",
        "--harmonic-weights", "1e-3,1e-5", "--folds", "3", "-o", str(out),
    ]  # fmt: skip
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    check_snapshot("selection", out / "results.json")
    rep = json.loads((out / "results.json").read_text())["repetitions"][0]
    errors = rep["field_error"]
    assert {"sh3", "sh3-kaula-truth", "sh3-kaula-cv", "sh-auto", "network-best-cv"} <= set(errors)
    # the truth's choice is the lowest 1.05 R_B error among the scanned weights, and the
    # cross-validated fit is one of the scanned fits, refitted the same way
    scanned = {w: errors[f"network-best-w{w:g}"] for w in (1e-3, 1e-5)}
    weight = rep["network_weight"]
    assert errors["network-best-truth"]["r1.05"] == min(e["r1.05"] for e in scanned.values())
    assert errors["network-best-cv"] == scanned[weight["cv_weight"]]
    assert weight["within"] == (weight["cv_over_truth"] <= 1.1)
    # the weight the 'lowest' rule would keep, from the recorded cross-validation table
    (table,) = rep["selection"]["network-best-cv"]
    costs = dict(zip(table["candidates"], table["held_out_cost"], strict=True))
    assert weight["lowest_weight"] == min(costs, key=costs.get) == table["lowest"]
    lowest_error = scanned[weight["lowest_weight"]]["r1.05"]
    assert weight["lowest_over_truth"] == round(
        lowest_error / errors["network-best-truth"]["r1.05"], 4
    )
    # the truth scan of alpha can only do as well as or better than no regularisation there
    assert errors["sh3-kaula-truth"]["r1.05"] <= errors["sh3"]["r1.05"] + 1e-9
    readme = (out / "README.md").read_text()
    assert "never worse than no correction" in readme and "| network-best-cv |" in readme
    assert "the 'lowest' rule on the same folds" in readme
