"""Arcs and model files record the body they were made with, and every command rebuilds it
from there: a body that no catalogue knows goes through simulate, fit, evaluate, export."""

import json
from dataclasses import replace

import numpy as np
import pytest
from typer.testing import CliRunner

from hamgrav.bodies.catalogue import Body, contact_binary
from hamgrav.bodies.interiors import build_truth
from hamgrav.bodies.rotation import RotationModel
from hamgrav.cli import app
from hamgrav.errors import DatasetError, InputError
from hamgrav.fit.estimator import GravityEstimator, body_for_arcs
from hamgrav.io.arcs import load_arcs, save_arcs
from hamgrav.io.models import load_model, save_model
from hamgrav.sim.tracking import OrbitFamily, TrackingConfig, simulate_orbits

runner = CliRunner()


@pytest.fixture(scope="module")
def rock():
    """A body no catalogue holds, with a rotation model and a NAIF ID."""
    body = contact_binary(name="rock-2031", length_m=420.0, head_ratio=0.55)
    return replace(
        body,
        rotation=RotationModel(40.0, -60.0, 12.5, body.spin_period_s),
        naif_id=-2031,
        source={"kind": "files", "mesh": "rock.obj", "units": "m"},
        description="a rock from files",
    )


@pytest.fixture(scope="module")
def rock_arcs_file(rock, tmp_path_factory):
    truth = build_truth(rock, "head-tail", n_mascons=80, seed=3)
    families = [OrbitFamily(1.3, 20.0), OrbitFamily(1.6, 75.0), OrbitFamily(2.0, 45.0)]
    arcs = simulate_orbits(
        truth, families, TrackingConfig(arcs_per_orbit=3, window_spin_periods=0.5), seed=5
    )
    return save_arcs(arcs, tmp_path_factory.mktemp("rock") / "arcs.h5")


@pytest.fixture
def no_catalogue(tmp_path, monkeypatch):
    """No body data folder: a lookup by name of anything but the synthetic body fails."""
    monkeypatch.setenv("HAMGRAV_BODIES", str(tmp_path / "no-bodies-here"))


def test_arcs_file_records_the_body(rock, rock_arcs_file, no_catalogue):
    arcs = load_arcs(rock_arcs_file)
    record = arcs.body
    assert record is not None and record.name == "rock-2031"
    assert record.mesh_sha256 == rock.mesh_sha256
    assert record.source == rock.source and record.naif_id == -2031
    assert record.rotation["pole_dec_deg"] == -60.0
    body = body_for_arcs(arcs)
    # the frame is the truth's centre of mass, not the mesh's origin
    assert body.origin_m == arcs.body_origin_m != (0.0, 0.0, 0.0)
    assert body.mesh_sha256 == rock.mesh_sha256
    assert body.brillouin_radius == pytest.approx(
        replace(rock, origin_m=arcs.body_origin_m).brillouin_radius, rel=1e-15
    )
    assert body.rotation == rock.rotation


def test_fit_and_model_file_record_the_body(rock, rock_arcs_file, tmp_path, no_catalogue):
    arcs = load_arcs(rock_arcs_file)
    est = GravityEstimator("sh", degree=2).fit(arcs)
    fitted = est.fitted_
    assert fitted.body.mesh_sha256 == rock.mesh_sha256
    path = save_model(fitted, tmp_path / "m.h5")
    again = load_model(path)
    assert again.body.mesh_sha256 == rock.mesh_sha256
    assert again.body.origin_m == arcs.body_origin_m
    assert Body.from_record(again.body).brillouin_radius == pytest.approx(
        body_for_arcs(arcs).brillouin_radius, rel=1e-15
    )


def test_commands_take_the_body_from_the_files(rock_arcs_file, tmp_path, no_catalogue):
    model = tmp_path / "sh3.h5"
    result = runner.invoke(app, ["fit", str(rock_arcs_file), "--model", "sh:3", "-o", str(model)])
    assert result.exit_code == 0, result.output
    result = runner.invoke(app, ["evaluate", str(model), "--shells", "1.2,1.5", "--json"])
    assert result.exit_code == 0, result.output
    errors = json.loads(result.stdout)["field_error"]
    assert errors["r1.5"] < 1.0
    icgem = tmp_path / "rock.gfc"
    result = runner.invoke(app, ["export", str(model), "--format", "icgem", "-o", str(icgem)])
    assert result.exit_code == 0, result.output
    assert icgem.is_file()
    network = tmp_path / "net.h5"
    result = runner.invoke(
        app,
        ["fit", str(rock_arcs_file), "--model", "network", "--hidden", "4", "--steps", "2"]
        + ["-o", str(network)],
    )
    assert result.exit_code == 0, result.output
    # a network is projected at the Brillouin radius of the recorded body
    result = runner.invoke(app, ["export", str(network), "--format", "icgem", "-o", str(icgem)])
    assert result.exit_code == 0, result.output
    assert load_model(network).body.mesh_sha256 == load_model(model).body.mesh_sha256


def test_body_option_must_agree_with_the_arcs(rock_arcs_file, tmp_path):
    # the synthetic body has another GM and spin period: its canonical units do not fit
    result = runner.invoke(
        app,
        ["fit", str(rock_arcs_file), "--model", "sh:2", "--body", "synthetic"]
        + ["-o", str(tmp_path / "m.h5")],
    )
    assert result.exit_code == 2
    assert "--body synthetic has GM" in result.output
    assert not (tmp_path / "m.h5").exists()


def test_estimator_body_is_checked_and_moved_into_the_arcs_frame(rock, rock_arcs_file):
    arcs = load_arcs(rock_arcs_file)
    est = GravityEstimator("sh", degree=2, body=rock)  # rock: origin at its mesh's origin
    assert est.body_of(arcs).origin_m == arcs.body_origin_m
    other = contact_binary(name="other")
    with pytest.raises(InputError, match="has GM"):
        GravityEstimator("sh", degree=2, body=other).body_of(arcs)
    # the same constants but another shape: used, and said
    bigger = replace(rock, mesh_m=rock.mesh_m.copy().apply_scale(1.01))
    with pytest.warns(Warning, match="another shape"):
        est = GravityEstimator("sh", degree=2, body=bigger)
        assert est.body_of(arcs).mesh_sha256 == bigger.mesh_sha256


def test_a_body_record_that_does_not_match_its_mesh_is_refused(rock_arcs_file, tmp_path, old_hdf5):
    path = tmp_path / "arcs.h5"
    path.write_bytes(rock_arcs_file.read_bytes())
    with old_hdf5(path) as f:
        f["body/vertices_m"][0, 0] += 1.0
    with pytest.warns(Warning, match="no hamgrav checksum"):
        with pytest.raises(DatasetError, match="does not match its recorded digest"):
            load_arcs(path)


def test_a_body_record_of_other_constants_is_refused(rock_arcs_file, tmp_path, old_hdf5):
    path = tmp_path / "arcs.h5"
    path.write_bytes(rock_arcs_file.read_bytes())
    with old_hdf5(path) as f:
        f["body"].attrs["gm_m3_s2"] = 2.0 * float(f.attrs["gm_m3_s2"])
    with pytest.warns(Warning, match="no hamgrav checksum"):
        with pytest.raises(DatasetError, match="differ from their body's"):
            load_arcs(path)


def test_arcs_without_a_body_record_are_looked_up_by_name(small_arcs, tmp_path, old_hdf5):
    """Files written before hamgrav recorded the body still load, by the body's name."""
    path = save_arcs(small_arcs, tmp_path / "arcs.h5")
    with old_hdf5(path) as f:
        del f["body"]
    with pytest.warns(Warning, match="no hamgrav checksum"):
        arcs = load_arcs(path)
    assert arcs.body is None
    body = body_for_arcs(arcs)
    assert body.name == "synthetic" and body.origin_m == arcs.body_origin_m
    assert np.isclose(body.brillouin_radius, body_for_arcs(small_arcs).brillouin_radius)


def test_a_model_of_other_constants_than_its_body_is_refused(rock_arcs_file, tmp_path, old_hdf5):
    arcs = load_arcs(rock_arcs_file)
    path = save_model(GravityEstimator("sh", degree=2).fit(arcs).fitted_, tmp_path / "m.h5")
    with old_hdf5(path) as f:
        f.attrs["spin_period_s"] = 2.0 * float(f.attrs["spin_period_s"])
    with pytest.warns(Warning, match="no hamgrav checksum"):
        with pytest.raises(DatasetError, match="differ from its recorded body's"):
            load_model(path)


def test_a_body_given_with_rounded_constants_takes_the_arcs(rock, rock_arcs_file, tmp_path):
    """A body whose GM differs from the arcs' by round-off fits in the arcs' units, and its
    model file reads back (the record carries the arcs' constants, not the body's)."""
    arcs = load_arcs(rock_arcs_file)
    close = replace(rock, gm_m3_s2=arcs.gm_m3_s2 * (1 + 1e-13))
    fitted = GravityEstimator("sh", degree=2, body=close).fit(arcs).fitted_
    assert fitted.body.gm_m3_s2 == arcs.gm_m3_s2 == fitted.gm_m3_s2
    again = load_model(save_model(fitted, tmp_path / "m.h5"))
    assert again.body.gm_m3_s2 == arcs.gm_m3_s2


def test_body_option_must_agree_with_the_model(rock_arcs_file, tmp_path):
    model = tmp_path / "m.h5"
    fit = ["fit", str(rock_arcs_file), "--model", "network", "--hidden", "4", "--steps", "2"]
    assert runner.invoke(app, [*fit, "-o", str(model)]).exit_code == 0
    out = tmp_path / "m.gfc"
    result = runner.invoke(
        app, ["export", str(model), "--format", "icgem", "--body", "synthetic", "-o", str(out)]
    )
    assert result.exit_code == 2
    assert "--body synthetic has GM" in result.output and "the model was fitted" in result.output
    assert not out.exists()
