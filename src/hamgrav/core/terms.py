"""Potential terms as heyoka expressions of the body-fixed position (canonical units).

Every term is a small frozen object implementing :class:`GravityTerm`: ``potential(offset)``
returns a heyoka expression V(q[, t]) (positive convention: the Hamiltonian carries ``-V``),
reading its runtime numbers from ``heyoka.par[offset : offset + n_params + trajectory_params]``,
and the term answers what fits, exports and model files ask of it (its default solver, its
natural regulariser, its SH tables...). Each term class is registered by name
(:func:`register_term`); model files record a term by that name and its constructor
arguments (:meth:`GravityTerm.describe`, :func:`term_from_description`). A term is one of
three kinds:

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
from dataclasses import dataclass, fields, is_dataclass
from typing import ClassVar, NamedTuple

import heyoka as hy
import numpy as np

from .hamiltonian import HESSIAN_ENTRIES, POSITION
from .mascons import MasconSet

__all__ = [
    "GravityTerm",
    "Term",
    "SHTables",
    "register_term",
    "registered_terms",
    "PointMass",
    "PointDipole",
    "MasconTerm",
    "NeuralPotential",
    "SphericalHarmonics",
    "SolarRadiationPressure",
    "position_derivatives",
    "sh_coefficients_of_mascons",
    "term_from_description",
]

x, y, z = POSITION


class GravityTerm(ABC):
    """The interface of every potential term (canonical units, positive potential).

    A term knows itself: its expression and parameter layout (:meth:`potential`,
    ``n_params``, ``trajectory_params``), its starting point (:meth:`initial_params`), how a
    fit treats it (``default_solver``, ``selects_on_validation``, ``natural_regulariser``,
    :meth:`kaula_weights`, ensembles through ``members``, :meth:`member` and
    :meth:`split_members`), what it exports (:meth:`expansion`, :meth:`sh_tables`,
    :meth:`export_json`) and how a model file records it (:meth:`describe` under its
    registered ``kind``, :meth:`from_description`). Callers ask the term instead of testing its
    class, so a new term is one subclass registered by :func:`register_term`, plus its tests.
    """

    #: the name the term is registered and recorded by (the "kind" of :meth:`describe`)
    kind: ClassVar[str] = ""
    #: learnable parameters shared by all trajectories
    n_params: int = 0
    #: parameters taking one value per trajectory
    trajectory_params: int = 0
    #: parts fitted each on its own whose mean is the potential (an ensemble); 1 otherwise
    members: int = 1
    #: the solver that fits this term when none is named: "lm" or "adam"
    default_solver: ClassVar[str] = "lm"
    #: whether a fit of this term returns its best iterate on the held-out arcs (an
    #: early-stopped fit: the solver sees them) rather than running to convergence on the
    #: training arcs, the held-out ones only checked
    selects_on_validation: ClassVar[bool] = False
    #: the regulariser natural to this term: "kaula" (weights :meth:`kaula_weights`),
    #: "harmonic" (the Laplacian penalty, :mod:`hamgrav.fit.harmonic`) or None
    natural_regulariser: ClassVar[str | None] = None

    @abstractmethod
    def potential(self, offset: int = 0) -> hy.expression:
        """V(q[, t]) as a heyoka expression, its runtime numbers at ``par[offset:]``."""

    def derivatives(self, offset: int = 0) -> tuple[list[hy.expression], list[hy.expression]]:
        """The gradient (d/dx, d/dy, d/dz) and the Hessian's six entries
        (:data:`hamgrav.core.hamiltonian.HESSIAN_ENTRIES`) of :meth:`potential` in the
        position [canonical], as heyoka expressions (what the state transition equations
        need). By default heyoka's ``diff_tensors``; a term may form them so that they share
        more of the work (a network: its layers' values)."""
        return position_derivatives(self.potential(offset))

    def parameter_rate_sum(
        self, params: np.ndarray, points: np.ndarray, directions: np.ndarray
    ) -> np.ndarray | None:
        """sum_k d (v_k . grad V(q_k)) / d theta (n_params,) over body-fixed ``points`` q_k
        (N, 3) and ``directions`` v_k (N, 3) [canonical], at parameters ``params``
        (n_params,): the adjoint's parameter rates of a whole block of nodes reduced at
        once (:func:`hamgrav.core.propagation.adjoint_gradient`, v the costate's momentum
        part). None (the default) when the term has no such reduction: the adjoint then
        evaluates heyoka's rates node by node."""
        return None

    @abstractmethod
    def key(self) -> str:
        """A string that identifies the compiled structure of this term."""

    @abstractmethod
    def describe(self) -> dict:
        """Plain-data description (JSON-able): the registered ``kind`` and the constructor
        arguments (documentation keys may follow), enough to rebuild the term."""

    @classmethod
    def from_description(cls, d: dict) -> GravityTerm:
        """The term of :meth:`describe` output: by default the constructor called with the
        description's entries that name its (dataclass) fields."""
        names = {f.name for f in fields(cls)} if is_dataclass(cls) else set()
        return cls(**{k: v for k, v in d.items() if k in names})

    @property
    def title(self) -> str:
        """A short name of the term for messages (e.g. "SH degree 8")."""
        return self.kind or type(self).__name__

    def initial_params(self, seed: int = 0) -> np.ndarray:
        """Starting values of the learnable parameters (n_params,); zeros unless overridden."""
        return np.zeros(self.n_params)

    def initial_trajectory_params(self) -> np.ndarray:
        """Starting values (trajectory_params,) of one trajectory's parameters when estimated."""
        return np.zeros(self.trajectory_params)

    def member(self) -> GravityTerm:
        """One member of an ensemble as a term of its own (the term itself unless an ensemble)."""
        return self

    def split_members(self, params: np.ndarray) -> list[np.ndarray]:
        """The members' parameter blocks of ``params`` (n_params,), member-major."""
        params = np.asarray(params, dtype=float)
        if params.shape != (self.n_params,):
            raise ValueError(f"expected {self.n_params} parameters, got {params.shape}")
        return list(params.reshape(self.members, self.n_params // self.members))

    def kaula_weights(self) -> np.ndarray | None:
        """Kaula's rule as the diagonal (n_params,) of the prior's normal matrix, to be scaled
        by the weight alpha; None when the rule does not apply to the term."""
        return None

    def expansion(self) -> tuple[int, float] | None:
        """(degree, reference radius [canonical]) when the term is an SH expansion of its own
        (exported exactly at that degree and radius), else None."""
        return None

    def sh_tables(self, params, degree: int, reference_radius: float) -> SHTables | None:
        """This term's exterior potential at parameters ``params`` as exact SH tables, degrees
        0..``degree`` at ``reference_radius`` [canonical], scaled by mu = 1 (conventions of
        :mod:`hamgrav.core.shexpansion`); None when it has no exact expansion (an exporter
        projects its field on a sphere instead)."""
        return None

    def export_json(self, params=None) -> dict | None:
        """The term's entry (plain data) in the framework-free JSON document of a model
        (:mod:`hamgrav.io.network_json`) at learnable parameters ``params``; None when that
        document has no place for it."""
        return None


#: The former name of :class:`GravityTerm`.
Term = GravityTerm

_REGISTRY: dict[str, type[GravityTerm]] = {}


def register_term(name: str, cls: type[GravityTerm] | None = None):
    """Register the term class ``cls`` under ``name`` (its ``kind``: how model files record
    it); without ``cls``, a class decorator that does so."""

    def register(cls: type[GravityTerm]) -> type[GravityTerm]:
        if name in _REGISTRY and _REGISTRY[name] is not cls:
            raise ValueError(f"a term kind {name!r} is registered already")
        cls.kind = name
        _REGISTRY[name] = cls
        return cls

    return register if cls is None else register(cls)


def registered_terms() -> dict[str, type[GravityTerm]]:
    """The registered term classes by name."""
    return dict(_REGISTRY)


class SHTables(NamedTuple):
    """A term's SH tables (:meth:`GravityTerm.sh_tables`): ``c``, ``s`` (L + 1, L + 1)
    [dimensionless, mu = 1], whether they are ``exact`` (not truncated) and a ``note``, one line
    saying what they are."""

    c: np.ndarray
    s: np.ndarray
    exact: bool
    note: str


def _hash_arrays(*arrays) -> str:
    h = hashlib.sha1()
    for a in arrays:
        h.update(np.ascontiguousarray(a, dtype=float).tobytes())
    return h.hexdigest()[:16]


def position_derivatives(potential: hy.expression) -> tuple[list, list]:
    """The gradient (3) and the Hessian's six entries (:data:`HESSIAN_ENTRIES`) of
    ``potential`` in the position variables, by heyoka's ``diff_tensors``."""
    tensors = hy.diff_tensors([potential], list(POSITION), diff_order=2)

    def entry(*axes: int) -> hy.expression:
        index = [0, 0, 0, 0]
        for axis in axes:
            index[1 + axis] += 1
        return tensors[index]

    return [entry(i) for i in range(3)], [entry(i, j) for i, j in HESSIAN_ENTRIES]


@register_term("point-mass")
@dataclass(frozen=True)
class PointMass(GravityTerm):
    """The central term mu / r (``mu`` canonical: 1 is the body's GM)."""

    mu: float = 1.0

    def potential(self, offset: int = 0) -> hy.expression:
        return self.mu / hy.sqrt(x * x + y * y + z * z)

    def key(self) -> str:
        return f"pm({self.mu!r})"

    def describe(self) -> dict:
        return {"kind": self.kind, "mu": self.mu}

    @classmethod
    def from_description(cls, d: dict) -> PointMass:
        return cls(float(d["mu"]))

    def sh_tables(self, params, degree: int, reference_radius: float) -> SHTables:
        c, s = np.zeros((degree + 1, degree + 1)), np.zeros((degree + 1, degree + 1))
        c[0, 0] = self.mu
        return SHTables(c, s, True, f"central term (GM times {self.mu!r}): C00, exact")

    def export_json(self, params=None) -> dict:
        return self.describe()


@register_term("point-dipole")
@dataclass(frozen=True)
class PointDipole(GravityTerm):
    """A point dipole at the origin, (d . q) / r^3: the first-order potential of a unit mass
    displaced by ``moment`` d [canonical length] from the origin (a known term: e.g. what
    brings a shape prior left where the shape is back to the frame's centre of mass)."""

    moment: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        moment = tuple(float(v) for v in self.moment)
        if len(moment) != 3 or not all(math.isfinite(v) for v in moment):
            raise ValueError(f"a dipole moment is three finite numbers, got {self.moment!r}")
        object.__setattr__(self, "moment", moment)

    def potential(self, offset: int = 0) -> hy.expression:
        r2 = x * x + y * y + z * z
        dx, dy, dz = self.moment
        return (dx * x + dy * y + dz * z) / (r2 * hy.sqrt(r2))

    def key(self) -> str:
        return f"dipole({self.moment!r})"

    def describe(self) -> dict:
        return {"kind": self.kind, "moment": list(self.moment)}

    @classmethod
    def from_description(cls, d: dict) -> PointDipole:
        return cls(tuple(float(v) for v in d["moment"]))

    def sh_tables(self, params, degree: int, reference_radius: float) -> SHTables:
        # (d . q) / r^3 = (1 / r) (R / r) sum over m of the degree-1 terms, 4-pi normalised
        # (P_10 = sqrt(3) sin(lat), P_11 = sqrt(3) cos(lat)): C10 = d_z / (sqrt(3) R), ...
        c, s = np.zeros((degree + 1, degree + 1)), np.zeros((degree + 1, degree + 1))
        if degree >= 1:
            dx, dy, dz = np.asarray(self.moment) / (math.sqrt(3.0) * reference_radius)
            c[1, 0], c[1, 1], s[1, 1] = dz, dx, dy
        return SHTables(c, s, True, f"point dipole {self.moment!r}: degree 1, exact")

    def export_json(self, params=None) -> dict:
        return self.describe()


@register_term("mascons")
@dataclass(frozen=True, eq=False)
class MasconTerm(GravityTerm):
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
            "kind": self.kind,
            "label": self.label,
            "positions": self.mascons.positions.tolist(),
            "masses": self.mascons.masses.tolist(),
        }

    @classmethod
    def from_description(cls, d: dict) -> MasconTerm:
        return cls(
            MasconSet(np.asarray(d["positions"], float), np.asarray(d["masses"], float)),
            str(d.get("label", "mascons")),
        )

    @property
    def title(self) -> str:
        return self.label

    def sh_tables(self, params, degree: int, reference_radius: float) -> SHTables:
        # shexpansion builds on this module's Legendre functions: imported on use
        from .shexpansion import mascon_tables

        c, s = mascon_tables(self.mascons, degree, reference_radius)
        note = (
            f"{self.label} ({len(self.mascons)} mascons, known, no errors): exact "
            f"coefficients, truncated at degree {degree}"
        )
        return SHTables(c, s, False, note)

    def export_json(self, params=None) -> dict:
        return self.describe()


@register_term("network")
@dataclass(frozen=True)
class NeuralPotential(GravityTerm):
    """N(q) = s (R_w / rho)^3 NN(x, y, z), rho = sqrt(r^2 + r_c^2): tanh hidden layers, one
    linear output.

    The envelope imposes the 1/r^3 decay of the slowest-fading (quadrupole) part of a
    perturbing potential and removes the additive-constant degeneracy of the last bias.
    The softening r_c (0 by default: (R_w / r)^3) caps how much the envelope amplifies the
    network near the centre, (R_w / r_c)^3 at most, so that a change of the network that the
    exterior barely sees is not multiplied by (R_w / r)^3 at a neck well inside R_B.
    With ``members`` = K > 1 the term is an ensemble: NN is the mean of K networks of the same
    shape, each with its own parameters (member-major: member 0's block, then member 1's...).
    Initialisation (seeded): Glorot-uniform weights, zero biases; member k uses seed + k.

    Fields: ``hidden`` layer sizes; ``scale`` s, the output's scale [canonical potential,
    GM / synchronous radius]; ``envelope_radius`` R_w [canonical length, synchronous radii]
    (the estimator's networks use 1, the synchronous radius); ``members`` K; ``softening``
    r_c [canonical length, synchronous radii].
    """

    hidden: tuple[int, ...] = (24, 24)
    scale: float = 0.1
    envelope_radius: float = 1.0
    members: int = 1
    softening: float = 0.0

    # Adam is the paper's protocol; its fit stops early, so it selects on the held-out arcs
    default_solver = "adam"
    selects_on_validation = True
    # the network is not harmonic by construction (SH are)
    natural_regulariser = "harmonic"

    def __post_init__(self) -> None:
        if not self.hidden or any(int(h) < 1 for h in self.hidden):
            raise ValueError(f"hidden layer sizes must be positive, got {self.hidden!r}")
        if int(self.members) < 1:
            raise ValueError(f"an ensemble needs at least one member, got {self.members!r}")
        object.__setattr__(self, "hidden", tuple(int(h) for h in self.hidden))
        object.__setattr__(self, "members", int(self.members))
        if not (math.isfinite(self.softening) and self.softening >= 0.0):
            raise ValueError(f"the envelope's softening must be >= 0, got {self.softening!r}")
        object.__setattr__(self, "softening", float(self.softening))

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
        return NeuralPotential(self.hidden, self.scale, self.envelope_radius, 1, self.softening)

    def envelope_distance(self, points: np.ndarray) -> np.ndarray:
        """rho / R_w at ``points`` (k, 3) [canonical]: the distance the envelope decays with,
        in envelope radii (r / R_w without softening)."""
        points = np.asarray(points, dtype=float)
        if not self.softening:
            return np.linalg.norm(points, axis=1) / self.envelope_radius
        r2 = np.sum(points * points, axis=1) + self.softening**2
        return np.sqrt(r2) / self.envelope_radius

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

    def _envelope(self) -> tuple[hy.expression, hy.expression]:
        """(rho^2, E = (R_w / rho)^3) as heyoka expressions: the same for the potential and
        its derivatives, so that a decomposition holding both shares them."""
        r2 = x * x + y * y + z * z
        if self.softening:
            r2 = r2 + self.softening**2
        return r2, self.envelope_radius**3 / (r2 * hy.sqrt(r2))

    def potential(self, offset: int = 0) -> hy.expression:
        return self.scale * self._envelope()[1] * self.network(offset)

    def member_layers_expressions(self, first: int) -> tuple:
        """One member's layers as heyoka expressions, its parameters at ``par[first:]``:
        (its output NN, each hidden layer's activations s_l, each layer's weights as rows
        of ``par`` expressions, the output layer's last). The expressions are those
        ``model.ffnn`` builds (a test holds them equal), so that a Taylor decomposition
        holding both shares them."""
        sizes = self.layer_sizes
        weight, bias = first, first + self.n_weights
        inputs, activations, weights = [x, y, z], [], []
        for n_in, n_out in zip(sizes[:-1], sizes[1:], strict=True):
            rows = [[hy.par[weight + i * n_in + j] for j in range(n_in)] for i in range(n_out)]
            weight += n_in * n_out
            layer = [
                hy.sum([w * v for w, v in zip(row, inputs, strict=True)] + [hy.par[bias + i]])
                for i, row in enumerate(rows)
            ]
            bias += n_out
            weights.append(rows)
            if len(weights) < len(sizes) - 1:
                inputs = [hy.tanh(a) for a in layer]
                activations.append(inputs)
        return layer[0], activations, weights

    def _member_derivatives(self, first: int) -> tuple:
        """One member's NN, its gradient (3) and Hessian entries (6) in the position.

        With a_l = W_l s_(l-1) + b_l, s_l = tanh(a_l) and u_l = dNN / ds_l (back from the
        output's weights, u_(l-1) = W_l^T ((1 - s_l^2) u_l)), the gradient is
        W_1^T ((1 - s_1^2) u_1); as affine maps have no curvature, the Hessian is
        sum_l T_l^T diag(-2 s_l (1 - s_l^2) u_l) T_l with T_l = d a_l / d q the layers'
        tangents (T_1 = W_1, T_l = W_l diag(1 - s_(l-1)^2) T_(l-1)): three directions
        carried forward through the layers instead of a reverse sweep of the gradient."""
        out, activations, weights = self.member_layers_expressions(first)
        slopes = [[1.0 - v * v for v in s] for s in activations]
        back = [None] * len(activations)
        back[-1] = weights[-1][0]
        for layer in range(len(activations) - 1, 0, -1):
            signal = [d * u for d, u in zip(slopes[layer], back[layer], strict=True)]
            rows = weights[layer]
            back[layer - 1] = [
                hy.sum([rows[i][j] * signal[i] for i in range(len(rows))])
                for j in range(len(rows[0]))
            ]
        first_signal = [d * u for d, u in zip(slopes[0], back[0], strict=True)]
        gradient = [
            hy.sum([row[k] * g for row, g in zip(weights[0], first_signal, strict=True)])
            for k in range(3)
        ]
        tangents = [weights[0]]
        for layer in range(1, len(activations)):
            carried = [
                [d * t for t in row] for d, row in zip(slopes[layer - 1], tangents[-1], strict=True)
            ]
            tangents.append(
                [
                    [
                        hy.sum([w * c[k] for w, c in zip(row, carried, strict=True)])
                        for k in (0, 1, 2)
                    ]
                    for row in weights[layer]
                ]
            )
        parts = {entry: [] for entry in HESSIAN_ENTRIES}
        for s, d, u, t in zip(activations, slopes, back, tangents, strict=True):
            curvature = [-2.0 * v * dv * uv for v, dv, uv in zip(s, d, u, strict=True)]
            for a in range(3):
                weighted = [c * row[a] for c, row in zip(curvature, t, strict=True)]
                for b in range(a, 3):
                    parts[a, b] += [w * row[b] for w, row in zip(weighted, t, strict=True)]
        return out, gradient, [hy.sum(parts[entry]) for entry in HESSIAN_ENTRIES]

    def parameter_rate_sum(
        self, params: np.ndarray, points: np.ndarray, directions: np.ndarray
    ) -> np.ndarray:
        """sum_k d (v_k . grad N(q_k)) / d theta (see :meth:`GravityTerm.parameter_rate_sum`),
        by reverse mode through the network's forward tangent: with the envelope's parts
        alpha_k = s v_k . grad E(q_k) and beta_k = s E(q_k), it is the gradient of
        sum_k alpha_k NN(q_k) + beta_k v_k . grad NN(q_k), each layer's weights the sum over
        the nodes of outer products (matrix products over all the nodes at once)."""
        points = np.asarray(points, dtype=float)
        directions = np.asarray(directions, dtype=float)
        r2 = np.einsum("ki,ki->k", points, points) + self.softening**2
        envelope = self.envelope_radius**3 / (r2 * np.sqrt(r2))
        # v . grad E = -3 E (q . v) / rho^2; the members' mean carries 1 / K
        alpha = (
            -3.0
            * self.scale
            / self.members
            * envelope
            * np.einsum("ki,ki->k", points, directions)
            / r2
        )
        beta = self.scale / self.members * envelope
        out = []
        for block in self.split_members(params):
            weights, biases = self.member_arrays(block)
            # forward: values x_l and tangents t_l (along v) of each layer's output, and the
            # tangents of its input to tanh, nodes first
            values, tangents, slopes, pre_tangents = [points], [directions], [], []
            for w, b in zip(weights[:-1], biases[:-1], strict=True):
                s = np.tanh(values[-1] @ w.T + b)
                d = 1.0 - s * s
                slopes.append(d)
                pre_tangents.append(tangents[-1] @ w.T)
                tangents.append(d * pre_tangents[-1])
                values.append(s)
            # reverse: adjoints of each layer's output value and tangent
            w_out = weights[-1][0]
            value_bar = alpha[:, None] * w_out
            tangent_bar = beta[:, None] * w_out
            grad_w = [None] * len(weights)
            grad_b = [None] * len(weights)
            grad_w[-1] = (alpha @ values[-1] + beta @ tangents[-1])[None, :]
            grad_b[-1] = np.array([alpha.sum()])
            for layer in range(len(weights) - 2, -1, -1):
                s, d = values[layer + 1], slopes[layer]
                pre_bar = value_bar * d - 2.0 * tangent_bar * pre_tangents[layer] * s * d
                pre_tangent_bar = tangent_bar * d
                grad_w[layer] = pre_bar.T @ values[layer] + pre_tangent_bar.T @ tangents[layer]
                grad_b[layer] = pre_bar.sum(axis=0)
                if layer:
                    value_bar = pre_bar @ weights[layer]
                    tangent_bar = pre_tangent_bar @ weights[layer]
            out.append(np.concatenate([g.ravel() for g in grad_w] + grad_b))
        return np.concatenate(out)

    def derivatives(self, offset: int = 0) -> tuple[list[hy.expression], list[hy.expression]]:
        """The gradient and Hessian of N = s E NN, E = (R_w / rho)^3, by the product rule from
        each member's (:meth:`_member_derivatives`) and the envelope's closed forms."""
        members = [
            self._member_derivatives(offset + k * self.member_params) for k in range(self.members)
        ]
        mean = 1.0 / self.members

        def averaged(values):
            return values[0] if self.members == 1 else hy.sum(list(values)) * mean

        net = averaged([m[0] for m in members])
        net_gradient = [averaged([m[1][k] for m in members]) for k in range(3)]
        net_hessian = [averaged([m[2][k] for m in members]) for k in range(6)]
        q = (x, y, z)
        r2, envelope = self._envelope()
        # grad E = -3 E q / rho^2, Hess E = 15 E q q^T / rho^4 - 3 E I / rho^2
        slope = -3.0 * envelope / r2
        envelope_gradient = [slope * qi for qi in q]
        bend = 15.0 * envelope / (r2 * r2)
        gradient = [
            self.scale * (net * g_e + envelope * g_n)
            for g_e, g_n in zip(envelope_gradient, net_gradient, strict=True)
        ]
        hessian = []
        for (a, b), h_n in zip(HESSIAN_ENTRIES, net_hessian, strict=True):
            h_e = bend * q[a] * q[b] + slope if a == b else bend * q[a] * q[b]
            cross = envelope_gradient[a] * net_gradient[b] + net_gradient[a] * envelope_gradient[b]
            hessian.append(self.scale * (net * h_e + cross + envelope * h_n))
        return gradient, hessian

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

    def without_output(self, params: np.ndarray) -> np.ndarray:
        """A copy of ``params`` (n_params,) with every member's output weights zero, so that
        NN is zero whatever the hidden layers: a start at no correction (the known part
        alone) that keeps the hidden layers' seeded variety. The output bias stays as given
        (zero in :meth:`initial_params`)."""
        params = np.array(params, dtype=float)
        last = self.layer_sizes[-2] * self.layer_sizes[-1]
        for block in self.split_members(params):  # views into params
            block[self.n_weights - last : self.n_weights] = 0.0
        return params

    def last_bias_index(self) -> int:
        """Index of the (last member's) output bias in the parameter layout."""
        return self.n_params - 1

    def key(self) -> str:
        members = f",x{self.members}" if self.members > 1 else ""
        softening = f",rc={self.softening!r}" if self.softening else ""
        return f"nn({self.hidden},{self.scale!r},{self.envelope_radius!r}{members}{softening})"

    def describe(self) -> dict:
        out = {
            "kind": self.kind,
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
        if self.softening:  # absent: (R_w / r)^3, as in files written before it existed
            out["envelope_softening"] = self.softening
        return out

    @classmethod
    def from_description(cls, d: dict) -> NeuralPotential:
        return cls(
            tuple(d["hidden"]),
            float(d["scale"]),
            float(d["envelope_radius"]),
            int(d.get("members", 1)),
            float(d.get("envelope_softening", 0.0)),
        )

    @property
    def title(self) -> str:
        return "network"

    def member_arrays(self, block: np.ndarray) -> tuple[list, list]:
        """One member's weights (out x in arrays, layer by layer) and biases from its
        parameter block (heyoka ``model.ffnn`` layout: all weights row-major, then all
        biases); views into ``block``."""
        sizes = self.layer_sizes
        weights, biases, k = [], [], 0
        for n_in, n_out in zip(sizes[:-1], sizes[1:], strict=True):
            weights.append(block[k : k + n_in * n_out].reshape(n_out, n_in))
            k += n_in * n_out
        for n_out in sizes[1:]:
            biases.append(block[k : k + n_out])
            k += n_out
        return weights, biases

    def member_layers(self, block: np.ndarray) -> dict:
        """One member's weights (out x in, layer by layer) and biases from its parameter block
        (:meth:`member_arrays`), as lists."""
        weights, biases = self.member_arrays(np.asarray(block, dtype=float))
        return {"weights": [w.tolist() for w in weights], "biases": [b.tolist() for b in biases]}

    def export_json(self, params=None) -> dict:
        return {
            "layer_sizes": list(self.layer_sizes),
            "activation": "tanh",
            "output_activation": "linear",
            "scale": self.scale,
            "envelope_radius": self.envelope_radius,
            "envelope_power": 3,
            "envelope_softening": self.softening,
            "members": [self.member_layers(b) for b in self.split_members(params)],
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


@register_term("sh")
@dataclass(frozen=True)
class SphericalHarmonics(GravityTerm):
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

    natural_regulariser = "kaula"

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
            "kind": self.kind,
            "degree": self.degree,
            "reference_radius": self.reference_radius,
            "mu": self.mu,
            "normalisation": "4pi, no Condon-Shortley phase (Montenbruck)",
            "layout": "l=2..L, m=0..l: C_lm then S_lm (m>0)",
        }

    @classmethod
    def from_description(cls, d: dict) -> SphericalHarmonics:
        return cls(int(d["degree"]), float(d["reference_radius"]), float(d["mu"]))

    @property
    def title(self) -> str:
        return f"SH degree {self.degree}"

    def kaula_weights(self) -> np.ndarray:
        """l^4 for each coefficient of degree l (Kaula's rule: sigma_l ~ 1 / l^2)."""
        return np.array([float(l) ** 4 for _, l, _ in sh_index(self.degree)])

    def expansion(self) -> tuple[int, float]:
        return self.degree, self.reference_radius

    def sh_tables(self, params, degree: int, reference_radius: float) -> SHTables:
        # shexpansion builds on this module's Legendre functions: imported on use
        from .shexpansion import sh_term_tables

        c, s = sh_term_tables(self, params, degree, reference_radius)
        exact = degree >= self.degree
        note = "exact" if exact else f"truncated at degree {degree}"
        return SHTables(c, s, exact, f"learned SH correction (degrees 2..{self.degree}): {note}")


@register_term("srp")
@dataclass(frozen=True)
class SolarRadiationPressure(GravityTerm):
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
            "kind": self.kind,
            "pressure_canonical": self.pressure_canonical,
            "sun_latitude_deg": self.sun_latitude_deg,
        }

    @classmethod
    def from_description(cls, d: dict) -> SolarRadiationPressure:
        return cls(float(d["pressure_canonical"]), float(d["sun_latitude_deg"]))


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


def term_from_description(d: dict) -> GravityTerm:
    """Rebuild a term from :meth:`GravityTerm.describe` output (model files), by the class
    registered under its ``kind``."""
    if not isinstance(d, dict):
        raise ValueError(f"a term description must be a JSON object, got {d!r}")
    kind = d.get("kind")
    if not isinstance(kind, str) or kind not in _REGISTRY:
        raise ValueError(f"unknown term kind {kind!r}")
    return _REGISTRY[kind].from_description(d)
