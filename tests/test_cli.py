import json

import numpy as np
import pytest
from typer.testing import CliRunner

from hamgrav.cli import app
from hamgrav.files import read_toml
from hamgrav.io.arcs import load_arcs
from hamgrav.sim.campaign import Campaign

runner = CliRunner()


def test_bodies_lists_synthetic():
    result = runner.invoke(app, ["bodies"])
    assert result.exit_code == 0
    assert result.stdout.splitlines()[0] == "synthetic"


@pytest.mark.parametrize(
    ("command", "shown"),
    [
        (["import-oem"], ["Position noise per component [m].", "[deg, ICRF]"]),
        (["select"], ["Campaign TOML whose [orbits] and [tracking] describe"]),
        (["experiment", "descent"], ["Evaluation shells [R_B].", "[default: 30.0]"]),
    ],
)
def test_help_keeps_units_in_brackets(command, shown):
    # brackets in help texts are units and table names, not markup to be swallowed
    result = runner.invoke(app, [*command, "--help"], terminal_width=200)
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    for fragment in shown:
        assert fragment in text, fragment


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
    # the campaign travels with the arcs and reads back whole, its frame included
    assert Campaign.from_dict(arcs.config) == Campaign.from_dict(read_toml(toml))
    assert arcs.config["frame"] == "centre-of-mass"


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
        ('body = "synthetic"\nframe = "inertial"\n[orbits]\ncount=1', "frame 'inertial'"),
        ('body = "synthetic"\ncontrast = -2\n[orbits]\ncount=1', "contrast must be a positive"),
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
    from hamgrav.io.arcs import save_arcs

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
    assert "incl. [deg]" in result.stdout  # units survive the table markup
    rows = json.loads(picks.read_text())["picks"]
    assert len(rows) == 2 and rows[0]["gain"] > rows[1]["gain"] > 0


def test_fit_network_writes_model(arcs_file, tmp_path):
    from hamgrav.io.models import load_model

    model = tmp_path / "nn.h5"
    result = runner.invoke(
        app,
        [
            "fit",
            str(arcs_file),
            "--model",
            "network",
            "--hidden",
            "8",
            "--steps",
            "4",
            "-o",
            str(model),
        ],
    )
    assert result.exit_code == 0, result.output
    fitted = load_model(model, expect_body="synthetic")
    assert fitted.model.n_learn == 3 * 8 + 8 + 8 + 1
    assert fitted.solver["name"] == "adam"


def test_fit_envelope_softening(small_arcs, tmp_path):
    """--envelope-softening-rb gives the network's envelope a softening in R_B of the body,
    carried by the model file; a continued fit must give the same; checked first."""
    from hamgrav.fit.estimator import body_for_arcs
    from hamgrav.io.arcs import save_arcs
    from hamgrav.io.models import load_model

    first = save_arcs(small_arcs.subset(range(5)), tmp_path / "first.h5")
    everything = save_arcs(small_arcs, tmp_path / "all.h5")
    base = ["--model", "network", "--hidden", "6", "--steps", "3"]
    soft, out = tmp_path / "soft.h5", tmp_path / "out.h5"
    result = runner.invoke(
        app, ["fit", str(first), *base, "--envelope-softening-rb", "0.3", "-o", str(soft)]
    )
    assert result.exit_code == 0, result.output
    r_b = body_for_arcs(small_arcs).brillouin_radius  # about the arcs' frame origin
    term = load_model(soft).model.learnable
    assert term.softening == pytest.approx(0.3 * r_b, rel=1e-12)
    # a continued fit keeps its model's envelope: the same softening, or it is refused
    again = ["fit", str(everything), *base, "--init", str(soft), "-o", str(out)]
    assert runner.invoke(app, [*again, "--envelope-softening-rb", "0.3"]).exit_code == 0
    other = runner.invoke(app, [*again, "--envelope-softening-rb", "0.2"])
    assert other.exit_code == 2 and "structure" in other.output
    for extra, message in (
        (["--envelope-softening-rb", "-1"], "--envelope-softening-rb must be a finite number >= 0"),
        (["--model", "sh:3", "--envelope-softening-rb", "0.3"], "applies to networks"),
    ):
        result = runner.invoke(app, ["fit", str(first), *extra, "-o", str(tmp_path / "x.h5")])
        assert result.exit_code == 2 and message in " ".join(result.output.split()), result.output
        assert not (tmp_path / "x.h5").exists()


def test_fit_prior_placement(arcs_file, tmp_path):
    from hamgrav.core.terms import PointDipole
    from hamgrav.io.models import load_model

    out = tmp_path / "in-place.h5"
    base = ["fit", str(arcs_file), "--model", "sh:2"]
    result = runner.invoke(
        app, [*base, "--prior", "shape", "--prior-placement", "in-place", "-o", str(out)]
    )
    assert result.exit_code == 0, result.output
    prior, dipole = load_model(out).model.known
    assert isinstance(dipole, PointDipole)
    np.testing.assert_allclose(dipole.moment, -prior.mascons.centre_of_mass, atol=1e-12)
    for extra, message in (
        (["--prior-placement", "in-place"], "--prior-placement in-place needs --prior shape"),
        (["--prior", "shape", "--prior-placement", "moved"], "--prior-placement must be"),
    ):
        result = runner.invoke(app, [*base, *extra, "-o", str(tmp_path / "x.h5")])
        assert result.exit_code == 2 and message in " ".join(result.output.split()), result.output
        assert not (tmp_path / "x.h5").exists()


def test_fit_rejects_bad_options(arcs_file, tmp_path):
    out = tmp_path / "m.h5"
    result = runner.invoke(app, ["fit", str(arcs_file), "--model", "sh:1", "-o", str(out)])
    assert result.exit_code == 2 and "--model must be one of network, network-best" in result.output
    result = runner.invoke(app, ["fit", str(arcs_file), "--kaula", "1e-6", "-o", str(out)])
    assert result.exit_code == 2 and "--kaula applies to spherical-harmonics" in result.output
    result = runner.invoke(app, ["fit", str(arcs_file), "--resume", "-o", str(out)])
    assert result.exit_code == 2 and "no checkpoint" in result.output
    assert not out.exists()


def test_fit_shape_prior(arcs_file, tmp_path):
    from hamgrav.io.models import load_model

    out = tmp_path / "prior.h5"
    result = runner.invoke(
        app, ["fit", str(arcs_file), "--model", "sh:2", "--prior", "shape", "-o", str(out)]
    )
    assert result.exit_code == 0, result.output
    fitted = load_model(out)
    (prior,) = fitted.model.known
    assert prior.describe()["kind"] == "mascons" and prior.label == "shape prior"
    assert np.linalg.norm(prior.mascons.centre_of_mass) < 1e-12
    assert fitted.prior["kind"] == "shape" and fitted.prior["n_mascons"] > 0


def test_fit_weighted(arcs_file, tmp_path):
    from hamgrav.io.models import load_model

    plain, weighted = tmp_path / "plain.h5", tmp_path / "weighted.h5"
    for out, extra in ((plain, []), (weighted, ["--weighted"])):
        result = runner.invoke(
            app, ["fit", str(arcs_file), "--model", "sh:2", *extra, "-o", str(out)]
        )
        assert result.exit_code == 0, result.output
    a, b = load_model(plain).solver, load_model(weighted).solver
    assert a["weighted"] is False and b["weighted"] is True
    # residuals divided by sigma ~ 1e-4 canonical: the cost grows by orders of magnitude
    assert b["initial_cost"] > 1e4 * a["initial_cost"]


def test_fit_share_weighs_one_kind_of_arcs_as_a_set(small_arcs, tmp_path):
    """--share KIND=SHARE: the arcs of that kind weigh, as a set, SHARE of the cost with no
    correction; the fit records the weights; bad values and absent kinds are refused."""
    from dataclasses import replace

    from hamgrav.core.problem import ArcProblem
    from hamgrav.io.arcs import save_arcs
    from hamgrav.io.models import load_model

    arcs = replace(small_arcs, trajectory_kind=("orbit", "orbit", "descent"))
    path = save_arcs(arcs, tmp_path / "two-kinds.h5")
    out = tmp_path / "shared.h5"
    args = ["fit", str(path), "--model", "sh:2", "-o", str(out)]
    result = runner.invoke(app, [*args, "--share", "descent=0.2"])
    assert result.exit_code == 0, result.output
    fitted = load_model(out)
    descent = arcs.trajectory == 2
    # what no correction leaves on each arc, computed apart from the CLI
    costs = ArcProblem(fitted.model, arcs).arc_costs(np.zeros(fitted.model.n_learn))
    expected = 0.2 / 0.8 * costs[~descent].sum() / costs[descent].sum()
    record = fitted.solver["arc_weights"]
    assert record["n_not_one"] == 3
    assert [record["min"], record["max"]] == pytest.approx(sorted([1.0, expected]), rel=1e-9)
    assert f"the 3 descent arcs weigh {expected:.3g} each, the other 6 arcs 1" in result.output
    for bad, message in (
        ("descent", "--share must be KIND=SHARE with SHARE in (0, 1)"),
        ("descent=1", "--share must be KIND=SHARE with SHARE in (0, 1)"),
        ("=0.2", "--share must be KIND=SHARE"),
        ("particle=0.2", "have no arcs of kind 'particle' (their kinds: descent, orbit)"),
    ):
        refused = runner.invoke(app, [*args, "--share", bad])
        assert refused.exit_code == 2, (bad, refused.output)
        assert message in " ".join(refused.output.split()), (bad, refused.output)
    # a choice by cross-validation is refused before any arc is propagated
    chosen = runner.invoke(app, [*args, "--kaula", "cv", "--share", "descent=0.2"])
    assert chosen.exit_code == 2
    assert "--share and --kaula cv do not go together" in " ".join(chosen.output.split())
    assert "arcs weigh" not in chosen.output  # no weights were formed


def test_fit_kaula_cv_and_the_truth_scan_refused(arcs_file, tmp_path):
    from hamgrav.io.models import load_model

    out = tmp_path / "kaula.h5"
    args = ["fit", str(arcs_file), "--model", "sh:3", "-o", str(out)]
    result = runner.invoke(app, [*args, "--kaula", "cv", "--folds", "3"])
    assert result.exit_code == 0, result.output
    (table,) = load_model(out).solver["selection"]
    assert table["name"] == "kaula_alpha" and table["folds"] == 3
    assert table["candidates"] == [1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 0.0]
    assert load_model(out).solver["kaula_alpha"] == table["chosen"]
    # the table is summarised: one line per candidate, the kept one marked
    assert "kaula_alpha by 3-fold cross-validation" in result.output
    assert result.output.count("<- kept") == 1
    # the truth scan is an experiments' protocol: the CLI names the option that replaces it
    scan = runner.invoke(app, [*args, "--kaula", "scan"])
    assert scan.exit_code == 2 and "choose it from the arcs with --kaula cv" in scan.output


def test_fit_resume_after_interrupt(arcs_file, tmp_path, monkeypatch):
    """An interrupted Adam fit keeps its checkpoint; --resume ends where an uninterrupted run
    ends, and removes the checkpoint."""
    from hamgrav.io import models
    from hamgrav.io.models import load_model

    args = ["fit", str(arcs_file), "--model", "network", "--hidden", "4", "--steps", "30"]
    full = tmp_path / "full.h5"
    assert runner.invoke(app, [*args, "-o", str(full)]).exit_code == 0
    out = tmp_path / "resumed.h5"
    real_save = models.save_checkpoint

    def save_then_interrupt(*args):
        real_save(*args)
        raise KeyboardInterrupt

    monkeypatch.setattr(models, "save_checkpoint", save_then_interrupt)
    result = runner.invoke(app, [*args, "-o", str(out)])
    assert result.exit_code == 130 and "--resume" in result.output
    assert models.checkpoint_path_for(out).exists() and not out.exists()
    monkeypatch.setattr(models, "save_checkpoint", real_save)
    result = runner.invoke(app, [*args, "--resume", "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert not models.checkpoint_path_for(out).exists()
    assert np.array_equal(load_model(out).params, load_model(full).params)


def test_internal_errors_are_not_user_errors(monkeypatch, arcs_file, tmp_path):
    """A bug (a plain ValueError) is reported as a bug (status 70, "please report", no
    traceback); with --debug its traceback comes back."""
    from hamgrav.fit import estimator

    def broken(*args, **kwargs):
        raise ValueError("a bug")

    monkeypatch.setattr(estimator.GravityEstimator, "fit", broken)
    args = ["fit", str(arcs_file), "--model", "sh:2", "-o", str(tmp_path / "m.h5")]
    result = runner.invoke(app, args)
    assert result.exit_code == 70
    assert "internal error (a bug in hamgrav, not in your input): ValueError: a bug" in (
        result.output
    )
    assert "Please report it" in result.output and "Traceback" not in result.output
    result = runner.invoke(app, ["--debug", *args])
    assert result.exit_code == 1 and isinstance(result.exception, ValueError)


def test_fit_strict_fails_a_fit_that_learns_nothing(point_mass_arcs, tmp_path):
    from hamgrav.io.arcs import save_arcs
    from hamgrav.io.models import load_model

    arcs = save_arcs(point_mass_arcs, tmp_path / "pm.h5")
    out = tmp_path / "m.h5"
    args = ["fit", str(arcs), "--model", "sh:2", "-o", str(out)]
    lenient = runner.invoke(app, args)
    assert lenient.exit_code == 0 and "does not clearly improve" in lenient.output
    strict = runner.invoke(app, [*args, "--strict"])
    assert strict.exit_code == 3 and "does not clearly improve" in strict.output
    solver = load_model(out).solver
    assert solver["outcome"] == "no improvement" and not solver["diagnostics"]["improved"]


def test_fit_strict_passes_a_fit_that_learns(small_arcs, tmp_path):
    from hamgrav.io.arcs import save_arcs

    arcs = save_arcs(small_arcs, tmp_path / "a.h5")
    args = ["fit", str(arcs), "--model", "sh:2", "-o", str(tmp_path / "m.h5"), "--strict"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "does not clearly improve" not in result.output


def test_fit_strict_fails_an_overfit_fit(point_mass_arcs, tmp_path):
    """The issue's failure in miniature: SH 8 on 12 arcs converges on its training arcs; the
    arcs held out by default show it, in one line each, and --strict fails it."""
    from hamgrav.io.arcs import save_arcs
    from hamgrav.io.models import load_model

    arcs = save_arcs(point_mass_arcs, tmp_path / "pm.h5")
    out = tmp_path / "m.h5"
    result = runner.invoke(app, ["fit", str(arcs), "--model", "sh:8", "-o", str(out), "--strict"])
    text = " ".join(result.output.split())
    assert result.exit_code == 3
    assert "cost on the validation arcs" in text and "does not clearly improve" in text
    assert text.count("looks overfit") == 1 and "above 10x" in text
    diagnostics = load_model(out).solver["diagnostics"]
    assert diagnostics["overfit"] and diagnostics["held_out_to_training"] > 10
    # chosen from the arcs, the degree is the lowest and the fit passes the overfit check
    auto = runner.invoke(app, ["fit", str(arcs), "--model", "sh:auto:8", "-o", str(out)])
    assert auto.exit_code == 0 and "looks overfit" not in auto.output
    assert load_model(out).model.learnable.degree == 2


def test_fit_harmonic_cv(arcs_file, tmp_path):
    from hamgrav.io.models import load_model

    out = tmp_path / "n.h5"
    args = ["fit", str(arcs_file), "--hidden", "4", "--solver", "lm", "-o", str(out)]
    result = runner.invoke(app, [*args, "--harmonic", "cv", "--folds", "2"])
    assert result.exit_code == 0, result.output
    (table,) = load_model(out).solver["selection"]
    assert table["name"] == "harmonic" and table["candidates"] == [1e-3, 1e-4, 1e-5, 1e-6]
    # the harmonic weight's own cross-validation: bands of altitude, the lowest held-out cost
    assert table["group"] == "altitude" and table["rule"] == "lowest"
    assert load_model(out).solver["harmonic"]["weight"] == table["chosen"]
    assert "harmonic by 2-fold cross-validation" in result.output
    refused = runner.invoke(app, [*args, "--harmonic", "cv", "--solver", "adam"])
    assert refused.exit_code == 2 and "--harmonic applies to networks fitted by LM" in (
        " ".join(refused.output.split())
    )
    bad = runner.invoke(app, [*args, "--model", "sh:auto:1"])
    assert bad.exit_code == 2 and "'sh:auto' / 'sh:auto:L'" in bad.output
    group = runner.invoke(app, [*args, "--harmonic", "cv", "--cv-group", "height"])
    assert group.exit_code == 2 and "--cv-group must be one of arc, trajectory, altitude" in (
        " ".join(group.output.split())
    )
    # the options are checked in the order of the help: --model before --cv-group
    both = runner.invoke(app, [*args, "--model", "sh:auto:1", "--cv-group", "height"])
    assert both.exit_code == 2 and "'sh:auto' / 'sh:auto:L'" in both.output


def test_fit_harmonic_cv_in_folds_of_arcs(arcs_file, tmp_path):
    from hamgrav.io.models import load_model

    out = tmp_path / "n.h5"
    args = ["fit", str(arcs_file), "--hidden", "4", "--solver", "lm", "-o", str(out)]
    result = runner.invoke(app, [*args, "--harmonic", "cv", "--folds", "2", "--cv-group", "arc"])
    assert result.exit_code == 0, result.output
    (table,) = load_model(out).solver["selection"]
    assert table["group"] == "arc" and table["folds"] == 2


def test_fit_strict_follows_the_diagnostics_not_the_outcome(point_mass_arcs, tmp_path, monkeypatch):
    """A fit that ends for another reason than "no improvement" (here: damping saturated)
    but does not beat no correction is still refused by --strict."""
    from dataclasses import replace

    from hamgrav.fit import lm
    from hamgrav.fit.base import Outcome
    from hamgrav.io.arcs import save_arcs
    from hamgrav.io.models import load_model

    iterate = lm.LevenbergMarquardt._iterate

    def saturated(self, *args, **kwargs):
        result = iterate(self, *args, **kwargs)
        return replace(result, outcome=Outcome.DAMPING_SATURATED, message="damping saturated")

    monkeypatch.setattr(lm.LevenbergMarquardt, "_iterate", saturated)
    arcs = save_arcs(point_mass_arcs, tmp_path / "pm.h5")
    out = tmp_path / "m.h5"
    result = runner.invoke(app, ["fit", str(arcs), "--model", "sh:2", "-o", str(out), "--strict"])
    assert result.exit_code == 3 and "does not clearly improve" in result.output
    solver = load_model(out).solver
    assert solver["outcome"] == "damping saturated" and not solver["diagnostics"]["improved"]


def test_fit_init_continues_a_model_as_a_stage(small_arcs, tmp_path):
    from hamgrav.io.arcs import save_arcs
    from hamgrav.io.models import load_model

    first = save_arcs(small_arcs.subset(range(5)), tmp_path / "first.h5")
    everything = save_arcs(small_arcs, tmp_path / "all.h5")
    stage1, stage2 = tmp_path / "s1.h5", tmp_path / "s2.h5"
    base = ["--model", "sh:3"]
    assert runner.invoke(app, ["fit", str(first), *base, "-o", str(stage1)]).exit_code == 0
    result = runner.invoke(
        app, ["fit", str(everything), *base, "--init", str(stage1), "-o", str(stage2)]
    )
    assert result.exit_code == 0, result.output
    stages = load_model(stage2).stages
    assert [s["stage"] for s in stages] == [0, 1]
    assert [s["n_arcs"] for s in stages] == [5, 9]
    assert stages[1]["warm_started"] and stages[0]["arcs_file"] == str(first)
    # each stage says what it left of no correction's cost: 5 arcs are too few to hold out
    # (checked on the training arcs), 9 hold out 2
    assert [s["checked_on"] for s in stages] == ["training arcs", "validation arcs"]
    assert [s["n_validation"] for s in stages] == [0, 2]
    assert all(s["relative_cost"] < 1 for s in stages)
    other = runner.invoke(
        app, ["fit", str(everything), "--model", "sh:2", "--init", str(stage1), "-o", str(stage2)]
    )
    assert other.exit_code == 2 and "structure" in other.output
    missing = runner.invoke(
        app, ["fit", str(everything), *base, "--init", str(tmp_path / "no.h5"), "-o", str(stage2)]
    )
    assert missing.exit_code == 2 and "--init: " in missing.output and "no.h5" in missing.output


def test_fit_default_is_network_best(arcs_file, tmp_path):
    from hamgrav.io.models import load_model

    out = tmp_path / "best.h5"
    result = runner.invoke(app, ["fit", str(arcs_file), "--hidden", "4", "-o", str(out)])
    assert result.exit_code == 0, result.output
    solver = load_model(out).solver
    assert solver["name"] == "levenberg-marquardt" and solver["damping_floor"] == 1e-8
    assert [m["init_seed"] for m in solver["members"]] == [0, 1, 2]
    assert "parameter directions constrained" in result.output


@pytest.fixture(scope="module")
def sh_model_file(tmp_path_factory):
    """A model file of a point mass plus degree-2 harmonics, without any arcs file."""
    from hamgrav.core.model import Model
    from hamgrav.core.terms import PointMass, SphericalHarmonics
    from hamgrav.fit.fitted import FittedModel
    from hamgrav.io.models import save_model

    term = SphericalHarmonics(2, 0.7)
    params = np.array([-0.06, 0.0, 0.0, 0.025, -0.01])
    fitted = FittedModel(Model((PointMass(),), term), params, "rock", 2.34, 43675.2)
    return save_model(fitted, tmp_path_factory.mktemp("model") / "sh2.h5"), fitted


FIELD_COLUMNS = [
    "x_m", "y_m", "z_m", "potential_m2_s2", "ax_m_s2", "ay_m_s2", "az_m_s2",
    "potential_central_m2_s2", "potential_known_m2_s2", "potential_correction_m2_s2",
]  # fmt: skip


def test_evaluate_points_writes_the_si_field(sh_model_file, tmp_path):
    model, fitted = sh_model_file
    points = np.array([[600.0, -80.0, 150.0], [-20.0, 0.0, 900.0], [1e4, 2e4, -3e4]])
    csv = tmp_path / "points.csv"
    rows = "\n".join(",".join(repr(float(v)) for v in p) for p in points)
    csv.write_text(f"# a comment\nx_m, y_m, z_m\n\n{rows}\n")
    out = tmp_path / "field.csv"
    # no arcs file and no truth: the model alone
    result = runner.invoke(app, ["evaluate", str(model), "--points", str(csv), "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert f"wrote the field at 3 points to {out}" in " ".join(result.output.split())
    lines = out.read_text().splitlines()
    assert lines[0].split(",") == FIELD_COLUMNS
    table = np.loadtxt(out, delimiter=",", skiprows=1)
    assert table.shape == (3, 10)
    assert np.array_equal(table[:, :3], points)
    np.testing.assert_allclose(table[:, 3], fitted.potential(points), rtol=1e-15)
    np.testing.assert_allclose(table[:, 4:7], fitted.acceleration(points), rtol=1e-15)
    np.testing.assert_allclose(table[:, 7], 2.34 / np.linalg.norm(points, axis=1), rtol=1e-14)
    assert not table[:, 8].any()  # a point-mass known part has nothing beyond GM/r
    np.testing.assert_allclose(table[:, 7:].sum(axis=1), table[:, 3], rtol=1e-13)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("1,2,3\n", "line 1: expected the header x_m,y_m,z_m, got '1,2,3'"),
        ("x_km,y_km,z_km\n1,2,3\n", "line 1: expected the header x_m,y_m,z_m"),
        ("x_m,y_m,z_m\n1,2,3\n4,5\n", "line 3: expected three finite numbers x,y,z [m]"),
        ("x_m,y_m,z_m\n1,2,abc\n", "line 2: expected three finite numbers"),
        ("x_m,y_m,z_m\n1,2,nan\n", "line 2: expected three finite numbers"),
        ("x_m,y_m,z_m\n", "holds no points"),
        ("x_m,y_m,z_m\n100,0,0\n0,0,0\n", "line 3: model"),
    ],
)
def test_evaluate_points_refuses_a_bad_file(sh_model_file, tmp_path, text, message):
    model, _ = sh_model_file
    csv = tmp_path / "p.csv"
    csv.write_text(text)
    out = tmp_path / "f.csv"
    result = runner.invoke(app, ["evaluate", str(model), "--points", str(csv), "-o", str(out)])
    assert result.exit_code == 2, result.output
    text = " ".join(result.output.split())
    assert message in text and str(csv) in text
    assert len(result.output.strip().splitlines()) == 1
    assert not out.exists()


def test_evaluate_points_option_errors(sh_model_file, tmp_path):
    model, _ = sh_model_file
    csv = tmp_path / "p.csv"
    csv.write_text("x_m,y_m,z_m\n100,0,0\n")
    result = runner.invoke(app, ["evaluate", str(model), "--points", str(csv)])
    assert result.exit_code == 2 and "needs -o FIELD.csv" in result.output
    result = runner.invoke(
        app, ["evaluate", str(model), "--points", str(csv), "--uncertainty", "-o", "f.csv"]
    )
    assert result.exit_code == 2 and "leave out --arcs, --uncertainty and --figure" in result.output
    result = runner.invoke(app, ["evaluate", str(model), "-o", str(tmp_path / "f.csv")])
    assert result.exit_code == 2 and "is the field file of --points" in result.output
    result = runner.invoke(app, ["evaluate", str(model), "--points", str(csv), "-o", str(csv)])
    assert result.exit_code == 2 and "is also the input points" in result.output


def test_evaluate_figure_needs_arcs_without_a_truth(arcs_file, small_arcs, tmp_path):
    from hamgrav.core.model import Model
    from hamgrav.core.terms import PointMass
    from hamgrav.fit.fitted import FittedModel
    from hamgrav.io.models import save_model

    training = {"arcs_file": str(arcs_file), "truth_sha256": small_arcs.truth_digest()}
    fitted = FittedModel(
        Model((PointMass(),)),
        np.zeros(0),
        small_arcs.body_name,
        small_arcs.gm_m3_s2,
        small_arcs.spin_period_s,
        body_origin_m=tuple(small_arcs.body_origin_m),
        training=training,
    )
    model = save_model(fitted, tmp_path / "pm.h5")
    png = tmp_path / "r.png"
    result = runner.invoke(app, ["evaluate", str(model), "--figure", str(png)])
    assert result.exit_code == 2
    assert "residual figures are drawn for arcs without a truth" in result.output
    assert not png.exists()


def test_fit_init_with_an_anchor_holds_the_field_where_the_new_arcs_do_not_reach(
    small_arcs, synthetic_truth, tmp_path
):
    """``--init M --anchor W``: the stage's learned field stays at the continued model's at
    the collocation points clear of the new arcs (recomputed here), where the same stage
    without the anchor moves it; the model file records the anchor, and the checkpoint's
    identity carries it (a resume under another anchor is refused)."""
    from hamgrav.core.model import evaluate_field
    from hamgrav.fit.anchor import AnchorSettings, points_clear_of
    from hamgrav.fit.estimator import GravityEstimator
    from hamgrav.fit.lm import LevenbergMarquardt
    from hamgrav.io.arcs import save_arcs
    from hamgrav.io.fit_run import prepare_fit
    from hamgrav.io.models import load_model

    first = save_arcs(small_arcs.subset(range(5)), tmp_path / "first.h5")
    everything = save_arcs(small_arcs, tmp_path / "all.h5")
    stage1, free, held = (tmp_path / f"{n}.h5" for n in ("s1", "free", "held"))
    base = ["--model", "network-best", "--hidden", "4"]
    assert runner.invoke(app, ["fit", str(first), *base, "-o", str(stage1)]).exit_code == 0
    go = ["fit", str(everything), *base, "--init", str(stage1)]
    assert runner.invoke(app, [*go, "-o", str(free)]).exit_code == 0
    anchored = [*go, "--anchor", "1e3", "--anchor-clearance-m", "200"]
    result = runner.invoke(app, [*anchored, "-o", str(held)])
    assert result.exit_code == 0, result.output
    start, after_free, after_held = (load_model(p) for p in (stage1, free, held))
    body = synthetic_truth.body
    clearance = body.units.to_length(200.0)
    est = GravityEstimator("network", hidden=(4,), body=body)
    points = points_clear_of(
        est.collocation_points(small_arcs), small_arcs.states[5:][..., :3], clearance
    )
    assert 0 < len(points) < 1500
    record = after_held.stages[-1]["anchor"]
    assert record == {"weight": 1e3, "points": len(points), "clearance": clearance}
    assert after_held.solver["anchor"] == {"weight": 1e3, "points": len(points)}
    assert "anchor" not in after_free.stages[-1]
    member = start.model.member()
    term = start.model.learnable
    for k in range(term.members):
        a0, a_free, a_held = (
            evaluate_field(member, term.split_members(m.params[: term.n_params])[k], points)[1]
            for m in (start, after_free, after_held)
        )
        size = np.abs(a0).max()
        assert np.abs(a_free - a0).max() > 0.05 * size
        assert np.abs(a_held - a0).max() < 1e-3 * size
    # the anchor is part of the fit's identity: a checkpoint of another anchor is not resumed
    prepared = [
        prepare_fit(
            GravityEstimator(
                "network", hidden=(4,), members=3, body=body, solver=LevenbergMarquardt()
            ),
            small_arcs,
            tmp_path / "x.h5",
            init=start,
            anchor=AnchorSettings(w, clearance),
        ).identity
        for w in (1e3, 1e2)
    ]
    assert prepared[0]["anchor"]["weight"] == 1e3 and prepared[0] != prepared[1]


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--anchor", "1e-4"], "--anchor holds a continued fit near the model it continues"),
        (["--anchor-on", "potential"], "--anchor-on sets the field anchor: give --anchor W"),
        (["--anchor", "0", "--init", "M"], "--anchor must be a finite number > 0, got 0.0"),
        (["--anchor", "1", "--init", "M", "--anchor-on", "geoid"], "one of acceleration, pot"),
        (["--anchor", "1", "--init", "M", "--anchor-clearance-m", "-1"], "must be a finite"),
    ],
)
def test_fit_anchor_options_are_checked_first(small_arcs, tmp_path, extra, message):
    from hamgrav.io.arcs import save_arcs

    arcs = save_arcs(small_arcs, tmp_path / "all.h5")
    extra = [str(tmp_path / "m.h5") if e == "M" else e for e in extra]
    result = runner.invoke(app, ["fit", str(arcs), "-o", str(tmp_path / "o.h5"), *extra])
    assert result.exit_code == 2 and message in result.output, result.output


def test_fit_anchor_refuses_what_it_cannot_hold_before_fitting(small_arcs, tmp_path):
    from hamgrav.io.arcs import save_arcs

    first = save_arcs(small_arcs.subset(range(5)), tmp_path / "first.h5")
    everything = save_arcs(small_arcs, tmp_path / "all.h5")
    net = ["--model", "network-best", "--hidden", "4"]
    adam = ["--model", "network", "--hidden", "4", "--steps", "3"]
    for name, model in (("net", net), ("adam", adam)):
        made = runner.invoke(app, ["fit", str(first), *model, "-o", str(tmp_path / name)])
        assert made.exit_code == 0, made.output
    cases = {
        "fit with LM (--model network-best, or --solver lm)": ("adam", adam),
        "give the harmonic penalty's weight (--harmonic W), not a choice": (
            "net",
            [*net, "--harmonic", "cv"],
        ),
        "smaller clearance (--anchor-clearance-m)": ("net", [*net, "--anchor-clearance-m", "1e7"]),
    }
    for k, (message, (init, extra)) in enumerate(cases.items()):
        out = tmp_path / f"o{k}.h5"
        go = ["fit", str(everything), "--init", str(tmp_path / init), "--anchor", "1", "-o"]
        result = runner.invoke(app, [*go, str(out), *extra])
        assert result.exit_code == 2 and message in result.output, result.output
        # refused before the fit: no progress bar, no checkpoint, no model
        assert "fitting" not in result.output and not out.exists()


def test_fit_anchor_on_the_potential_with_the_default_clearance(
    small_arcs, synthetic_truth, tmp_path
):
    from hamgrav.io.arcs import save_arcs
    from hamgrav.io.models import load_model

    first = save_arcs(small_arcs.subset(range(5)), tmp_path / "first.h5")
    everything = save_arcs(small_arcs, tmp_path / "all.h5")
    stage1, stage2 = tmp_path / "s1.h5", tmp_path / "s2.h5"
    net = ["--model", "network-best", "--hidden", "4"]
    assert runner.invoke(app, ["fit", str(first), *net, "-o", str(stage1)]).exit_code == 0
    args = ["fit", str(everything), *net, "--init", str(stage1), "--anchor", "0.5"]
    result = runner.invoke(app, [*args, "--anchor-on", "potential", "-o", str(stage2)])
    assert result.exit_code == 0, result.output
    fitted = load_model(stage2)
    anchor = fitted.stages[-1]["anchor"]
    assert anchor["quantity"] == "potential" and anchor["weight"] == 0.5
    radius = synthetic_truth.body.brillouin_radius
    assert anchor["clearance"] == pytest.approx(0.1 * radius, rel=1e-12)
    assert fitted.solver["anchor"]["quantity"] == "potential"


def test_fit_anchor_needs_arcs_that_extend_the_models_own(small_arcs, tmp_path):
    from hamgrav.io.arcs import save_arcs

    first = save_arcs(small_arcs.subset(range(5)), tmp_path / "first.h5")
    shuffled = save_arcs(small_arcs.subset([1, 0, *range(2, 9)]), tmp_path / "shuffled.h5")
    stage1 = tmp_path / "s1.h5"
    for model in (["--model", "network-best", "--hidden", "4"], ["--model", "sh:2"]):
        assert runner.invoke(app, ["fit", str(first), *model, "-o", str(stage1)]).exit_code == 0
        go = ["fit", "--init", str(stage1), "--anchor", "1", "-o", str(tmp_path / "o.h5")]
        same = runner.invoke(app, [*go, str(first), *model])
        other = runner.invoke(app, [*go, str(shuffled), *model])
        if model[1] == "sh:2":
            assert other.exit_code == 2 and "needs a network" in other.output, other.output
            continue
        assert same.exit_code == 2 and "5 arcs given, none of them new" in same.output
        assert other.exit_code == 2 and "their first 5 are not the model's" in other.output
