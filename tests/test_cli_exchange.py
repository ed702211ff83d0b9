"""The import-oem, import-spk and export commands (tracking in, coefficients and networks out)."""

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
    # the import records the body it was made with, in the files' frame
    assert arcs.body.mesh_sha256 == small_arcs.body.mesh_sha256
    assert arcs.body.origin_m == arcs.body_origin_m
    assert arcs.body.source["kind"] == "synthetic"


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


def test_evaluate_figure_plots_the_reported_residuals(imported, tmp_path, monkeypatch):
    from hamgrav.report import figures

    model = tmp_path / "sh2.h5"
    result = runner.invoke(app, ["fit", str(imported), "--model", "sh:2", "-o", str(model)])
    assert result.exit_code == 0, result.output
    drawn = []

    def keep(*args, **kwargs):
        drawn.append(real(*args, **kwargs))
        return drawn[-1]

    real = figures.residual_figure
    monkeypatch.setattr(figures, "residual_figure", keep)
    png = tmp_path / "residuals.png"
    args = ["evaluate", str(model), "--shells", "1.5", "--json", "--figure", str(png)]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    out = json.loads(result.stdout)
    assert out["figure"] == str(png)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    res = out["residuals"]
    lines = {line.get_gid(): line for ax in drawn[0].axes for line in ax.lines if line.get_gid()}
    assert len(lines) == 2 * 9 * 3  # position and velocity, 9 arcs, x y z
    for name, rms, sigma in (
        ("position", res["rms_position_m"], res["sigma_r_m"]),
        ("velocity", res["rms_velocity_mm_s"], res["sigma_v_mm_s"]),
    ):
        for a in range(9):
            y = np.stack([lines[f"{name} arc {a} {c}"].get_ydata() for c in "xyz"])
            # what is drawn, in sigmas, is what evaluate reports as the arc's RMS
            assert np.sqrt(np.mean((y * sigma) ** 2)) == pytest.approx(rms[a], rel=1e-12)
            assert len(lines[f"{name} arc {a} x"].get_xdata()) == 39  # the anchor left out
    # the figure's path is checked before any work
    result = runner.invoke(app, ["evaluate", str(model), "--figure", str(tmp_path / "d" / "x.png")])
    assert result.exit_code == 2 and "--figure: folder" in result.output


@pytest.fixture(scope="module")
def spk_file(small_arcs, synthetic, tmp_path_factory):
    from hamgrav.io.spk import write_spk

    return write_spk(small_arcs, tmp_path_factory.mktemp("spk") / "arcs.bsp", synthetic)


def test_import_spk_round_trip(spk_file, small_arcs, tmp_path):
    out = tmp_path / "arcs.h5"
    targets = ["--target", "-1000", "--target", "-1001", "--target=-1002"]
    result = runner.invoke(
        app, ["import-spk", str(spk_file), "--body", "synthetic", *targets, "-o", str(out)]
    )
    assert result.exit_code == 0, result.output
    assert "wrote 9 arcs of 40 samples of 3 targets" in " ".join(result.output.split())
    arcs = load_arcs(out)
    np.testing.assert_allclose(arcs.times, small_arcs.times, rtol=0, atol=1e-9)
    np.testing.assert_allclose(arcs.states, small_arcs.states, rtol=0, atol=1e-9)


def test_import_spk_errors_are_one_line(spk_file, tmp_path):
    import spiceypy

    out = tmp_path / "a.h5"
    ets = 9.5e8 + 60.0 * np.arange(10)
    states = np.tile([1.0, 0.0, 0.0, 0.0, 1e-4, 0.0], (10, 1))
    sun = tmp_path / "sun.bsp"
    handle = spiceypy.spkopn(str(sun), "test", 0)
    spiceypy.spkw13(handle, -77, 10, "J2000", ets[0], ets[-1], "test", 3, 10, states, ets)
    spiceypy.spkcls(handle)
    text = tmp_path / "notes.txt"
    text.write_text("not a kernel\n")
    cases = [
        ([str(spk_file), "--target", "-5"], "hold no trajectory of target -5"),
        ([str(sun), "--target", "-77", "--center", "3999999"], "not to body 'synthetic'"),
        ([str(spk_file), "--target", "-1000", "--start", "2029-01-01"], "outside the coverage"),
        ([str(text), "--target", "-1000"], "is not a SPICE kernel hamgrav reads"),
        ([str(tmp_path / "x.bsp"), "--target", "-1000"], "kernel file not found"),
        ([str(spk_file), "--target", "-1000", "--pole-ra", "3"], "give all of --pole-ra"),
    ]
    for args, message in cases:
        result = runner.invoke(app, ["import-spk", *args, "--body", "synthetic", "-o", str(out)])
        assert result.exit_code == 2, result.output
        lines = result.output.strip().splitlines()
        assert len(lines) == 1 and message in lines[0], result.output
        assert not out.exists()


def test_simulate_writes_an_spk_beside_the_arcs(tmp_path):
    toml = tmp_path / "c.toml"
    toml.write_text(
        'body = "synthetic"\ninterior = "uniform"\nn_mascons = 100\nseed = 5\n[orbits]\n'
        "families = [[1.5, 30.0], [1.9, 70.0]]\n[tracking]\narcs_per_orbit = 2\n"
        "window_spin_periods = 0.3\n"
    )
    out, spk = tmp_path / "arcs.h5", tmp_path / "arcs.bsp"
    result = runner.invoke(app, ["simulate", str(toml), "-o", str(out), "--spk", str(spk)])
    assert result.exit_code == 0, result.output
    back = tmp_path / "back.h5"
    result = runner.invoke(
        app,
        ["import-spk", str(spk), "--body", "synthetic", "--target", "-1000", "--target", "-1001"]
        + ["-o", str(back)],
    )
    assert result.exit_code == 0, result.output
    arcs, again = load_arcs(out), load_arcs(back)
    np.testing.assert_allclose(again.times, arcs.times, rtol=0, atol=1e-9)
    np.testing.assert_allclose(again.states, arcs.states, rtol=0, atol=1e-9)
    # the SPK is checked before the simulation: a folder is refused, and nothing is written
    result = runner.invoke(
        app, ["simulate", str(toml), "-o", str(tmp_path / "b.h5"), "--spk", str(tmp_path)]
    )
    assert result.exit_code == 2 and "--spk" in result.output
    assert not (tmp_path / "b.h5").exists()
