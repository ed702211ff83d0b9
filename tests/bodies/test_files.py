"""A body from the user's files: Body.from_files, body TOML files, and their paths as names."""

from pathlib import Path

import numpy as np
import pytest

from hamgrav.bodies.catalogue import (
    G_SI,
    Body,
    check_body_name,
    contact_binary,
    list_bodies,
    load_body,
)
from hamgrav.bodies.files import read_body_toml
from hamgrav.bodies.shapes import write_icq, write_pds_plates
from hamgrav.errors import BodyDataError, InputError

SYNTHETIC = contact_binary()
DENSITY = 1900.0  # kg/m^3, the synthetic body's


@pytest.fixture
def plates_km(tmp_path):
    """The synthetic body's shape as a PDS plate table in km."""
    return write_pds_plates(tmp_path / "shape.tab", SYNTHETIC.mesh_m, units="km")


def test_from_files_keeps_the_shape_and_constants(plates_km):
    body = Body.from_files(
        plates_km,
        gm_m3_s2=SYNTHETIC.gm_m3_s2,
        spin_period_s=SYNTHETIC.spin_period_s,
        pole=(30.0, -60.0),
        prime_meridian_deg=12.0,
        units="km",
        naif_id=-1,
    )
    assert body.name == "shape" and body.naif_id == -1
    np.testing.assert_allclose(body.mesh_m.vertices, SYNTHETIC.mesh_m.vertices, atol=1e-9)
    assert body.origin_m == (0.0, 0.0, 0.0)  # the file's origin, moved later by the truth
    assert body.units.length_m == pytest.approx(SYNTHETIC.units.length_m, rel=1e-12)
    rotation = body.rotation
    assert (rotation.pole_ra_deg, rotation.pole_dec_deg, rotation.prime_meridian_deg) == (
        30.0,
        -60.0,
        12.0,
    )
    assert rotation.spin_period_s == body.spin_period_s
    assert body.source == {
        "kind": "files",
        "mesh": str(plates_km.resolve()),
        "format": "pds",
        "units": "km",
    }
    assert len(body.mesh_sha256) == 64


@pytest.mark.parametrize(
    "units, gm_scale, message",
    [
        ("m", 1.0, r"density GM / \(G V\) = 1\.9e\+12 kg/m\^3 .* set units = \"km\""),
        ("km", 1e-18, r"density .* = 1\.9e-15 kg/m\^3 .* check gm_m3_s2"),
        ("m", 1e-9 * 1e-9, r"= 1\.9e-06 kg/m\^3 .*GM is likely in km\^3/s\^2: give gm_m3_s2"),
    ],
)
def test_implausible_density_names_the_fix(plates_km, units, gm_scale, message):
    with pytest.raises(BodyDataError, match=message) as exc:
        Body.from_files(
            plates_km,
            gm_m3_s2=SYNTHETIC.gm_m3_s2 * gm_scale,
            spin_period_s=SYNTHETIC.spin_period_s,
            units=units,
        )
    assert str(plates_km) in str(exc.value) and "\n" not in str(exc.value)


def test_metres_read_as_km_names_the_fix(tmp_path):
    path = write_pds_plates(tmp_path / "shape.tab", SYNTHETIC.mesh_m, units="m")
    with pytest.raises(
        BodyDataError,
        match=r"= 1\.9e-06 kg/m\^3 .*in metres read as km \(set units = \"m\"\), or GM in km",
    ):
        Body.from_files(path, gm_m3_s2=SYNTHETIC.gm_m3_s2, spin_period_s=3e4, units="km")
    body = Body.from_files(path, gm_m3_s2=SYNTHETIC.gm_m3_s2, spin_period_s=3e4, units="m")
    assert body.gm_m3_s2 / (G_SI * body.mesh_m.volume) == pytest.approx(DENSITY, rel=1e-9)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"gm_m3_s2": 0.0}, "gm_m3_s2 must be a finite number > 0, got 0.0"),
        ({"gm_m3_s2": float("nan")}, "gm_m3_s2 must be a finite number > 0, got nan"),
        ({"spin_period_s": float("inf")}, "spin_period_s must be a finite number > 0, got inf"),
        ({"units": "mm"}, "units must be 'm' or 'km', got 'mm'"),
        ({"pole": (10.0, 95.0)}, r"declination must lie in \[-90, 90\]"),
        ({"prime_meridian_deg": 5.0}, "a prime meridian or rotation epoch needs the pole"),
        ({"fmt": "wrl"}, "shape format 'wrl'"),
    ],
)
def test_from_files_argument_errors(plates_km, kwargs, message):
    args = {"gm_m3_s2": SYNTHETIC.gm_m3_s2, "spin_period_s": 3e4, "units": "km", **kwargs}
    with pytest.raises(InputError, match=message):
        Body.from_files(plates_km, **args)


BODY_TOML = """
name = "rock"
shape = "shapes/rock.icq"
units = "km"
format = "icq"
gm_m3_s2 = {gm!r}
spin_period_s = 8136.0
naif_id = 2065803
description = "an ellipsoid"
[rotation]
pole_ra_deg = 310.0
pole_dec_deg = -84.0
prime_meridian_deg = 20.0
epoch_tdb = "2022-09-26T23:14:00"
"""

AXES_M = np.array([400.0, 300.0, 250.0])


def _ellipsoid_radius(u):
    return 1.0 / np.sqrt(np.sum((u / AXES_M) ** 2, axis=1))


def _rock_toml(folder: Path, text: str | None = None) -> Path:
    (folder / "shapes").mkdir(exist_ok=True)
    write_icq(folder / "shapes" / "rock.icq", _ellipsoid_radius, 16, units="km")
    gm = float(G_SI * 2000.0 * 4 / 3 * np.pi * AXES_M.prod())
    path = folder / "rock.toml"
    path.write_text(BODY_TOML.format(gm=gm) if text is None else text)
    return path


def test_body_toml(tmp_path):
    path = _rock_toml(tmp_path)
    body = read_body_toml(path)
    assert body.name == "rock" and body.naif_id == 2065803 and body.description == "an ellipsoid"
    assert body.spin_period_s == 8136.0 and body.rotation.epoch == "2022-09-26T23:14:00"
    assert body.rotation.prime_meridian_deg == 20.0 and body.rotation.pole_dec_deg == -84.0
    assert body.mesh_m.volume == pytest.approx(4 / 3 * np.pi * AXES_M.prod(), rel=0.01)
    assert body.source == {
        "kind": "files",
        "mesh": str((tmp_path / "shapes" / "rock.icq").resolve()),
        "format": "icq",
        "units": "km",
        "toml": str(path.resolve()),
    }


def test_a_body_toml_path_is_a_body_name(tmp_path, monkeypatch):
    path = _rock_toml(tmp_path)
    reference = read_body_toml(path)
    for spec in (str(path), path):
        assert load_body(spec).mesh_sha256 == reference.mesh_sha256
        check_body_name(spec)
    monkeypatch.chdir(tmp_path)
    assert load_body("rock.toml").mesh_sha256 == reference.mesh_sha256  # relative: the cwd
    # a file without the .toml suffix: by its path, or by its bare name when no body has it
    path.rename(tmp_path / "rock.cfg")
    assert load_body("./rock.cfg").name == "rock" and load_body("rock.cfg").name == "rock"
    check_body_name("rock.cfg")
    assert "rock" not in list_bodies() and list_bodies()[0] == "synthetic"
    with pytest.raises(BodyDataError, match="body file not found: missing.toml; give the path"):
        check_body_name("missing.toml")
    with pytest.raises(BodyDataError, match="unknown body 'vesta'.* or give a body TOML file"):
        load_body("vesta")


def _edited(text: str, old: str, new: str) -> str:
    assert old in text
    return text.replace(old, new)


GOOD = BODY_TOML.format(gm=1e-3)


@pytest.mark.parametrize(
    "text, error, message",
    [
        ("colour = 3\n" + GOOD, InputError, r"unknown key\(s\) \['colour'\]; allowed"),
        (_edited(GOOD, 'units = "km"\n', ""), InputError, "'units' is required: .*no default"),
        (_edited(GOOD, 'units = "km"', 'units = "mi"'), InputError, "'units' must be \"m\" or"),
        (_edited(GOOD, "gm_m3_s2 = 0.001\n", ""), InputError, "'gm_m3_s2' is required"),
        (_edited(GOOD, "gm_m3_s2 = 0.001", 'gm_m3_s2 = "35"'), InputError, "must be a number > 0"),
        (_edited(GOOD, "spin_period_s = 8136.0", "spin_period_s = -1"), InputError, "> 0, got -1"),
        (_edited(GOOD, "shape = ", "shape = 3 #"), InputError, "'shape' must be a string"),
        (_edited(GOOD, '"icq"', '"vrml"'), InputError, "'format' must be one of obj, ply"),
        (_edited(GOOD, "2065803", "2065803.5"), InputError, "'naif_id' must be an integer"),
        (GOOD + "spin = 3\n", InputError, r"unknown key\(s\) in \[rotation\] \['spin'\]"),
        (_edited(GOOD, "pole_dec_deg = -84.0\n", ""), InputError, r"\[rotation\] needs pole_dec"),
        (_edited(GOOD, "= 310.0", '= "north"'), InputError, "pole_ra_deg must be a number"),
        (_edited(GOOD, "rock.icq", "gone.icq"), BodyDataError, r"shape file .*gone.icq not found"),
        ("name = ", InputError, "not valid TOML"),
        # the constants are read, and the shape in km: a GM of 1e-3 m^3/s^2 is too light for it
        (GOOD, BodyDataError, r"bulk density .* is outside the plausible 100-20000 kg/m\^3"),
    ],
)
def test_body_toml_errors_name_the_file_and_key(tmp_path, text, error, message):
    path = _rock_toml(tmp_path, text)
    with pytest.raises(error, match=message) as exc:
        read_body_toml(path)
    assert str(path) in str(exc.value) and "\n" not in str(exc.value)


def test_body_toml_with_inside_out_shape(tmp_path):
    (tmp_path / "shapes").mkdir()
    mesh = SYNTHETIC.mesh_m
    flipped = type(mesh)(mesh.vertices, mesh.faces[:, ::-1], process=False)
    write_pds_plates(tmp_path / "shapes" / "rock.icq", flipped, units="km")
    path = tmp_path / "rock.toml"
    path.write_text(_edited(GOOD, 'format = "icq"', 'format = "pds"'))
    with pytest.raises(BodyDataError, match=r"rock.toml: .*rock.icq is inside out"):
        check_body_name(path)
