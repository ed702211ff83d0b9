"""The whole path of a user with their own body and tracking, through the command line, with
no catalogue (HAMGRAV_BODIES points nowhere): a shape in km as Gaskell ICQ and its constants
in a body TOML, tracking as a SPICE SPK, import-spk, fits whose model is chosen from the arcs
alone, evaluate --points and export --format icgem; only the test knows the truth."""

import csv
import json
import math

import numpy as np
import pyshtools as pysh
import pytest
from typer.testing import CliRunner

from hamgrav.bodies.catalogue import G_SI, contact_binary_radius
from hamgrav.bodies.evaluation import evaluation_sets
from hamgrav.bodies.shapes import read_shape, write_icq
from hamgrav.cli import app
from hamgrav.core.mascons import mascon_potential
from hamgrav.fit.estimator import body_for_arcs
from hamgrav.io.arcs import load_arcs
from hamgrav.io.models import load_model

runner = CliRunner()


def run(*words):
    result = runner.invoke(app, [str(w) for w in words])
    assert result.exit_code == 0, result.output
    return result


def pysh_potential(coeffs: pysh.SHGravCoeffs, points_m: np.ndarray) -> np.ndarray:
    """V [m^2/s^2] from pyshtools' reading of the file and its own Legendre functions."""
    cilm = coeffs.to_array(normalization="4pi", csphase=1)
    degrees = np.arange(cilm.shape[1])
    out = []
    for x, y, z in points_m:
        r = math.sqrt(x * x + y * y + z * z)
        lat, lon = math.degrees(math.asin(z / r)), math.degrees(math.atan2(y, x))
        scaled = cilm * ((coeffs.r0 / r) ** degrees)[None, :, None]
        out.append(coeffs.gm / r * pysh.expand.MakeGridPoint(scaled, lat, lon, norm=1, csphase=1))
    return np.array(out)


def relative(approx, truth) -> float:
    return float(np.sqrt(np.sum((approx - truth) ** 2) / np.sum(truth**2)))


@pytest.fixture(scope="module")
def user_folder(tmp_path_factory):
    """The user's files: rock/shape.icq (km), rock/body.toml, campaign.toml."""
    folder = tmp_path_factory.mktemp("user")
    (folder / "rock").mkdir()
    shape = folder / "rock" / "shape.icq"
    write_icq(shape, lambda u: contact_binary_radius(u, length_m=520.0), q=16, units="km")
    gm = float(f"{G_SI * 1900.0 * read_shape(shape, units='km').volume:.4g}")
    (folder / "rock" / "body.toml").write_text(
        'name = "rock"\nshape = "shape.icq"\nunits = "km"\n'
        f"gm_m3_s2 = {gm!r}\nspin_period_s = 43200.0\nnaif_id = 2999001\n"
        "[rotation]\npole_ra_deg = 95.0\npole_dec_deg = -67.0\nprime_meridian_deg = 10.0\n"
    )
    (folder / "campaign.toml").write_text(
        'body = "rock/body.toml"\ninterior = "uniform"\nn_mascons = 150\nseed = 3\n'
        "[orbits]\ncount = 8\nradius_rb = [1.3, 2.0]\ninclination_deg = [10, 80]\n"
        "[tracking]\narcs_per_orbit = 4\nwindow_spin_periods = 0.6\n"
    )
    return folder


def test_own_body_from_files_to_icgem(user_folder, tmp_path, monkeypatch):
    monkeypatch.setenv("HAMGRAV_BODIES", str(tmp_path / "no-catalogue"))
    monkeypatch.chdir(user_folder)
    report = json.loads(run("body", "rock/body.toml", "--json").stdout)
    assert report["name"] == "rock" and 1800 < report["bulk_density_kg_m3"] < 2000
    # the SPK's states are relative to the centre of mass: at constant density, the
    # shape's centroid, which the body report gives in the shape file's frame
    origin = ",".join(f"{v:.17g}" for v in report["constant_density_centre_m"])
    # the simulator stands in for the mission: its SPK is what the user receives
    run("simulate", "campaign.toml", "-o", tmp_path / "sim.h5", "--spk", tmp_path / "rock.bsp")
    simulated = load_arcs(tmp_path / "sim.h5")
    sigma_v = simulated.sigma_v_m_s
    imported = run(
        "import-spk", tmp_path / "rock.bsp", "--body", "rock/body.toml", "--target", "all",
        "--sigma-r", "0.05", "--sigma-v", repr(sigma_v), "--origin", origin,
        "-o", tmp_path / "arcs.h5",
    )  # fmt: skip
    assert "of 8 targets" in " ".join(imported.output.split())  # --target all: every orbit
    arcs = load_arcs(tmp_path / "arcs.h5")
    assert not arcs.has_truth and arcs.n_arcs == simulated.n_arcs
    assert arcs.body.source["kind"] == "files" and arcs.body.source["units"] == "km"
    fit_sh = run(
        "fit", tmp_path / "arcs.h5", "--model", "sh:auto:6", "--kaula", "cv", "-o",
        tmp_path / "sh.h5",
    )  # fmt: skip
    assert "cross-validation" in fit_sh.output
    run(
        "fit", tmp_path / "arcs.h5", "--model", "network-best", "--hidden", "8", "-o",
        tmp_path / "net.h5",
    )  # fmt: skip

    # only the test knows the truth: the simulated arcs' mascons, at the same coordinates
    # (the states are relative to the truth's centre of mass, which the centroid the user
    # gave as origin misses by round-off of the truth's compression)
    body = body_for_arcs(simulated)
    assert math.dist(body.origin_m, arcs.body_origin_m) < 0.5
    units = body.units
    sets = evaluation_sets(body, (1.1, 1.5), (30.0,), seed=1)

    def truth_perturbing(points):  # canonical points -> [m^2/s^2]
        v = mascon_potential(simulated.truth, points) - 1.0 / np.linalg.norm(points, axis=1)
        return units.from_potential(v)

    # evaluate --points: the network's field in SI at points in metres, no truth, no arcs
    for name, points in sets.items():
        points_m = points * units.length_m
        table = tmp_path / f"{name}.csv"
        table.write_text(
            "x_m,y_m,z_m\n" + "".join(f"{x:.17g},{y:.17g},{z:.17g}\n" for x, y, z in points_m)
        )
        run("evaluate", tmp_path / "net.h5", "--points", table, "-o", tmp_path / f"{name}-v.csv")
        with open(tmp_path / f"{name}-v.csv") as fh:
            rows = list(csv.DictReader(fh))
        total = np.array([float(r["potential_m2_s2"]) for r in rows])
        central = np.array([float(r["potential_central_m2_s2"]) for r in rows])
        error = relative(total - central, truth_perturbing(points))
        assert error < 1.0, (name, error)  # beats no correction, inside R_B too

    # export: the SH model's whole potential as ICGEM, read by pyshtools, against the truth
    run("export", tmp_path / "sh.h5", "--format", "icgem", "-o", tmp_path / "rock.gfc")
    coeffs = pysh.SHGravCoeffs.from_file(tmp_path / "rock.gfc", format="icgem", errors="formal")
    fitted = load_model(tmp_path / "sh.h5")
    assert coeffs.gm == pytest.approx(fitted.gm_m3_s2, rel=1e-12)
    assert fitted.body.mesh_sha256 == arcs.body.mesh_sha256
    for name in ("r1.1", "r1.5"):  # an SH series holds outside the Brillouin sphere
        points_m = sets[name] * units.length_m
        v = pysh_potential(coeffs, points_m) - coeffs.gm / np.linalg.norm(points_m, axis=1)
        error = relative(v, truth_perturbing(sets[name]))
        assert error < 1.0, (name, error)
