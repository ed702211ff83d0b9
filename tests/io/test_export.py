"""Coefficient files (ICGEM, SHADR) and the JSON network file, read back by other code."""

import json
import math
import re
from pathlib import Path

import numpy as np
import pyshtools as pysh
import pytest

from hamgrav.core.fields import shell_points
from hamgrav.core.mascons import MasconSet
from hamgrav.core.model import Model, evaluate_field
from hamgrav.core.terms import (
    MasconTerm,
    NeuralPotential,
    PointDipole,
    PointMass,
    SphericalHarmonics,
)
from hamgrav.errors import InputError
from hamgrav.fit.fitted import FittedModel
from hamgrav.io.network_json import network_document, write_network_json
from hamgrav.io.shformats import sh_export, write_icgem, write_shadr
from hamgrav.units import CanonicalUnits

GM, PERIOD = 2.34, 43675.2
UNITS = CanonicalUnits(GM, PERIOD)
R_REF = 0.65  # canonical reference radius
README = Path(__file__).resolve().parents[2] / "README.md"


def fitted_with(known, learnable, params):
    return FittedModel(Model(known, learnable), np.asarray(params), "itokawa", GM, PERIOD)


@pytest.fixture(scope="module")
def sh_fitted():
    term = SphericalHarmonics(4, R_REF)
    params = 0.03 * np.random.default_rng(5).normal(size=term.n_params)
    return fitted_with((PointMass(),), term, params)


@pytest.fixture(scope="module")
def prior():
    rng = np.random.default_rng(8)
    pos = 0.15 * rng.normal(size=(12, 3))
    pos -= pos.mean(axis=0)
    return MasconTerm(MasconSet(pos, np.full(12, 1 / 12)), "shape prior")


def network_fitted(known, members=1, seed=2, softening=0.0):
    term = NeuralPotential((10, 8), members=members, softening=softening)
    params = term.initial_params(seed) + 0.05 * np.random.default_rng(seed).normal(
        size=term.n_params
    )
    return fitted_with(known, term, params)


def pysh_potential(coeffs: pysh.SHGravCoeffs, points_m: np.ndarray) -> np.ndarray:
    """V [m^2/s^2] at body-fixed points [m] from pyshtools' own Legendre evaluation."""
    cilm = coeffs.to_array(normalization="4pi", csphase=1)
    degrees = np.arange(cilm.shape[1])
    out = []
    for x, y, z in points_m:
        r = math.sqrt(x * x + y * y + z * z)
        lat, lon = math.degrees(math.asin(z / r)), math.degrees(math.atan2(y, x))
        scaled = cilm * ((coeffs.r0 / r) ** degrees)[None, :, None]
        out.append(coeffs.gm / r * pysh.expand.MakeGridPoint(scaled, lat, lon, norm=1, csphase=1))
    return np.array(out)


def model_potential(fitted, points, which="total"):
    return UNITS.from_potential(evaluate_field(fitted.model, fitted.params, points, which)[0])


def test_icgem_of_sh_model_read_by_pyshtools(sh_fitted, tmp_path):
    cov = np.diag(np.linspace(1e-8, 4e-8, sh_fitted.model.n_learn))
    exp = sh_export(sh_fitted, covariance=cov)
    path = write_icgem(exp, tmp_path / "sh4.gfc")
    coeffs = pysh.SHGravCoeffs.from_file(path, format="icgem", errors="formal")
    assert coeffs.lmax == 4 and coeffs.gm == GM
    assert math.isclose(coeffs.r0, R_REF * UNITS.length_m, rel_tol=1e-15)
    # the potential at 1.5 R from the centre, and on a shell, to 1e-12 relative
    pts = shell_points(1.5 * R_REF, 50, seed=3)
    v_file = pysh_potential(coeffs, UNITS.from_length(pts))
    v_model = model_potential(sh_fitted, pts)
    np.testing.assert_allclose(v_file, v_model, rtol=1e-12, atol=0)
    # the perturbing part alone (C00 = 0) is the learned SH term
    coeffs.coeffs[0, 0, 0] = 0.0
    pert = pysh_potential(coeffs, UNITS.from_length(pts))
    learned = model_potential(sh_fitted, pts, "learnable")
    assert np.max(np.abs(pert - learned)) < 1e-12 * np.max(np.abs(learned))
    # formal errors in the same normalisation: C20 is the first parameter
    assert math.isclose(coeffs.errors[0, 2, 0], 1e-4, rel_tol=1e-6)
    assert coeffs.errors[0, 0, 0] == 0.0
    text = path.read_text()
    for words in ("no Condon-Shortley phase", "central term included", "tide_free"):
        assert words in text
    assert exp.method == "exact" and max(exp.accuracy.values()) < 1e-13


def test_pyshtools_gravity_vector_is_hamgrav_acceleration(sh_fitted, tmp_path):
    path = write_icgem(sh_export(sh_fitted), tmp_path / "sh4.gfc")
    coeffs = pysh.SHGravCoeffs.from_file(path, format="icgem")
    lat, lon = 0.4, -2.0
    q = (
        1.5
        * R_REF
        * np.array([math.cos(lat) * math.cos(lon), math.cos(lat) * math.sin(lon), math.sin(lat)])
    )
    g = coeffs.expand(
        lat=math.degrees(lat), lon=math.degrees(lon), r=float(np.linalg.norm(q)) * UNITS.length_m
    )
    _, a = evaluate_field(sh_fitted.model, sh_fitted.params, q[None], "total")
    a = UNITS.from_acceleration(a[0])
    e_r = q / np.linalg.norm(q)
    e_theta = np.array(
        [math.sin(lat) * math.cos(lon), math.sin(lat) * math.sin(lon), -math.cos(lat)]
    )
    e_phi = np.array([-math.sin(lon), math.cos(lon), 0.0])
    np.testing.assert_allclose(
        g, [a @ e_r, a @ e_theta, a @ e_phi], rtol=1e-11, atol=1e-12 * np.linalg.norm(a)
    )


def test_shadr_matches_icgem(sh_fitted, tmp_path):
    cov = np.diag(np.linspace(1e-8, 4e-8, sh_fitted.model.n_learn))
    exp = sh_export(sh_fitted, covariance=cov)
    icgem = pysh.SHGravCoeffs.from_file(
        write_icgem(exp, tmp_path / "a.gfc"), format="icgem", errors="formal"
    )
    shadr = pysh.SHGravCoeffs.from_file(
        write_shadr(exp, tmp_path / "a.tab"),
        format="shtools",
        header=True,
        header_units="km",
        errors=True,
    )
    assert math.isclose(shadr.gm, GM, rel_tol=1e-15)
    assert math.isclose(shadr.r0, icgem.r0, rel_tol=1e-15)
    np.testing.assert_array_equal(shadr.coeffs, icgem.coeffs)
    np.testing.assert_allclose(shadr.errors, icgem.errors, rtol=1e-6)


def test_shape_prior_is_included_and_its_truncation_stated(prior, tmp_path):
    term = SphericalHarmonics(3, R_REF)
    fitted = fitted_with((prior,), term, 0.01 * np.ones(term.n_params))
    errors = []
    for degree in (4, 12):
        exp = sh_export(fitted, degree=degree)
        assert any("shape prior (12 mascons" in c for c in exp.contents)
        assert exp.method == "approximate" and exp.c[0, 0] == pytest.approx(1.0, abs=1e-15)
        errors.append(exp.accuracy["r1.5R"])
        coeffs = pysh.SHGravCoeffs.from_file(write_icgem(exp, tmp_path / "p.gfc"), format="icgem")
        pts = shell_points(1.5 * R_REF, 40, seed=4)
        pert = pysh_potential(coeffs, UNITS.from_length(pts)) - UNITS.from_potential(
            1 / np.linalg.norm(pts, axis=1)
        )
        truth = model_potential(fitted, pts) - UNITS.from_potential(1 / np.linalg.norm(pts, axis=1))
        # the stated accuracy is the file's (other points, same shell: same order)
        measured = np.sqrt(np.sum((pert - truth) ** 2) / np.sum(truth**2))
        assert 0.2 < measured / exp.accuracy["r1.5R"] < 5
    assert errors[1] < 0.1 * errors[0]  # the exact mascon series converges outside R


def test_network_projection_states_its_error(tmp_path):
    fitted = network_fitted((PointMass(),))
    exp = sh_export(fitted, degree=10, reference_radius=R_REF)
    assert exp.errors == "no" and exp.method == "approximate"
    assert any("projected on the sphere r = R by Gauss-Legendre" in c for c in exp.contents)
    coeffs = pysh.SHGravCoeffs.from_file(write_icgem(exp, tmp_path / "n.gfc"), format="icgem")
    pts = shell_points(R_REF, 60, seed=9)
    central = UNITS.from_potential(1 / np.linalg.norm(pts, axis=1))
    pert_file = pysh_potential(coeffs, UNITS.from_length(pts)) - central
    pert_model = model_potential(fitted, pts) - central
    measured = np.sqrt(np.sum((pert_file - pert_model) ** 2) / np.sum(pert_model**2))
    assert measured < 0.05 and 0.2 < measured / exp.accuracy["r1R"] < 5
    with pytest.raises(InputError, match="formal errors of a projected network"):
        sh_export(fitted, degree=4, reference_radius=R_REF, covariance=np.eye(3))
    with pytest.raises(InputError, match="give the degree and the reference radius"):
        sh_export(fitted)


def readme_evaluator():
    """The numpy evaluator printed in the README, executed as it stands there."""
    text = README.read_text()
    section = text.split("## Import and export", 1)[1]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    assert "def hamgrav_network_potential(" in code
    namespace: dict = {}
    exec(compile(code, "README.md", "exec"), namespace)  # noqa: S102
    return namespace["hamgrav_network_potential"]


@pytest.mark.parametrize(
    "with_prior, softening, dipole", [(False, 0.0, False), (True, 0.0, False), (False, 0.3, True)]
)
def test_json_network_evaluated_by_the_readme_function(
    prior, with_prior, softening, dipole, tmp_path
):
    known = (prior,) if with_prior else (PointMass(),)
    if dipole:  # a prior left in place brings its dipole
        known += (PointDipole((0.02, -0.01, 0.03)),)
    fitted = network_fitted(known, members=2 if with_prior else 1, softening=softening)
    path = write_network_json(fitted, tmp_path / "net.json")
    evaluate = readme_evaluator()
    pts = np.concatenate([shell_points(k, 30, seed=i) for i, k in enumerate((0.5, 0.8, 1.5))])
    v_json = evaluate(path, UNITS.from_length(pts))
    v_model = model_potential(fitted, pts)
    np.testing.assert_allclose(v_json, v_model, rtol=1e-12, atol=0)
    doc = json.loads(path.read_text())
    assert doc["network"]["layer_sizes"] == [3, 10, 8, 1]
    assert doc["units"]["length_m"] == UNITS.length_m
    assert doc["body"]["name"] == "itokawa" and doc["body"]["gm_m3_s2"] == GM
    kinds = (["mascons"] if with_prior else ["point-mass"]) + (["point-dipole"] if dipole else [])
    assert [k["kind"] for k in doc["known"]] == kinds


def test_json_refuses_sh_models(sh_fitted):
    with pytest.raises(InputError, match="export spherical harmonics with --format icgem"):
        network_document(sh_fitted)
