"""Potential terms as heyoka expressions of the body-fixed position (canonical units).

Every term is a small frozen object with one job: ``potential(offset)`` returns a heyoka
expression V(q[, t]) (positive convention: the Hamiltonian carries ``-V``), reading its
runtime numbers from ``heyoka.par[offset : offset + n_params + trajectory_params]``. A term is
one of three kinds:

- known: no runtime parameters (its numbers are compiled in as constants): point mass, mascons;
- learnable: ``n_params`` parameters shared by every trajectory: network, spherical harmonics;
- per-trajectory: ``trajectory_params`` parameters that take one value per trajectory (orbit,
  particle, descent), known or estimated: solar radiation pressure (area-to-mass).

Parameter layouts:

- :class:`NeuralPotential`: heyoka ``model.ffnn`` order: all weight matrices layer by layer,
  row-major (output x input), then all biases layer by layer; an ensemble's members follow
  one another.
- :class:`SphericalHarmonics`: for l = 2..L, m = 0..l: C_lm, then S_lm when m > 0.
- :class:`SolarRadiationPressure`: one area-to-mass coefficient [m^2/kg] per trajectory.
"""

from __future__ import annotations

import hashlib
import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

import heyoka as hy
import numpy as np

from .hamiltonian import POSITION
from .mascons import MasconSet

__all__ = [
    "Term",
    "PointMass",
    "MasconTerm",
    "NeuralPotential",
    "SphericalHarmonics",
    "SolarRadiationPressure",
    "sh_coefficients_of_mascons",
    "term_from_description",
]

x, y, z = POSITION


class Term(ABC):
    """Base of all potential terms (canonical units, positive potential)."""

    #: learnable parameters shared by all trajectories
    n_params: int = 0
    #: parameters taking one value per trajectory
    trajectory_params: int = 0

    @abstractmethod
    def potential(self, offset: int = 0) -> hy.expression:
        """V(q[, t]) as a heyoka expression, its runtime numbers at ``par[offset:]``."""

    @abstractmethod
    def key(self) -> str:
        """A string that identifies the compiled structure of this term."""

    @abstractmethod
    def describe(self) -> dict:
        """Plain-data description (JSON-able), enough to rebuild the term."""

    def initial_params(self, seed: int = 0) -> np.ndarray:
        """Starting values of the learnable parameters (n_params,); zeros unless overridden."""
        return np.zeros(self.n_params)

    def initial_trajectory_params(self) -> np.ndarray:
        """Starting values (trajectory_params,) of one trajectory's parameters when estimated."""
        return np.zeros(self.trajectory_params)


def _hash_arrays(*arrays) -> str:
    h = hashlib.sha1()
    for a in arrays:
        h.update(np.ascontiguousarray(a, dtype=float).tobytes())
    return h.hexdigest()[:16]


@dataclass(frozen=True)
class PointMass(Term):
    """The central term mu / r (``mu`` canonical: 1 is the body's GM)."""

    mu: float = 1.0

    def potential(self, offset: int = 0) -> hy.expression:
        return self.mu / hy.sqrt(x * x + y * y + z * z)

    def key(self) -> str:
        return f"pm({self.mu!r})"

    def describe(self) -> dict:
        return {"kind": "point-mass", "mu": self.mu}


@dataclass(frozen=True, eq=False)
class MasconTerm(Term):
    """A fixed mascon sum sum m_i / |q - q_i| (the truth, or the shape prior as a known term),
    built by heyoka's ``model.fixed_centres_potential`` with the masses and positions
    (canonical) compiled in as constants."""

    mascons: MasconSet
    label: str = "mascons"

    def potential(self, offset: int = 0) -> hy.expression:
        # heyoka returns the potential energy -sum m_i / r_i; hamgrav's V is positive
        return -hy.model.fixed_centres_potential(
            masses=self.mascons.masses.tolist(), positions=self.mascons.positions
        )

    def key(self) -> str:
        return f"mascons({_hash_arrays(self.mascons.positions, self.mascons.masses)})"

    def describe(self) -> dict:
        return {
            "kind": "mascons",
            "label": self.label,
            "positions": self.mascons.positions.tolist(),
            "masses": self.mascons.masses.tolist(),
        }


@dataclass(frozen=True)
class NeuralPotential(Term):
    """N(q) = s (R_w / r)^3 NN(x, y, z): tanh hidden layers, one linear output.

    The envelope imposes the 1/r^3 decay of the slowest-fading (quadrupole) part of a
    perturbing potential and removes the additive-constant degeneracy of the last bias.
    With ``members`` = K > 1 the term is an ensemble: NN is the mean of K networks of the same
    shape, each with its own parameters (member-major: member 0's block, then member 1's...).
    Initialisation (seeded): Glorot-uniform weights, zero biases; member k uses seed + k.

    Fields: ``hidden`` layer sizes; ``scale`` s, the output's scale [canonical potential,
    GM / synchronous radius]; ``envelope_radius`` R_w [canonical length, synchronous radii]
    (hamgrav uses the Brillouin radius); ``members`` K.
    """

    hidden: tuple[int, ...] = (24, 24)
    scale: float = 0.1
    envelope_radius: float = 1.0
    members: int = 1

    def __post_init__(self) -> None:
        if not self.hidden or any(int(h) < 1 for h in self.hidden):
            raise ValueError(f"hidden layer sizes must be positive, got {self.hidden!r}")
        if int(self.members) < 1:
            raise ValueError(f"an ensemble needs at least one member, got {self.members!r}")
        object.__setattr__(self, "hidden", tuple(int(h) for h in self.hidden))
        object.__setattr__(self, "members", int(self.members))

    @property
    def layer_sizes(self) -> tuple[int, ...]:
        """Layer widths of one member, input (3: x, y, z) to output (1)."""
        return (3, *self.hidden, 1)

    @property
    def n_weights(self) -> int:
        """Number of weights of one member (the first block of its parameter layout)."""
        s = self.layer_sizes
        return sum(s[i] * s[i + 1] for i in range(len(s) - 1))

    @property
    def member_params(self) -> int:
        """Weights plus biases of one member."""
        return self.n_weights + sum(self.layer_sizes[1:])

    @property
    def n_params(self) -> int:  # type: ignore[override]
        """Parameters of all members."""
        return self.members * self.member_params

    def member(self) -> NeuralPotential:
        """One member of the ensemble as a network of its own."""
        return NeuralPotential(self.hidden, self.scale, self.envelope_radius)

    def split_members(self, params: np.ndarray) -> list[np.ndarray]:
        """The members' parameter blocks of ``params`` (n_params,)."""
        params = np.asarray(params, dtype=float)
        if params.shape != (self.n_params,):
            raise ValueError(f"expected {self.n_params} parameters, got {params.shape}")
        return list(params.reshape(self.members, self.member_params))

    def network(self, offset: int = 0) -> hy.expression:
        """NN(x, y, z), dimensionless (the members' mean), parameters at ``par[offset:]``."""
        activations = [hy.tanh] * len(self.hidden) + [lambda e: e]
        outputs = []
        for k in range(self.members):
            first = offset + k * self.member_params
            (out,) = hy.model.ffnn(
                inputs=[x, y, z],
                nn_hidden=list(self.hidden),
                n_out=1,
                activations=activations,
                nn_wb=[hy.par[first + i] for i in range(self.member_params)],
            )
            outputs.append(out)
        return outputs[0] if self.members == 1 else hy.sum(outputs) / self.members

    def potential(self, offset: int = 0) -> hy.expression:
        r2 = x * x + y * y + z * z
        envelope = self.envelope_radius**3 / (r2 * hy.sqrt(r2))
        return self.scale * envelope * self.network(offset)

    def initial_params(self, seed: int = 0) -> np.ndarray:
        """Glorot-uniform weights (member k seeded by ``seed + k``), zero biases."""
        s = self.layer_sizes
        blocks = []
        for k in range(self.members):
            rng = np.random.default_rng(seed + k)
            weights = [
                rng.uniform(-1, 1, s[i] * s[i + 1]) * math.sqrt(6.0 / (s[i] + s[i + 1]))
                for i in range(len(s) - 1)
            ]
            blocks.append(np.concatenate(weights + [np.zeros(sum(s[1:]))]))
        return np.concatenate(blocks)

    def last_bias_index(self) -> int:
        """Index of the (last member's) output bias in the parameter layout."""
        return self.n_params - 1

    def key(self) -> str:
        members = f",x{self.members}" if self.members > 1 else ""
        return f"nn({self.hidden},{self.scale!r},{self.envelope_radius!r}{members})"

    def describe(self) -> dict:
        return {
            "kind": "network",
            "hidden": list(self.hidden),
            "scale": self.scale,
            "envelope_radius": self.envelope_radius,
            "members": self.members,
            "activation": "tanh",
            "layout": (
                "ffnn: weights (row-major, out x in) layer by layer, then biases; "
                "members one after the other, the potential uses their mean"
            ),
        }


def sh_index(degree: int) -> list[tuple[str, int, int]]:
    """The parameter layout of a degree-``degree`` expansion: ('C'|'S', l, m) for l >= 2."""
    out = []
    for l in range(2, degree + 1):
        for m in range(l + 1):
            out.append(("C", l, m))
            if m > 0:
                out.append(("S", l, m))
    return out


@dataclass(frozen=True)
class SphericalHarmonics(Term):
    """Fully normalised SH expansion of the perturbing potential, degrees 2..L.

    Conventions of heyoka ``model.sh_gravity_pot`` (Montenbruck & Gill: 4-pi normalised, no
    Condon-Shortley phase). The monopole is the separate central term and degree 1 vanishes
    about the centre of mass, so C00 = C1m = S1m = 0 here.

    Fields: ``degree`` L; ``reference_radius`` R [canonical length, synchronous radii] (hamgrav
    uses the Brillouin radius); ``mu`` the GM of the expansion [canonical, 1 = the body's].
    The parameters (the coefficients C_lm, S_lm) are dimensionless.
    """

    degree: int
    reference_radius: float
    mu: float = 1.0

    def __post_init__(self) -> None:
        if self.degree < 2:
            raise ValueError(f"SH degree must be at least 2, got {self.degree}")
        if not self.reference_radius > 0:
            raise ValueError("reference radius must be positive")

    @property
    def n_params(self) -> int:  # type: ignore[override]
        """(L + 1)^2 - 4 coefficients: degrees 2..L."""
        return (self.degree + 1) ** 2 - 4

    def coefficient_table(self, values) -> list[list]:
        """[[C, S], ...] in heyoka's degree-then-order order from the parameter values."""
        table = [[0.0, 0.0] for _ in range((self.degree + 1) * (self.degree + 2) // 2)]
        for k, (kind, l, m) in enumerate(sh_index(self.degree)):
            table[l * (l + 1) // 2 + m][0 if kind == "C" else 1] = values[k]
        return table

    def potential(self, offset: int = 0) -> hy.expression:
        pars = [hy.par[offset + k] for k in range(self.n_params)]
        return hy.model.sh_gravity_pot(
            [x, y, z], self.coefficient_table(pars), self.mu, self.reference_radius
        )

    def key(self) -> str:
        return f"sh({self.degree},{self.reference_radius!r},{self.mu!r})"

    def describe(self) -> dict:
        return {
            "kind": "sh",
            "degree": self.degree,
            "reference_radius": self.reference_radius,
            "mu": self.mu,
            "normalisation": "4pi, no Condon-Shortley phase (Montenbruck)",
            "layout": "l=2..L, m=0..l: C_lm then S_lm (m>0)",
        }


@dataclass(frozen=True)
class SolarRadiationPressure(Term):
    """Cannonball SRP with the Sun fixed in inertial space, so rotating in the body frame.

    V = -k c (s_hat(t) . q) with c the area-to-mass coefficient [m^2/kg] (one per trajectory)
    and k = ``pressure_canonical`` the acceleration [canonical] per unit area-to-mass
    [m^2/kg] (:meth:`pressure_for` gives it from a heliocentric distance [AU] and a
    reflectivity 1 + rho), so that the acceleration a = grad V = -k c s_hat pushes away from
    the Sun. The Sun direction at t = 0 makes angle ``sun_latitude_deg`` [deg] with the
    equator and lies in the x-z plane; the body frame turns at omega = 1.
    """

    pressure_canonical: float  # k: acceleration [canonical] per unit area-to-mass [m^2/kg]
    sun_latitude_deg: float = 0.0

    trajectory_params = 1

    @staticmethod
    def pressure_for(units, distance_au: float = 1.0, reflectivity: float = 1.0) -> float:
        """k for a body with ``units`` at heliocentric ``distance_au`` (flux 1361 W/m^2 at 1
        AU), multiplied by ``reflectivity`` = 1 + rho (1 for a black body)."""
        pressure_n_m2 = 1361.0 / 299_792_458.0 / distance_au**2
        return reflectivity * pressure_n_m2 / units.acceleration_m_s2

    def sun_direction(self) -> list[hy.expression]:
        """Unit vector to the Sun in the body frame, a function of canonical time."""
        lat = math.radians(self.sun_latitude_deg)
        t = hy.time
        # inertial (cos lat, 0, sin lat) seen from the frame rotated by angle t about z
        return [math.cos(lat) * hy.cos(t), -math.cos(lat) * hy.sin(t), math.sin(lat)]

    def potential(self, offset: int = 0) -> hy.expression:
        s = self.sun_direction()
        return -self.pressure_canonical * hy.par[offset] * (s[0] * x + s[1] * y + s[2] * z)

    def key(self) -> str:
        return f"srp({self.pressure_canonical!r},{self.sun_latitude_deg!r})"

    def describe(self) -> dict:
        return {
            "kind": "srp",
            "pressure_canonical": self.pressure_canonical,
            "sun_latitude_deg": self.sun_latitude_deg,
        }


def _normalised_legendre(lmax: int, t: np.ndarray) -> np.ndarray:
    """Fully normalised associated Legendre functions P_lm(t) (no Condon-Shortley phase),
    shape (lmax+1, lmax+1, n); standard stable recursions."""
    t = np.asarray(t, dtype=float)
    u = np.sqrt(np.maximum(0.0, 1.0 - t * t))
    p = np.zeros((lmax + 1, lmax + 1, t.size))
    p[0, 0] = 1.0
    if lmax >= 1:
        p[1, 1] = math.sqrt(3.0) * u
    for m in range(2, lmax + 1):
        p[m, m] = math.sqrt((2 * m + 1) / (2 * m)) * u * p[m - 1, m - 1]
    for m in range(0, lmax):
        p[m + 1, m] = math.sqrt(2 * m + 3) * t * p[m, m]
    for m in range(0, lmax + 1):
        for l in range(m + 2, lmax + 1):
            a = math.sqrt((2 * l - 1) * (2 * l + 1) / ((l - m) * (l + m)))
            b = math.sqrt(
                (2 * l + 1) * (l + m - 1) * (l - m - 1) / ((l - m) * (l + m) * (2 * l - 3))
            )
            p[l, m] = a * t * p[l - 1, m] - b * p[l - 2, m]
    return p


def sh_coefficients_of_mascons(mascons: MasconSet, degree: int, reference_radius: float):
    """Exact normalised coefficients (in :func:`sh_index` order) of a mascon set, total mass
    normalised to 1: C_lm + i S_lm = sum_i m_i (r_i/R)^l P_lm(sin phi_i) e^{i m lambda_i}."""
    pos = mascons.positions
    r = np.linalg.norm(pos, axis=1)
    sin_phi = pos[:, 2] / r
    lam = np.arctan2(pos[:, 1], pos[:, 0])
    p = _normalised_legendre(degree, sin_phi)
    mass = mascons.masses / mascons.masses.sum()
    out = []
    for kind, l, m in sh_index(degree):
        # P_lm here is normalised with sqrt((2 - delta_m0)(2l+1)(l-m)!/(l+m)!); the exterior
        # coefficients of a point mass are P_lm / (2l+1) times (r/R)^l.
        common = mass * (r / reference_radius) ** l * p[l, m] / (2 * l + 1)
        trig = np.cos(m * lam) if kind == "C" else np.sin(m * lam)
        out.append(float(np.sum(common * trig)))
    return np.asarray(out)


def term_from_description(d: dict) -> Term:
    """Rebuild a term from :meth:`Term.describe` output (model files)."""
    if not isinstance(d, dict):
        raise ValueError(f"a term description must be a JSON object, got {d!r}")
    kind = d.get("kind")
    if kind == "point-mass":
        return PointMass(float(d["mu"]))
    if kind == "mascons":
        return MasconTerm(
            MasconSet(np.asarray(d["positions"], float), np.asarray(d["masses"], float)),
            str(d.get("label", "mascons")),
        )
    if kind == "network":
        return NeuralPotential(
            tuple(d["hidden"]),
            float(d["scale"]),
            float(d["envelope_radius"]),
            int(d.get("members", 1)),
        )
    if kind == "sh":
        return SphericalHarmonics(int(d["degree"]), float(d["reference_radius"]), float(d["mu"]))
    if kind == "srp":
        return SolarRadiationPressure(float(d["pressure_canonical"]), float(d["sun_latitude_deg"]))
    raise ValueError(f"unknown term kind {kind!r}")
