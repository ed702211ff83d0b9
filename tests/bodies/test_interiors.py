import numpy as np
import pytest

from hamgrav.bodies.interiors import INTERIORS, build_truth, head_lobe_mask, volume_samples
from hamgrav.bodies.polyhedron import polyhedron_potential
from hamgrav.core.fields import relative_field_error, shell_points
from hamgrav.core.geometry import points_inside
from hamgrav.core.mascons import mascon_potential
from hamgrav.errors import InputError


@pytest.mark.parametrize("interior", INTERIORS)
def test_total_mass_is_one_and_centred(synthetic, interior):
    truth = build_truth(synthetic, interior, n_mascons=150, seed=2)
    assert truth.mascons.total_mass == pytest.approx(1.0, abs=1e-12)
    assert np.allclose(truth.mascons.centre_of_mass, 0.0, atol=1e-12)
    assert np.all(truth.mascons.masses > 0)
    # the body moved with the mascons: every mascon is inside the recentred shape
    assert points_inside(np.asarray(truth.body.mesh.triangles), truth.mascons.positions).all()


def test_not_recentred_keeps_mesh_frame(synthetic):
    truth = build_truth(synthetic, "head-tail", n_mascons=100, recentre=False)
    assert np.linalg.norm(truth.mascons.centre_of_mass) > 0.05  # the head pulls it along x
    assert truth.body.origin_m == (0.0, 0.0, 0.0)


def test_shape_frame_keeps_the_centre_of_mass_offset(synthetic):
    com = build_truth(synthetic, "head-tail", n_mascons=100)
    shape = build_truth(synthetic, "head-tail", n_mascons=100, frame="shape")
    # origin at the shape's constant-density centroid, where imaging would put it ...
    assert np.allclose(shape.body.constant_density_centre_of_mass, 0.0, atol=1e-9)
    # ... so the denser head pulls the centre of mass off the origin, as far as the two
    # frames' origins are apart
    offset = np.asarray(shape.parameters["recentred_by"]) - com.parameters["recentred_by"]
    assert np.linalg.norm(shape.mascons.centre_of_mass) > 0.05
    assert np.allclose(shape.mascons.centre_of_mass, -offset, atol=1e-12)
    with pytest.raises(InputError, match="unknown frame 'barycentre'"):
        build_truth(synthetic, "uniform", n_mascons=10, frame="barycentre")


def test_volume_samples_fill_the_shape(synthetic):
    pts = volume_samples(synthetic, 50_000)
    pitch = (synthetic.volume / 50_000) ** (1 / 3)
    assert len(pts) * pitch**3 == pytest.approx(synthetic.volume, rel=0.01)
    assert np.allclose(pts.mean(axis=0), synthetic.constant_density_centre_of_mass, atol=pitch / 5)


def test_head_tail_contrast(synthetic):
    # as many mascons as volume samples: every sample is its own mascon, densities visible
    from hamgrav.bodies.interiors import volume_samples

    n = len(volume_samples(synthetic, 4000))
    truth = build_truth(synthetic, "head-tail", n_mascons=n, samples=4000, recentre=False)
    assert len(truth.mascons) == n
    masses = truth.mascons.masses
    light, heavy = masses.min(), masses.max()
    assert heavy / light == pytest.approx(2.0, rel=1e-12)
    is_head = np.isclose(masses, heavy)
    assert np.all(is_head | np.isclose(masses, light))
    assert 0.1 < is_head.mean() < 0.5  # the smaller lobe
    x = truth.mascons.positions[:, 0]
    assert x[is_head].min() > x[~is_head].max() - 0.05  # beyond the neck, at +x


def test_void_fraction(synthetic):
    truth = build_truth(synthetic, "void", n_mascons=300, void_fraction=0.18, seed=4)
    assert truth.parameters["void_fraction"] == pytest.approx(0.18, abs=1e-4)
    centre = np.asarray(truth.parameters["void_centre"])
    assert np.linalg.norm(centre) > 0.05  # off-centre
    # no mascon sits deep in the void: the nearest one is about a void radius away
    void_radius = (0.18 * synthetic.volume * 3 / (4 * np.pi)) ** (1 / 3)
    com_shift = np.asarray(truth.parameters["recentred_by"])
    d = np.linalg.norm(truth.mascons.positions - (centre - com_shift), axis=1)
    assert d.min() > 0.5 * void_radius


def test_anomalies(synthetic):
    truth = build_truth(synthetic, "anomalies", n_mascons=200, seed=5, recentre=False)
    anomalies = np.asarray(truth.parameters["anomaly_positions"])
    assert anomalies.shape == (4, 3)
    masses = truth.mascons.masses[-4:]
    assert np.allclose(masses, 0.015)
    assert truth.mascons.masses[:-4].sum() == pytest.approx(0.94, abs=1e-12)
    # each at 0.85 of the local surface radius along its direction
    origins = np.zeros_like(anomalies)
    dirs = anomalies / np.linalg.norm(anomalies, axis=1, keepdims=True)
    loc, idx, _ = truth.body.mesh.ray.intersects_location(origins, dirs)
    for k in range(4):
        r_surface = np.linalg.norm(loc[idx == k], axis=1).max()
        assert np.linalg.norm(anomalies[k]) == pytest.approx(0.85 * r_surface, rel=1e-9)


def test_bad_interior_named(synthetic):
    with pytest.raises(ValueError, match="unknown interior 'marble'; choose one of uniform"):
        build_truth(synthetic, "marble")


@pytest.mark.bodies
def test_itokawa_head_from_reference(itokawa):
    """Itokawa's head lobe is the denser region of the shared head/tail reference mascons."""
    truth = build_truth(itokawa, "head-tail", n_mascons=300, samples=40_000)
    assert truth.parameters["head_definition"].startswith("reference file")
    # the reference head holds about 19 % of the volume, on the +x side
    assert truth.parameters["head_volume_fraction"] == pytest.approx(0.188, abs=0.01)
    assert truth.parameters["recentred_by"][0] > 0


def test_neck_split_finds_synthetic_head():
    from hamgrav.bodies.catalogue import contact_binary

    body = contact_binary(head_ratio=0.6)
    pts = volume_samples(body, 20_000)
    head = head_lobe_mask(pts)
    assert pts[head, 0].mean() > 0 > pts[~head, 0].mean()
    assert 0.1 < head.mean() < 0.4


@pytest.mark.bodies
@pytest.mark.parametrize("name", ["itokawa", "67p"])
def test_uniform_truth_matches_polyhedron(data_folder, name):
    from hamgrav.bodies.catalogue import load_body

    truth = build_truth(load_body(name), "uniform")  # default mascon count
    pts = shell_points(1.05 * truth.body.brillouin_radius, 400, seed=3)
    v_poly = polyhedron_potential(truth.body, pts)
    v_masc = mascon_potential(truth.mascons, pts)
    central = 1 / np.linalg.norm(pts, axis=1)
    assert relative_field_error(v_masc, v_poly) < 0.01
    # stricter: the perturbing part alone is within 1 % too
    assert relative_field_error(v_masc - central, v_poly - central) < 0.01


def test_polyhedron_sign_and_scale(synthetic):
    pts = shell_points(50 * synthetic.brillouin_radius, 10)
    v = polyhedron_potential(synthetic, pts)
    assert np.allclose(v * np.linalg.norm(pts, axis=1), 1.0, atol=1e-3)


def test_the_centred_shape_prior_is_fitted_once_per_body_and_seed(synthetic, monkeypatch):
    from hamgrav.bodies import shape_prior

    calls = []
    real = shape_prior.fit_shape_prior

    def counted(*args, **kwargs):
        calls.append(kwargs.get("seed"))
        return real(*args, **kwargs, samples=5_000)

    monkeypatch.setattr(shape_prior, "fit_shape_prior", counted)
    monkeypatch.setattr(shape_prior, "_CENTRED_PRIORS", {})
    first, report = shape_prior.centred_shape_prior(synthetic, 20, seed=4)
    again, _ = shape_prior.centred_shape_prior(synthetic, 20, seed=4)
    assert calls == [4] and again is first
    report["n_mascons"] = -1  # the caller's copy of the report, not the cache's
    assert shape_prior.centred_shape_prior(synthetic, 20, seed=4)[1]["n_mascons"] > 0
    shape_prior.centred_shape_prior(synthetic, 20, seed=5)
    assert calls == [4, 5]


def test_campaign_frame_and_contrast_reach_the_truth():
    from hamgrav.sim.campaign import Campaign, build_campaign_truth

    data = {"body": "synthetic", "interior": "head-tail", "n_mascons": 50, "orbits": {"count": 1}}
    truth = build_campaign_truth(Campaign.from_dict({**data, "contrast": 1.5, "frame": "shape"}))
    assert truth.parameters["contrast"] == 1.5 and truth.parameters["frame"] == "shape"
    assert build_campaign_truth(Campaign.from_dict(data)).parameters["contrast"] == 2.0


def test_void_gives_every_mascon_asked_for(synthetic):
    # a cavity empties 18 % of the volume samples: asking for more mascons than the samples
    # it leaves used to return that many mascons without a word
    from hamgrav.bodies.interiors import volume_samples

    samples = 2000
    left = int(round(0.82 * len(volume_samples(synthetic, samples))))
    truth = build_truth(synthetic, "void", n_mascons=left + 200, samples=samples, seed=4)
    assert len(truth.mascons) == left + 200
    assert truth.parameters["volume_samples"] > samples
    assert truth.mascons.masses.sum() == pytest.approx(1.0, rel=1e-12)


def test_the_shape_prior_is_fitted_inside_the_brillouin_sphere_too(synthetic):
    """The close points of the prior's fit carry its accuracy into the close-proximity space
    (checked against the exact polyhedron 0.05 R_B above the surface, inside R_B, where an
    exterior-only fit is free to err)."""
    from hamgrav.bodies.evaluation import deep_set
    from hamgrav.bodies.shape_prior import fit_shape_prior

    centred = synthetic.recentred(synthetic.constant_density_centre_of_mass)
    deep = deep_set(centred, 0.05 * centred.brillouin_radius_m, 0)
    assert len(deep) > 50
    v_poly = polyhedron_potential(centred, deep)
    central = 1.0 / np.linalg.norm(deep, axis=1)
    errors = {}
    for n_close in (0, None):
        prior, report = fit_shape_prior(synthetic, 60, n_close_points=n_close, samples=20_000)
        prior = prior.translated(-synthetic.constant_density_centre_of_mass)
        v_prior = mascon_potential(prior, deep)
        errors[n_close] = relative_field_error(v_prior - central, v_poly - central)
        assert report["perturbing_error_r1.05"] < 0.01
        # the far field pays for the close points, but stays a small fraction of a percent
        assert report["perturbing_error_r1.5"] < 0.003
    assert errors[None] < 0.5 * errors[0], errors
    assert report["perturbing_error_close"] < 2 * errors[None]
