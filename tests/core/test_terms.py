import heyoka as hy
import numpy as np
import pytest

from hamgrav.core.fields import perturbing_potential, relative_field_error, shell_points
from hamgrav.core.hamiltonian import POSITION
from hamgrav.core.mascons import MasconSet
from hamgrav.core.model import Model, evaluate_field, parameter_rate_function
from hamgrav.core.terms import (
    NeuralPotential,
    PointMass,
    SolarRadiationPressure,
    SphericalHarmonics,
    _normalised_legendre,
    position_derivatives,
    sh_coefficients_of_mascons,
    sh_index,
)


@pytest.fixture(scope="module")
def cluster():
    rng = np.random.default_rng(0)
    pos = rng.normal(size=(60, 3)) * [0.3, 0.15, 0.1]
    mass = rng.uniform(0.5, 1.0, 60)
    pos -= mass @ pos / mass.sum()
    return MasconSet(pos, mass / mass.sum())


def test_parameter_counts():
    assert NeuralPotential((24, 24)).n_params == 721
    assert NeuralPotential((16, 16)).n_params == 353
    assert NeuralPotential((16,)).n_params == 3 * 16 + 16 + 16 + 1
    assert [SphericalHarmonics(L, 1.0).n_params for L in (4, 8, 12, 16)] == [21, 77, 165, 285]
    assert len(sh_index(8)) == 77


def test_network_initialisation_seeded():
    nn = NeuralPotential((16, 16))
    a, b = nn.initial_params(1), nn.initial_params(1)
    assert np.array_equal(a, b) and not np.array_equal(a, nn.initial_params(2))
    assert np.all(a[nn.n_weights :] == 0.0)  # biases start at zero
    # Glorot-uniform bound of the first layer: sqrt(6 / (3 + 16))
    assert np.abs(a[:48]).max() <= np.sqrt(6 / 19)


def test_network_layout_matches_numpy():
    nn = NeuralPotential((5, 4), scale=0.1)
    theta = np.random.default_rng(3).normal(size=nn.n_params)
    model = Model((PointMass(),), nn)
    pts = np.array([[1.1, -0.4, 0.3], [0.2, 0.9, -1.5]])
    v, _ = evaluate_field(model, theta, pts)
    # the documented layout, by hand
    w1 = theta[:15].reshape(5, 3)
    w2 = theta[15:35].reshape(4, 5)
    w3 = theta[35:39].reshape(1, 4)
    b1, b2, b3 = theta[39:44], theta[44:48], theta[48:49]
    out = (w3 @ np.tanh(w2 @ np.tanh(w1 @ pts.T + b1[:, None]) + b2[:, None]) + b3[:, None])[0]
    r = np.linalg.norm(pts, axis=1)
    assert np.allclose(v, 0.1 * out / r**3, rtol=1e-13)


def test_ensemble_is_the_mean_of_its_members():
    from hamgrav.core.terms import term_from_description

    ens = NeuralPotential((5, 4), members=3)
    one = ens.member()
    assert ens.n_params == 3 * one.n_params and ens.member_params == one.n_params
    theta = np.random.default_rng(4).normal(size=ens.n_params)
    blocks = ens.split_members(theta)
    pts = np.array([[1.1, -0.4, 0.3], [0.2, 0.9, -1.5], [-2.0, 0.1, 0.4]])
    v, a = evaluate_field(Model((PointMass(),), ens), theta, pts)
    each = [evaluate_field(Model((PointMass(),), one), b, pts) for b in blocks]
    assert np.allclose(v, np.mean([e[0] for e in each], axis=0), rtol=1e-13)
    assert np.allclose(a, np.mean([e[1] for e in each], axis=0), rtol=1e-13)
    # member k starts where a single network seeded seed + k starts
    init = ens.initial_params(5)
    assert all(
        np.array_equal(b, one.initial_params(5 + k)) for k, b in enumerate(ens.split_members(init))
    )
    assert ens.key() != one.key() and term_from_description(ens.describe()) == ens
    with pytest.raises(ValueError, match="at least one member"):
        NeuralPotential((4,), members=0)


def test_network_potential_decays_as_r_cubed():
    nn = NeuralPotential((16, 16))
    theta = nn.initial_params(5)
    theta[-1] = 0.3
    model = Model((PointMass(),), nn)
    d = shell_points(1.0, 20, seed=1)
    v1, _ = evaluate_field(model, theta, 1e6 * d)
    v2, _ = evaluate_field(model, theta, 2e6 * d)
    assert np.allclose(v2 / v1, 1 / 8, rtol=1e-3)


def test_softened_envelope_matches_numpy_and_caps_the_amplification():
    from hamgrav.core.terms import term_from_description

    soft = NeuralPotential((5, 4), scale=0.1, envelope_radius=1.2, softening=0.4)
    theta = np.random.default_rng(7).normal(size=soft.n_params)
    pts = np.array([[1.1, -0.4, 0.3], [0.02, 0.01, -0.03], [-2.0, 0.1, 0.4]])
    v, a = evaluate_field(Model((PointMass(),), soft), theta, pts)
    plain = NeuralPotential((5, 4), scale=0.1, envelope_radius=1.2)
    v0, _ = evaluate_field(Model((PointMass(),), plain), theta, pts)
    r2 = np.sum(pts * pts, axis=1)
    # the same network (v: the learned term's potential): only the envelope differs,
    # (R_w / r)^3 against R_w^3 / rho^3
    nn = v0 * r2**1.5 / (0.1 * 1.2**3)
    assert np.allclose(v, 0.1 * 1.2**3 * nn / (r2 + 0.16) ** 1.5, rtol=1e-12)
    # the acceleration is the gradient of the softened potential (central differences)
    h = 1e-6
    for k in range(3):
        step = np.zeros(3)
        step[k] = h
        vp, _ = evaluate_field(Model((PointMass(),), soft), theta, pts + step)
        vm, _ = evaluate_field(Model((PointMass(),), soft), theta, pts - step)
        assert np.allclose(a[:, k], (vp - vm) / (2 * h), rtol=1e-6, atol=1e-9)
    # near the centre the envelope stays below (R_w / r_c)^3; far out it is (R_w / r)^3
    assert soft.envelope_distance(pts[1:2])[0] * 1.2 == pytest.approx(np.sqrt(r2[1] + 0.16))
    assert np.allclose(soft.envelope_distance(1e4 * pts), plain.envelope_distance(1e4 * pts))
    assert soft.key() != plain.key() and "envelope_softening" not in plain.describe()
    assert term_from_description(soft.describe()) == soft
    assert soft.member().softening == 0.4
    assert soft.export_json(theta)["envelope_softening"] == 0.4
    with pytest.raises(ValueError, match="softening"):
        NeuralPotential((4,), softening=-0.1)


def test_legendre_normalisation_matches_pyshtools():
    import pyshtools

    for t in (-0.9, -0.2, 0.0, 0.35, 0.99):
        ours = _normalised_legendre(12, np.array([t]))[:, :, 0]
        ref = pyshtools.legendre.PlmBar(12, t, csphase=1, cnorm=0)
        for l in range(13):
            for m in range(l + 1):
                assert ours[l, m] == pytest.approx(ref[l * (l + 1) // 2 + m], rel=1e-12, abs=1e-14)


def test_point_mass_coefficients_closed_form():
    # a unit mass at (0, 0, a): C_l0 = (a/R)^l / sqrt(2l+1), all others 0
    a, radius = 0.3, 0.5
    c = sh_coefficients_of_mascons(MasconSet(np.array([[0.0, 0.0, a]]), np.ones(1)), 6, radius)
    for k, (kind, l, m) in enumerate(sh_index(6)):
        expected = (a / radius) ** l / np.sqrt(2 * l + 1) if (kind, m) == ("C", 0) else 0.0
        assert c[k] == pytest.approx(expected, abs=1e-15)


def test_exact_sh_reproduces_mascons_outside_brillouin(cluster):
    radius = np.linalg.norm(cluster.positions, axis=1).max()
    pts = shell_points(1.5 * radius, 300, seed=2)
    truth = perturbing_potential(cluster, pts)
    errors = []
    for degree in (2, 4, 8, 12):
        sh = SphericalHarmonics(degree, radius)
        v, _ = evaluate_field(
            Model((PointMass(),), sh), sh_coefficients_of_mascons(cluster, degree, radius), pts
        )
        errors.append(relative_field_error(v, truth))
    assert all(b < a for a, b in zip(errors, errors[1:], strict=False))
    assert errors[-1] < 0.01


def test_field_acceleration_is_gradient(cluster):
    sh = SphericalHarmonics(4, 0.5)
    model = Model((PointMass(),), sh)
    c = sh_coefficients_of_mascons(cluster, 4, 0.5)
    p = np.array([[0.7, -0.2, 0.3]])
    _, acc = evaluate_field(model, c, p)
    h = 1e-6
    fd = [
        (evaluate_field(model, c, p + h * e)[0] - evaluate_field(model, c, p - h * e)[0])[0]
        / (2 * h)
        for e in np.eye(3)
    ]
    assert np.allclose(acc[0], fd, rtol=1e-7)


def test_srp_pushes_away_from_sun():
    srp = SolarRadiationPressure(pressure_canonical=2.0, sun_latitude_deg=0.0)
    x, y, z = hy.make_vars("x", "y", "z")
    v = srp.potential(0)
    grad = [hy.diff(v, q) for q in (x, y, z)]
    f = hy.cfunc(grad, vars=[x, y, z])
    # at t = 0 the Sun is along +x: acceleration -k c x_hat
    acc = f(np.array([0.3, 0.1, 0.2]), pars=np.array([0.5]), time=0.0)
    assert np.allclose(acc, [-1.0, 0.0, 0.0])
    # a quarter turn later the body frame has turned by pi/2: the Sun is along -y
    acc = f(np.array([0.3, 0.1, 0.2]), pars=np.array([0.5]), time=np.pi / 2)
    assert np.allclose(acc, [0.0, 1.0, 0.0], atol=1e-15)


def test_srp_sun_latitude():
    # at t = 0 the Sun lies at latitude 30 deg in the x-z plane: pushed away from it
    srp = SolarRadiationPressure(pressure_canonical=2.0, sun_latitude_deg=30.0)
    x, y, z = hy.make_vars("x", "y", "z")
    v = srp.potential(0)
    f = hy.cfunc([hy.diff(v, q) for q in (x, y, z)], vars=[x, y, z])
    acc = f(np.array([0.3, 0.1, 0.2]), pars=np.array([0.5]), time=0.0)
    lat = np.radians(30.0)
    assert np.allclose(acc, [-np.cos(lat), 0.0, -np.sin(lat)])


def test_srp_pressure_falls_with_the_square_of_the_distance():
    from hamgrav.units import CanonicalUnits

    units = CanonicalUnits(4.892, 15465.8)
    near = SolarRadiationPressure.pressure_for(units, distance_au=1.0)
    assert SolarRadiationPressure.pressure_for(units, distance_au=2.0) == pytest.approx(near / 4)


def test_srp_pressure_units():
    from hamgrav.units import CanonicalUnits

    units = CanonicalUnits(4.892, 15465.8)
    k = SolarRadiationPressure.pressure_for(units, distance_au=1.0)
    assert k * units.acceleration_m_s2 == pytest.approx(1361.0 / 299792458.0)


def test_terms_answer_for_themselves():
    """What fits and exports ask of a term, asked of the term (no tests of its class)."""
    sh, nn = SphericalHarmonics(3, 0.8), NeuralPotential((4,), members=2)
    assert (sh.default_solver, sh.selects_on_validation, sh.natural_regulariser) == (
        "lm",
        False,
        "kaula",
    )
    assert (nn.default_solver, nn.selects_on_validation, nn.natural_regulariser) == (
        "adam",
        True,
        "harmonic",
    )
    assert PointMass().natural_regulariser is None and PointMass().kaula_weights() is None
    assert np.array_equal(sh.kaula_weights(), [float(l) ** 4 for _, l, _ in sh_index(3)])
    assert nn.kaula_weights() is None and sh.expansion() == (3, 0.8) and nn.expansion() is None
    assert (sh.members, sh.member(), nn.member().members) == (1, sh, 1)
    theta = np.arange(float(nn.n_params))
    assert [len(b) for b in nn.split_members(theta)] == [nn.member_params] * 2
    assert np.array_equal(sh.split_members(np.ones(sh.n_params))[0], np.ones(sh.n_params))
    assert (sh.title, nn.title, PointMass().title) == ("SH degree 3", "network", "point-mass")
    assert Model((PointMass(),), nn).member().learnable == nn.member()
    assert Model((PointMass(),), sh).member().learnable is sh
    # exports: exact tables where the term has them, None for the network (projected)
    central = PointMass(0.5).sh_tables(None, 4, 1.0)
    assert central.exact and central.c[0, 0] == 0.5 and not central.c[1:].any()
    assert nn.sh_tables(theta, 4, 1.0) is None and sh.export_json(np.zeros(12)) is None
    coeffs = np.linspace(1.0, 2.0, sh.n_params)
    assert sh.sh_tables(coeffs, 2, 0.8).c[2, 0] == 1.0 and not sh.sh_tables(coeffs, 2, 0.8).exact
    assert len(nn.export_json(theta)["members"]) == 2


def test_registry_rebuilds_every_term_and_a_new_one(cluster, monkeypatch):
    from dataclasses import dataclass

    from hamgrav.core import terms
    from hamgrav.core.hamiltonian import POSITION
    from hamgrav.core.terms import (
        GravityTerm,
        MasconTerm,
        register_term,
        registered_terms,
        term_from_description,
    )

    assert set(registered_terms()) >= {"point-mass", "mascons", "network", "sh", "srp"}
    for term in (
        PointMass(0.7),
        NeuralPotential((3, 2), 0.2, 1.1, 2),
        SphericalHarmonics(4, 0.9, 0.5),
        SolarRadiationPressure(1e-3, 12.0),
    ):
        assert term_from_description(term.describe()) == term
    mascons = term_from_description(MasconTerm(cluster, "prior").describe())
    assert mascons.key() == MasconTerm(cluster).key() and mascons.title == "prior"
    monkeypatch.setattr(terms, "_REGISTRY", dict(terms._REGISTRY))  # the new term stays here

    @register_term("test-dipole")
    @dataclass(frozen=True)
    class Dipole(GravityTerm):
        """A fixed dipole along z: a term written in one place, rebuilt by its name."""

        strength: float = 1e-3

        def potential(self, offset: int = 0):
            x, y, z = POSITION
            return self.strength * z / hy.sqrt(x * x + y * y + z * z) ** 3

        def key(self) -> str:
            return f"dipole({self.strength!r})"

        def describe(self) -> dict:
            return {"kind": self.kind, "strength": self.strength}

    model = Model((PointMass(), Dipole(2e-3)))
    again = Model.from_description(model.describe())
    assert again.known[1] == Dipole(2e-3) and again.key() == model.key()
    with pytest.raises(ValueError, match="registered already"):
        register_term("sh", Dipole)
    with pytest.raises(ValueError, match="unknown term kind 'nope'"):
        term_from_description({"kind": "nope"})


def test_point_dipole_is_the_first_order_of_a_displaced_mass():
    from hamgrav.core.shexpansion import mascon_tables
    from hamgrav.core.terms import PointDipole, term_from_description

    d = np.array([0.03, -0.02, 0.05])
    dipole = PointDipole(tuple(d))
    pts = shell_points(1.0, 50, seed=4) * np.linspace(2.0, 40.0, 50)[:, None]
    v, a = evaluate_field(Model((PointMass(), dipole)), np.zeros(0), pts, which="total")
    r = np.linalg.norm(pts, axis=1)
    assert np.allclose(v, 1 / r + pts @ d / r**3, rtol=1e-14)
    # a unit mass at d: 1 / |q - d| = 1 / r + (d . q) / r^3 + O(|d|^2 / r^3)
    shifted = 1 / np.linalg.norm(pts - d, axis=1)
    assert np.all(np.abs(v - shifted) <= 2.0 * (d @ d) / r**3)
    # the acceleration is the gradient of the dipole's potential, by hand
    expected = (
        -1 * pts / r[:, None] ** 3
        + d / r[:, None] ** 3
        - 3 * (pts @ d)[:, None] * pts / r[:, None] ** 5
    )
    assert np.allclose(a, expected, rtol=1e-12)
    # its degree-1 SH coefficients are those of the unit mass at d (pyshtools-checked mascons)
    tables = dipole.sh_tables(None, 3, 0.8)
    c, s = mascon_tables(MasconSet(d[None, :], np.ones(1)), 3, 0.8)
    assert np.allclose(tables.c[1], c[1], rtol=1e-12) and np.allclose(tables.s[1], s[1], rtol=1e-12)
    assert not tables.c[0].any() and not tables.c[2:].any() and tables.exact
    assert term_from_description(dipole.describe()) == dipole and dipole.n_params == 0
    with pytest.raises(ValueError, match="three finite numbers"):
        PointDipole((1.0, np.nan, 0.0))


x, y, z = POSITION

NETWORKS = [
    NeuralPotential((5, 4)),
    NeuralPotential((6, 5, 3), members=2, softening=0.3),
    NeuralPotential((7,), scale=0.2, envelope_radius=0.8),
]


@pytest.mark.parametrize("term", NETWORKS, ids=lambda t: t.key())
def test_network_layers_are_ffnns_own_expressions(term):
    """The layers the network's derivatives are formed from are heyoka's ffnn's, expression
    for expression: a Taylor decomposition holding both then shares them (were ffnn to build
    its layers otherwise, the costate pass would silently do the network's work twice)."""
    out, activations, weights = term.member_layers_expressions(0)
    assert out == term.member().network(0)
    assert [len(s) for s in activations] == list(term.hidden)
    assert len(weights) == len(term.hidden) + 1


@pytest.mark.parametrize("term", NETWORKS, ids=lambda t: t.key())
def test_network_derivatives_equal_heyokas_diff_tensors(term, rng):
    """The network's gradient and Hessian in the position (forward tangents through the
    layers, the envelope by the product rule) equal heyoka's diff_tensors of its potential,
    at random points inside and outside the unit sphere and random parameters."""
    ours = term.derivatives(3)  # at an offset, as a model with other parameters has it
    reference = position_derivatives(term.potential(3))
    n = 40
    points = rng.normal(size=(3, n)) * rng.uniform(0.3, 2.5, n)
    pars = np.zeros((3 + term.n_params, n))
    pars[3:] = term.initial_params(1)[:, None] + 0.3 * rng.normal(size=(term.n_params, n))
    values = []
    for gradient, hessian in (ours, reference):
        f = hy.cfunc([*gradient, *hessian], vars=[x, y, z])
        values.append(f(points, pars=pars))
    assert np.all(np.isfinite(values[1])) and np.abs(values[1]).max() > 1e-3
    np.testing.assert_allclose(values[0], values[1], rtol=1e-11, atol=1e-13)


@pytest.mark.parametrize("term", NETWORKS, ids=lambda t: t.key())
def test_network_parameter_rate_sum_equals_heyokas_rates(term, rng):
    """The network's own reduction of the adjoint's parameter rates over many nodes equals
    minus the sum of heyoka's rates cfunc (the generic path) over the same nodes."""
    model = Model((PointMass(),), term)
    theta = term.initial_params(2) + 0.2 * rng.normal(size=term.n_params)
    n = 60
    states = rng.normal(size=(n, 6))
    states[:, :3] *= rng.uniform(0.5, 2.0, (n, 1)) / np.linalg.norm(states[:, :3], axis=1)[:, None]
    lam = rng.normal(size=(n, 6))
    rates = parameter_rate_function(model)
    values = rates(
        np.ascontiguousarray(np.concatenate([states, lam], axis=1).T),
        pars=np.repeat(theta[: rates.nparams, None], n, axis=1),
    )
    reference = -values.sum(axis=1)
    got = term.parameter_rate_sum(theta, states[:, :3], lam[:, 3:])
    assert got.shape == (term.n_params,)
    np.testing.assert_allclose(got, reference, rtol=1e-12, atol=1e-12 * np.abs(reference).max())
