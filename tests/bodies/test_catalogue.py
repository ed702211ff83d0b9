import json

import numpy as np
import pytest

from hamgrav.bodies.catalogue import contact_binary, list_bodies, load_body
from hamgrav.errors import BodyDataError


def test_synthetic_body_is_closed_and_centred(synthetic):
    mesh = synthetic.mesh_m
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    assert np.allclose(mesh.center_mass, 0.0, atol=1e-6)
    # GM from the stated density and the mesh volume
    assert synthetic.gm_m3_s2 == pytest.approx(6.6743e-11 * 1900.0 * mesh.volume, rel=1e-12)
    assert synthetic.brillouin_radius_m == pytest.approx(
        np.linalg.norm(mesh.vertices, axis=1).max(), rel=1e-12
    )
    extent = mesh.bounds[1] - mesh.bounds[0]
    assert extent[0] == pytest.approx(560.0, rel=1e-3)  # the stated length along x


def test_contact_binary_parameters():
    small = contact_binary(length_m=200.0, spin_period_s=7200.0)
    assert small.mesh_m.bounds[1, 0] - small.mesh_m.bounds[0, 0] == pytest.approx(200.0, rel=1e-3)
    assert small.units.time_s == pytest.approx(7200.0 / (2 * np.pi))
    with pytest.raises(ValueError, match="head_ratio"):
        contact_binary(head_ratio=3.0)


def test_synthetic_listed_without_data(monkeypatch, tmp_path):
    monkeypatch.setenv("HAMGRAV_BODIES", str(tmp_path / "nowhere"))
    assert list_bodies() == ["synthetic"]
    with pytest.raises(BodyDataError, match=r"folder .*nowhere \(HAMGRAV_BODIES\) does not exist"):
        load_body("itokawa")


def test_surface_points_raise_radially(synthetic):
    h = 0.01
    pts = synthetic.surface_points(h)
    r0 = np.linalg.norm(synthetic.mesh.vertices, axis=1)
    assert np.allclose(np.linalg.norm(pts, axis=1), r0 + h)


@pytest.mark.bodies
def test_catalogue_bodies_load(data_folder):
    catalogue = json.loads((data_folder / "catalogue.json").read_text())
    for name, entry in catalogue.items():
        body = load_body(name)
        assert body.units.length_m == pytest.approx(entry["synchronous_radius_m"], rel=1e-9)
        assert body.brillouin_radius_m == pytest.approx(entry["brillouin_radius_m"], rel=1e-6)


@pytest.mark.bodies
@pytest.mark.parametrize(
    "name, paper", [("itokawa", 0.97), ("67p", 0.93), ("bennu", 0.84), ("eros", 0.96)]
)
def test_envelope_fraction_matches_paper(data_folder, name, paper):
    # the paper quotes 96 % Eros, 97 % Itokawa, 93 % 67P, 84 % Bennu (rounded)
    assert load_body(name).envelope_fraction_inside_brillouin() == pytest.approx(paper, abs=0.015)


def _fake_folder(tmp_path, catalogue, mesh_text=None):
    (tmp_path / "catalogue.json").write_text(catalogue)
    (tmp_path / "rock").mkdir()
    if mesh_text is not None:
        (tmp_path / "rock" / "mesh.obj").write_text(mesh_text)
    return tmp_path


GOOD_ENTRY = json.dumps(
    {"rock": {"gm_m3_s2": 1.0, "spin_period_s": 1e4, "files": {"mesh": "mesh.obj"}}}
)


def test_malformed_catalogue(monkeypatch, tmp_path):
    monkeypatch.setenv("HAMGRAV_BODIES", str(_fake_folder(tmp_path, "{not json")))
    with pytest.raises(BodyDataError, match="catalogue.json is not valid JSON"):
        load_body("rock")


def test_catalogue_entry_missing_field(monkeypatch, tmp_path):
    bad = json.dumps({"rock": {"spin_period_s": 1e4, "files": {"mesh": "mesh.obj"}}})
    monkeypatch.setenv("HAMGRAV_BODIES", str(_fake_folder(tmp_path, bad)))
    with pytest.raises(BodyDataError, match="entry 'rock' .* malformed .*gm_m3_s2"):
        load_body("rock")


def test_missing_mesh_file(monkeypatch, tmp_path):
    monkeypatch.setenv("HAMGRAV_BODIES", str(_fake_folder(tmp_path, GOOD_ENTRY)))
    with pytest.raises(BodyDataError, match="mesh file not found: .*rock/mesh.obj"):
        load_body("rock")


def test_open_mesh_rejected(monkeypatch, tmp_path):
    one_triangle = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\n"
    monkeypatch.setenv("HAMGRAV_BODIES", str(_fake_folder(tmp_path, GOOD_ENTRY, one_triangle)))
    with pytest.raises(BodyDataError, match="shape file .*rock/mesh.obj has 2 triangles"):
        load_body("rock")


@pytest.mark.bodies
def test_unknown_body(data_folder):
    with pytest.raises(BodyDataError, match="unknown body 'vesta'; known: synthetic"):
        load_body("vesta")
