"""The import-oem and export commands (tracking in, coefficients and networks out)."""

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from hamgrav.cli import app
from hamgrav.io.arcs import load_arcs
from hamgrav.io.oem import export_oem_by_trajectory

runner = CliRunner()


@pytest.fixture(scope="module")
def oem_files(small_arcs, tmp_path_factory):
    return export_oem_by_trajectory(small_arcs, tmp_path_factory.mktemp("oem"))


@pytest.fixture(scope="module")
def imported(oem_files, tmp_path_factory):
    out = tmp_path_factory.mktemp("imported") / "arcs.h5"
    result = runner.invoke(
        app, ["import-oem", *map(str, oem_files), "--body", "synthetic", "-o", str(out)]
    )
    assert result.exit_code == 0, result.output
    assert "wrote 9 arcs of 40 samples from 3 files" in " ".join(result.output.split())
    return out


def test_import_oem_round_trip(imported, small_arcs):
    arcs = load_arcs(imported)
    np.testing.assert_allclose(arcs.times, small_arcs.times, rtol=0, atol=1e-9)
    np.testing.assert_allclose(arcs.states, small_arcs.states, rtol=0, atol=1e-9)


def test_fit_and_evaluate_without_truth(imported, tmp_path):
    model = tmp_path / "sh2.h5"
    result = runner.invoke(app, ["fit", str(imported), "--model", "sh:2", "-o", str(model)])
    assert result.exit_code == 0, result.output
    result = runner.invoke(app, ["evaluate", str(model), "--shells", "1.5", "--json"])
    assert result.exit_code == 0, result.output
    out = json.loads(result.stdout)
    assert out["field_error"] is None and "need simulated arcs" in out["note"]
    res = out["residuals"]
    assert len(res["rms_position_m"]) == 9 and res["sigma_r_m"] == 0.05
    assert res["chi2_per_dof"] < 0.2 * res["chi2_per_dof_no_correction"]
    assert set(out["field"]) == {"r1.5", "h30m"}
    assert out["field"]["r1.5"]["rms_learnable_potential_m2_s2"] > 0
    result = runner.invoke(app, ["evaluate", str(model), "--shells", "1.5"])
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    assert "RMS position residual [m]" in text and "relative field errors need simulated" in text


def test_import_oem_errors_are_one_line(oem_files, tmp_path):
    out = tmp_path / "a.h5"
    result = runner.invoke(
        app,
        ["import-oem", str(oem_files[0]), "--body", "synthetic", "-o", str(out), "--pole-ra", "3"],
    )
    assert result.exit_code == 2
    assert "give all of --pole-ra, --pole-dec and --prime-meridian" in result.output
    result = runner.invoke(
        app, ["import-oem", str(tmp_path / "x.oem"), "--body", "synthetic", "-o", str(out)]
    )
    assert result.exit_code == 2 and "OEM file not found" in result.output
    assert not out.exists()


def test_export_sh4_fit_to_icgem_read_by_pyshtools(imported, tmp_path):
    """The issue's contract: an SH 4 fit exported to ICGEM gives, through pyshtools, the
    same potential 1.5 R_B from the centre to 1e-12."""
    import math

    import pyshtools as pysh

    from hamgrav.core.model import evaluate_field
    from hamgrav.io.models import load_model
    from hamgrav.units import CanonicalUnits

    model = tmp_path / "sh4.h5"
    result = runner.invoke(app, ["fit", str(imported), "--model", "sh:4", "-o", str(model)])
    assert result.exit_code == 0, result.output
    gfc = tmp_path / "sh4.gfc"
    result = runner.invoke(app, ["export", str(model), "--format", "icgem", "-o", str(gfc)])
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    assert "C00 = 1 (central term included), formal errors from" in text
    coeffs = pysh.SHGravCoeffs.from_file(gfc, format="icgem", errors="formal")
    fitted = load_model(model)
    units = CanonicalUnits(fitted.gm_m3_s2, fitted.spin_period_s)
    r_b = fitted.model.learnable.reference_radius  # the Brillouin radius
    assert math.isclose(coeffs.r0, units.from_length(r_b), rel_tol=1e-15)
    lat, lon = 0.35, 2.2
    q = (
        1.5
        * r_b
        * np.array([math.cos(lat) * math.cos(lon), math.cos(lat) * math.sin(lon), math.sin(lat)])
    )
    v_model = float(
        units.from_potential(evaluate_field(fitted.model, fitted.params, q, "total")[0][0])
    )
    r_m = float(units.from_length(1.5 * r_b))
    cilm = coeffs.to_array(normalization="4pi", csphase=1)
    scaled = cilm * ((coeffs.r0 / r_m) ** np.arange(5))[None, :, None]
    v_file = (
        coeffs.gm
        / r_m
        * pysh.expand.MakeGridPoint(scaled, math.degrees(lat), math.degrees(lon), norm=1, csphase=1)
    )
    assert abs(v_file - v_model) <= 1e-12 * abs(v_model)
    assert np.all(coeffs.errors[:, 2:, :][coeffs.coeffs[:, 2:, :] != 0] > 0)  # formal errors


def test_export_refusals_are_one_line(imported, tmp_path):
    model = tmp_path / "sh2.h5"
    assert (
        runner.invoke(app, ["fit", str(imported), "--model", "sh:2", "-o", str(model)]).exit_code
        == 0
    )
    result = runner.invoke(
        app, ["export", str(model), "--format", "json", "-o", str(tmp_path / "x.json")]
    )
    text = " ".join(result.output.split())
    assert result.exit_code == 2 and "export spherical harmonics with --format icgem" in text
    assert "learnable term is SH degree 2;" in text  # the model, not an internal key
    result = runner.invoke(
        app, ["export", str(model), "--format", "gfc", "-o", str(tmp_path / "x")]
    )
    assert result.exit_code == 2 and "--format must be icgem, shadr or json" in result.output
    result = runner.invoke(
        app,
        ["export", str(model), "--format", "shadr", "--no-errors", "-o", str(tmp_path / "x.tab")],
    )
    assert result.exit_code == 0 and "no formal errors (--no-errors)" in " ".join(
        result.output.split()
    )


def test_imported_arcs_choose_the_model_without_a_truth(imported, tmp_path):
    """Imported tracking has no truth: --kaula cv and --model sh:auto choose from the arcs;
    the truth scan is refused, naming the option that replaces it."""
    from hamgrav.io.models import load_model

    assert not load_arcs(imported).has_truth
    model = tmp_path / "m.h5"
    args = ["fit", str(imported), "-o", str(model), "--folds", "3"]
    result = runner.invoke(app, [*args, "--model", "sh:auto:3", "--kaula", "cv"])
    assert result.exit_code == 0, result.output
    degree, alpha = load_model(model).solver["selection"]
    assert degree["candidates"] == [2, 3] and degree["chosen"] in (2, 3)
    assert alpha["candidates"][0] == 1e-4 and alpha["candidates"][-1] == 0.0
    assert load_model(model).model.learnable.degree == degree["chosen"]
    refused = runner.invoke(app, [*args, "--model", "sh:3", "--kaula", "scan"])
    assert refused.exit_code == 2
    assert "choose it from the arcs with --kaula cv" in " ".join(refused.output.split())


def test_evaluate_sigma(imported, arcs_with_truth, tmp_path):
    model = tmp_path / "sh3.h5"
    result = runner.invoke(app, ["fit", str(imported), "--model", "sh:3", "-o", str(model)])
    assert result.exit_code == 0, result.output
    result = runner.invoke(app, ["evaluate", str(model), "--shells", "1.5", "--sigma", "--json"])
    assert result.exit_code == 0, result.output
    u = json.loads(result.stdout)["uncertainty"]["r1.5"]
    assert u["rms_sigma_v_m2_s2"] > 0 and "rms_z" not in u  # no truth: no calibration
    result = runner.invoke(
        app,
        ["evaluate", str(model), "--arcs", str(arcs_with_truth), "--shells", "1.5", "--sigma"],
    )
    assert result.exit_code == 0, result.output
    assert "RMS error / sigma_V" in " ".join(result.output.split())


def test_evaluate_uncertainty_of_a_network(imported, arcs_with_truth, tmp_path):
    model = tmp_path / "net.h5"
    args = ["fit", str(imported), "--model", "network", "--hidden", "4", "--solver", "lm"]
    result = runner.invoke(app, [*args, "-o", str(model)])
    assert result.exit_code == 0, result.output
    result = runner.invoke(
        app, ["evaluate", str(model), "--shells", "1.5", "--uncertainty", "--json"]
    )
    assert result.exit_code == 0, result.output
    u = json.loads(result.stdout)["uncertainty"]
    assert u["covariance"]["members"] == 1 and u["covariance"]["parameters_per_member"] == 21
    assert 0 < u["covariance"]["ranks"][0] <= 21
    assert u["r1.5"]["rms_sigma_v_m2_s2"] > 0
    result = runner.invoke(
        app, ["evaluate", str(model), "--arcs", str(arcs_with_truth), "--shells", "1.5", "--sigma"]
    )
    assert result.exit_code == 0, result.output
    out = " ".join(result.output.split())
    assert "1 / 2 sigma" in out and "parameter directions constrained" in out


@pytest.fixture(scope="module")
def arcs_with_truth(small_arcs, tmp_path_factory):
    from hamgrav.io.arcs import save_arcs

    return save_arcs(small_arcs, tmp_path_factory.mktemp("truth") / "arcs.h5")
