import json

import pytest
from typer.testing import CliRunner

from hamgrav.cli import app
from hamgrav.io import load_arcs

runner = CliRunner()


def test_bodies_lists_synthetic():
    result = runner.invoke(app, ["bodies"])
    assert result.exit_code == 0
    assert result.stdout.splitlines()[0] == "synthetic"


def test_body_json_synthetic():
    result = runner.invoke(app, ["body", "synthetic", "--json", "--mascons", "200"])
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    for key in (
        "name",
        "gm_m3_s2",
        "spin_period_s",
        "synchronous_radius_m",
        "brillouin_radius_m",
        "envelope_fraction_inside_brillouin",
    ):
        assert key in report
    assert set(report["perturbation_ratio"]) == {"1.1", "2.0", "3.0"}
    ratios = report["perturbation_ratio"]
    # the perturbation fades with distance
    assert ratios["1.1"] > ratios["2.0"] > ratios["3.0"] > 0
    assert 0.5 < report["envelope_fraction_inside_brillouin"] <= 1.0


def test_body_table_has_units():
    result = runner.invoke(app, ["body", "synthetic", "--mascons", "200"])
    assert result.exit_code == 0
    assert "GM [m^3/s^2]" in result.stdout and "Brillouin radius R_B [m]" in result.stdout


def test_unknown_body_is_clear(monkeypatch, tmp_path):
    monkeypatch.setenv("HAMGRAV_BODIES", str(tmp_path))
    result = runner.invoke(app, ["body", "vesta"])
    assert result.exit_code == 2
    assert "body catalogue not found" in result.output


CAMPAIGN = """
body = "synthetic"
interior = "uniform"
n_mascons = 100
seed = 5
[orbits]
families = [[1.5, 30.0], [1.9, 70.0]]
[tracking]
arcs_per_orbit = 2
window_spin_periods = 0.3
"""


def test_simulate_writes_arcs(tmp_path):
    toml = tmp_path / "c.toml"
    toml.write_text(CAMPAIGN)
    out = tmp_path / "arcs.h5"
    result = runner.invoke(app, ["simulate", str(toml), "-o", str(out)])
    assert result.exit_code == 0, result.output
    arcs = load_arcs(out)
    assert arcs.n_arcs == 4 and arcs.config["seed"] == 5 and arcs.interior == "uniform"


@pytest.mark.parametrize(
    "text, message",
    [
        ('body = "synthetic"\ncolour = 3\n[orbits]\ncount=1', "unknown key(s) ['colour']"),
        ('body = "synthetic"\n', "an [orbits] table is required"),
        (
            'body = "synthetic"\n[orbits]\ncount = 1\n[tracking]\ncadense_s = 3',
            "unknown key(s) in [tracking] ['cadense_s']",
        ),
        ('body = "synthetic"\ninterior = "solid"\n[orbits]\ncount=1', "interior 'solid'"),
        ("body = ", "not valid TOML"),
    ],
)
def test_simulate_bad_campaign(tmp_path, text, message):
    toml = tmp_path / "c.toml"
    toml.write_text(text)
    result = runner.invoke(app, ["simulate", str(toml), "-o", str(tmp_path / "a.h5")])
    assert result.exit_code == 2
    assert message in " ".join(result.output.split())
    assert not (tmp_path / "a.h5").exists()


@pytest.fixture(scope="module")
def arcs_file(tmp_path_factory, small_arcs):
    from hamgrav.io import save_arcs

    return save_arcs(small_arcs, tmp_path_factory.mktemp("arcs") / "arcs.h5")


def test_fit_evaluate_select(arcs_file, tmp_path):
    model = tmp_path / "sh3.h5"
    result = runner.invoke(app, ["fit", str(arcs_file), "--model", "sh:3", "-o", str(model)])
    assert result.exit_code == 0, result.output
    assert not (tmp_path / "sh3.h5.checkpoint.npz").exists()
    result = runner.invoke(app, ["evaluate", str(model), "--shells", "1.2,1.5", "--json"])
    assert result.exit_code == 0, result.output
    errors = json.loads(result.stdout)["field_error"]
    assert set(errors) == {"r1.2", "r1.5", "h30m"}
    assert errors["r1.5"] < 1.0  # better than no correction on a shell above the arcs' floor
    pool = tmp_path / "pool.toml"
    pool.write_text(
        'body = "synthetic"\n[orbits]\ncount = 4\nradius_rb = [1.4, 2.0]\n'
        "inclination_deg = [0, 90]\n[tracking]\narcs_per_orbit = 2\n"
        "window_spin_periods = 0.2\n"
    )
    picks = tmp_path / "picks.json"
    result = runner.invoke(
        app, ["select", str(model), "--pool", str(pool), "--picks", "2", "-o", str(picks)]
    )
    assert result.exit_code == 0, result.output
    rows = json.loads(picks.read_text())["picks"]
    assert len(rows) == 2 and rows[0]["gain"] > rows[1]["gain"] > 0


def test_fit_network_writes_model(arcs_file, tmp_path):
    from hamgrav.modelfile import load_model

    model = tmp_path / "nn.h5"
    result = runner.invoke(
        app, ["fit", str(arcs_file), "--hidden", "8", "--steps", "4", "-o", str(model)]
    )
    assert result.exit_code == 0, result.output
    fitted = load_model(model, expect_body="synthetic")
    assert fitted.model.n_learn == 3 * 8 + 8 + 8 + 1
    assert fitted.solver["name"] == "adam"


def test_fit_rejects_bad_options(arcs_file, tmp_path):
    out = tmp_path / "m.h5"
    result = runner.invoke(app, ["fit", str(arcs_file), "--model", "sh:1", "-o", str(out)])
    assert result.exit_code == 2 and "--model must be 'network' or 'sh:L'" in result.output
    result = runner.invoke(app, ["fit", str(arcs_file), "--kaula", "1e-6", "-o", str(out)])
    assert result.exit_code == 2 and "--kaula applies to spherical-harmonics" in result.output
    result = runner.invoke(app, ["fit", str(arcs_file), "--resume", "-o", str(out)])
    assert result.exit_code == 2 and "no checkpoint" in result.output
    assert not out.exists()


def test_experiment_solvers_tiny(tmp_path):
    out = tmp_path / "solvers"
    result = runner.invoke(
        app,
        [
            "experiment",
            "solvers",
            "--body",
            "synthetic",
            "--orbits",
            "4",
            "--arcs-per-orbit",
            "3",
            "--hidden",
            "6",
            "--adam-steps",
            "4",
            "--lm-iterations",
            "2",
            "--stages",
            "2",
            "-o",
            str(out),
        ],
    )
    assert result.exit_code == 0, result.output
    data = json.loads((out / "results.json").read_text())
    assert set(data["fits"]) == {
        "sh4-lm",
        "sh8-lm",
        "network-adam-unweighted",
        "network-lm-unweighted",
        "network-adam-weighted",
        "network-lm-weighted",
    }
    assert data["command"].startswith("hamgrav experiment solvers")
    readme = (out / "README.md").read_text()
    assert "| network-lm-weighted | lm | weighted |" in readme
    assert (out / "d_optimal.png").stat().st_size > 1000
    d = data["d_optimal"]
    assert d["greedy_logdet"][0] >= max(r[0] for r in d["random_logdet"])


def test_experiment_descent_tiny(tmp_path):
    out = tmp_path / "descent"
    result = runner.invoke(
        app,
        [
            "experiment",
            "descent",
            "--body",
            "synthetic",
            "--orbits",
            "2",
            "--arcs-per-orbit",
            "2",
            "--descents",
            "2",
            "--hidden",
            "4",
            "--adam-steps",
            "3",
            "--lm-iterations",
            "2",
            "-o",
            str(out),
        ],
    )
    assert result.exit_code == 0, result.output
    data = json.loads((out / "results.json").read_text())
    for key in ("experiment", "body", "seed", "command", "models", "field_error", "wall_s"):
        assert key in data
    assert {"point-mass", "sh4", "sh8", "sh12", "network"} <= set(data["models"])
    for stats in data["models"].values():
        assert {"median_m", "p90_m", "worst_m", "landed", "total"} <= set(stats)
        assert stats["total"] == data["truth_landed"] == 2
    assert set(data["field_error"]["network"]) == {"h30m", "r1.05", "r1.1", "r1.2", "r1.5"}
    assert data["field_error"]["point-mass"]["r1.2"] == 1.0
    assert (out / "touchdown.png").exists() and (out / "geometry.png").exists()
    assert "| point-mass |" in (out / "README.md").read_text()
