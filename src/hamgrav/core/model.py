"""A dynamical model: known terms, at most one learnable term, per-trajectory terms; compiled once.

Runtime-parameter layout of the compiled system (``heyoka.par``)::

    par[0 : n_learn]                        the learnable term's parameters (theta)
    par[n_learn : n_learn + n_trajectory]   the per-trajectory terms' parameters, term by term,
                                            for the trajectory being propagated

The truth is a model too: its one known term is its mascon set. A fit's global parameter
vector (theta, then optionally every trajectory's own parameters) is mapped to each arc's
runtime parameters by :class:`hamgrav.core.problem.ArcProblem`.

This module holds hamgrav's one compile cache: integrators (batch or scalar, plain or
variational) and field functions are compiled once per (structure key, tolerance, kind) and
reused; changing parameters never recompiles.
"""

from __future__ import annotations

import copy
import threading
from collections import OrderedDict
from dataclasses import dataclass, replace

import heyoka as hy
import numpy as np

from .hamiltonian import (
    POSITION,
    STATE_VARIABLES,
    equations_of_motion,
    rotating_hamiltonian,
    transition_equations,
)
from .terms import GravityTerm, term_from_description

__all__ = [
    "Model",
    "DEFAULT_FIT_TOLERANCE",
    "DEFAULT_SENSITIVITY_TOLERANCE",
    "TRUTH_TOLERANCE",
    "CompiledIntegrators",
    "compiled_integrators",
    "parameter_rate_function",
    "field_function",
    "evaluate_field",
    "laplacian_function",
    "evaluate_laplacian",
    "field_parameter_gradient_function",
    "evaluate_field_parameter_gradient",
    "hamiltonian_values",
    "cache_info",
]

#: Relative/absolute tolerance of fit propagations of states (costs, trials, predictions).
DEFAULT_FIT_TOLERANCE = 1e-12
#: Tolerance of fit propagations that carry the sensitivities (normal equations, information
#: matrices): order 13 instead of 15, 15-30 % less propagation time for a 721-parameter network
#: on the 112 Itokawa arcs (the more for smoother fields). Heyoka's bound is loose: against
#: 1e-12, the normal equations of those arcs differ by 3e-13 (A^T A) and 5e-13 (A^T r), the
#: cost by 4e-14, relative (tests/core/test_problem.py checks the agreement).
DEFAULT_SENSITIVITY_TOLERANCE = 1e-10
#: Tolerance of truth propagations (simulated tracking, true descents).
TRUTH_TOLERANCE = 1e-14


@dataclass(frozen=True, eq=False)
class Model:
    """``known`` terms (no runtime parameters), an optional ``learnable`` term and
    ``per_trajectory`` terms (parameters with one value per trajectory, e.g. SRP)."""

    known: tuple[GravityTerm, ...]
    learnable: GravityTerm | None = None
    per_trajectory: tuple[GravityTerm, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "known", tuple(self.known))
        object.__setattr__(self, "per_trajectory", tuple(self.per_trajectory))
        for term in self.known:
            if term.n_params or term.trajectory_params:
                raise ValueError(f"known term {term.key()} must not carry parameters")
        if self.learnable is not None and (
            self.learnable.trajectory_params or not self.learnable.n_params
        ):
            raise ValueError(f"learnable term {self.learnable.key()} must have shared parameters")
        for term in self.per_trajectory:
            if term.n_params or not term.trajectory_params:
                raise ValueError(f"per-trajectory term {term.key()} needs trajectory_params only")

    @property
    def n_learn(self) -> int:
        """Number of learnable (shared) parameters."""
        return 0 if self.learnable is None else self.learnable.n_params

    @property
    def n_trajectory_params(self) -> int:
        """Number of parameters each trajectory carries (all per-trajectory terms)."""
        return sum(t.trajectory_params for t in self.per_trajectory)

    @property
    def n_system_params(self) -> int:
        """Length of the compiled system's runtime-parameter vector."""
        return self.n_learn + self.n_trajectory_params

    def member(self) -> Model:
        """The model of one member of the learnable term's ensemble (fitted each on its own):
        the model itself unless the term is an ensemble."""
        if self.learnable is None or self.learnable.members == 1:
            return self
        return replace(self, learnable=self.learnable.member())

    def key(self) -> str:
        """Structure key: equal keys compile to the same code."""
        parts = [t.key() for t in self.known]
        parts.append("learn:" + (self.learnable.key() if self.learnable else "none"))
        parts.append("traj:" + (",".join(t.key() for t in self.per_trajectory) or "none"))
        return "|".join(parts)

    def potentials(self, which: str = "all") -> list[hy.expression]:
        """The potential terms: ``which`` = "all", "known", "learnable" or "total" (known
        plus learnable, without per-trajectory terms)."""
        if which not in ("all", "known", "learnable", "total"):
            raise ValueError(f"which must be all, known, learnable or total, got {which!r}")
        return [term.potential(offset) for term, offset in self._terms_at_offsets(which)]

    def _terms_at_offsets(self, which: str = "all") -> list[tuple[GravityTerm, int]]:
        """The terms of :meth:`potentials` ``which``, each with the offset of its runtime
        parameters."""
        out = [] if which == "learnable" else [(t, 0) for t in self.known]
        if which != "known" and self.learnable is not None:
            out.append((self.learnable, 0))
        if which == "all":
            offset = self.n_learn
            for term in self.per_trajectory:
                out.append((term, offset))
                offset += term.trajectory_params
        return out

    def potential_derivatives(self) -> tuple[list[hy.expression], list[hy.expression]]:
        """The gradient (3) and the Hessian's six entries
        (:data:`hamgrav.core.hamiltonian.HESSIAN_ENTRIES`) of the whole potential (every
        term, as :meth:`potentials` "all"), each term's as it forms them
        (:meth:`hamgrav.core.terms.GravityTerm.derivatives`)."""
        parts = [term.derivatives(offset) for term, offset in self._terms_at_offsets()]
        if not parts:
            zero = hy.expression(0.0)
            return [zero] * 3, [zero] * 6
        return (
            [hy.sum([g[k] for g, _ in parts]) for k in range(3)],
            [hy.sum([h[k] for _, h in parts]) for k in range(6)],
        )

    def hamiltonian(self) -> hy.expression:
        """The rotating-frame Hamiltonian of this model."""
        return rotating_hamiltonian(self.potentials())

    def system(self):
        """Hamilton's equations (heyoka system) of this model."""
        return equations_of_motion(self.hamiltonian())

    def describe(self) -> dict:
        """Plain-data description (JSON-able), enough to rebuild the model."""
        return {
            "known": [t.describe() for t in self.known],
            "learnable": self.learnable.describe() if self.learnable else None,
            "per_trajectory": [t.describe() for t in self.per_trajectory],
        }

    @classmethod
    def from_description(cls, d: dict) -> Model:
        """Rebuild a model from :meth:`describe` output."""
        return cls(
            known=tuple(term_from_description(t) for t in d["known"]),
            learnable=term_from_description(d["learnable"]) if d.get("learnable") else None,
            per_trajectory=tuple(term_from_description(t) for t in d.get("per_trajectory", [])),
        )


# ------------------------------------------------------------------------------ compile cache
_CACHE: OrderedDict[tuple, object] = OrderedDict()
_CACHE_SIZE = 48  # compiled objects kept; the oldest go first
_LOCK = threading.Lock()
_BUILDS: dict[str, int] = {}


def _cached(key: tuple, build):
    with _LOCK:
        if key in _CACHE:
            _CACHE.move_to_end(key)
            return _CACHE[key]
        _BUILDS[key[1]] = _BUILDS.get(key[1], 0) + 1
        value = build()
        _CACHE[key] = value
        while len(_CACHE) > _CACHE_SIZE:
            _CACHE.popitem(last=False)
        return value


def cache_info() -> dict[str, int]:
    """How many objects of each kind ("batch", "scalar", "field", "energy") were compiled in
    this process so far (a recompilation inside a loop shows up here)."""
    return dict(_BUILDS)


class CompiledIntegrators:
    """The compiled integrator of one model structure and independent copies of it, one per
    thread (copying does not recompile). ``lock`` serialises users of the set."""

    def __init__(self, integrator):
        self.integrators = [integrator]
        self.lock = threading.Lock()

    def take(self, n: int) -> list:
        """At least ``n`` integrators (copies made on first demand); hold ``lock`` to use them."""
        while len(self.integrators) < n:
            self.integrators.append(copy.deepcopy(self.integrators[0]))
        return self.integrators[:n]


def compiled_integrators(
    model: Model,
    *,
    variational: bool = False,
    wrt: str = "params",
    batch: bool = True,
    tol: float = DEFAULT_FIT_TOLERANCE,
) -> CompiledIntegrators:
    """The (cached) Taylor integrator of ``model``: in batch mode (SIMD width of this CPU) or
    scalar; with ``variational`` it also carries first-order sensitivities after the state:
    d state / d par for every runtime parameter (``wrt="params"``: 6 + 6 n_par state
    variables) or d state / d initial state (``wrt="state"``: 6 + 36, the state transition
    matrix)."""
    width = int(hy.recommended_simd_size()) if batch else 1
    if wrt not in ("params", "state"):
        raise ValueError(f"wrt must be 'params' or 'state', got {wrt!r}")

    def build():
        sys = model.system()
        n_par = model.n_system_params
        n_state = 6
        if variational and wrt == "state":
            sys = transition_equations(*model.potential_derivatives())
            n_state = 42
        elif variational:
            if n_par == 0:
                raise ValueError("a model with no runtime parameters has no sensitivities")
            sys = hy.var_ode_sys(sys, hy.var_args.params, order=1)
            n_state = 6 * (1 + n_par)
        kwargs = {"tol": tol, "compact_mode": True}
        if batch:
            state = np.zeros((n_state, width))
            state[0] = state[4] = 1.0
            if n_par:
                kwargs["pars"] = np.zeros((n_par, width))
            return CompiledIntegrators(hy.taylor_adaptive_batch(sys, state, **kwargs))
        state = np.zeros(n_state)
        state[0] = state[4] = 1.0
        if n_par:
            kwargs["pars"] = np.zeros(n_par)
        return CompiledIntegrators(hy.taylor_adaptive(sys, state, **kwargs))

    kind = (f"var-{wrt}" if variational else "plain") + ("-batch" if batch else "-scalar")
    return _cached((model.key(), "batch" if batch else "scalar", kind, float(tol), width), build)


def parameter_rate_function(model: Model):
    """Compiled (cached) rates of the adjoint's parameter accumulator, -(df/dp)^T lam, one per
    runtime parameter: a heyoka ``cfunc`` with inputs (x (6), lam (6)) and the runtime
    parameters as its ``pars``. The gradient of the cost is minus its integral over each arc
    (evaluated at the nodes of :func:`hamgrav.core.propagation.adjoint_gradient`)."""

    def build():
        if model.n_system_params == 0:
            raise ValueError("a model with no runtime parameters has no parameter gradient")
        sys = model.system()
        xs = [v for v, _ in sys]
        lam = list(hy.make_vars(*(f"adjoint_lam{i}" for i in range(6))))
        # -(df/dp)^T lam is minus the gradient of the one scalar lam . f: one reverse sweep,
        # cheaper to evaluate than the Jacobian's columns contracted one by one
        lam_dot_f = hy.sum([v * e for v, (_, e) in zip(lam, sys, strict=True)])
        params = [hy.par[j] for j in range(model.n_system_params)]
        grad = hy.diff_tensors([lam_dot_f], diff_args=params, diff_order=1).jacobian
        return hy.cfunc(
            [-grad[0, j] for j in range(len(params))], vars=[*xs, *lam], compact_mode=True
        )

    return _cached((model.key(), "parameter-rates"), build)


def field_function(model: Model, which: str = "learnable"):
    """Compiled (cached) potential and acceleration of part of ``model`` at body-fixed points:
    ``which`` = "learnable" (the correction N), "known" or "total" (both). Built from the
    same expressions as the dynamics, so the field and the dynamics cannot disagree.

    Returns a heyoka ``cfunc`` with outputs (V, a_x, a_y, a_z), inputs (x, y, z) and the
    learnable parameters as its ``pars``.
    """

    def build():
        if which == "learnable" and model.learnable is None:
            raise ValueError("the model has no learnable term")
        v = hy.sum(model.potentials(which))
        acc = [hy.diff(v, q) for q in POSITION]
        return hy.cfunc([v, *acc], vars=list(POSITION), compact_mode=True)

    if which not in ("learnable", "known", "total"):
        raise ValueError(f"which must be 'learnable', 'known' or 'total', got {which!r}")
    return _cached((model.key(), "field", which), build)


def evaluate_field(model: Model, params: np.ndarray, points: np.ndarray, which: str = "learnable"):
    """Potential (n,) and acceleration (n, 3) [canonical] of part of ``model`` (see
    :func:`field_function`) at ``points`` (n, 3); ``params[:n_learn]`` are the learnable ones."""
    f = field_function(model, which)
    points = np.ascontiguousarray(np.atleast_2d(np.asarray(points, dtype=float)).T)
    n = points.shape[1]
    n_learn = model.n_learn
    if which != "known" and n_learn:
        theta = np.asarray(params, float)[:n_learn, None]
        out = f(points, pars=np.ascontiguousarray(np.broadcast_to(theta, (n_learn, n))))
    else:
        out = f(points)
    return out[0], out[1:].T


def laplacian_function(model: Model):
    """Compiled (cached) Laplacian of the learnable term and its gradient with respect to the
    learnable parameters, at body-fixed points: a heyoka ``cfunc`` with outputs
    (lap N, d lap N / d theta_0, ..., d lap N / d theta_{n-1}), inputs (x, y, z) and the
    learnable parameters as its ``pars``. A perturbing potential is harmonic outside the body
    (lap V = 0 there), which a network, unlike an SH expansion, does not satisfy by
    construction."""

    def laplacian(v):
        return hy.sum([hy.diff(hy.diff(v, q), q) for q in POSITION])

    return _with_parameter_gradient(model, "laplacian", laplacian)


def field_parameter_gradient_function(model: Model):
    """Compiled (cached) potential N of the learnable term and its spatial gradient (the
    acceleration it adds), with their gradients with respect to the learnable parameters, at
    body-fixed points: a heyoka ``cfunc`` with outputs (N, dN/dx, dN/dy, dN/dz), then d/d theta_j
    of each of the four (value-major), inputs (x, y, z) and the learnable parameters as its
    ``pars`` (the rows of a fit of N to sampled values of a field,
    :class:`hamgrav.core.field_problem.FieldProblem`)."""
    return _with_parameter_gradient(
        model, "field-gradient", lambda v: [v, *(hy.diff(v, q) for q in POSITION)]
    )


def _with_parameter_gradient(model: Model, name: str, of):
    """The cached cfunc of the values ``of(N)`` (one expression or a list; N: the learnable
    term's potential) and their gradients with respect to the learnable parameters, value by
    value (see :func:`laplacian_function`)."""

    def build():
        if model.learnable is None or model.n_learn == 0:
            raise ValueError("the model has no learnable parameters")
        values = of(model.learnable.potential(0))
        values = values if isinstance(values, list) else [values]
        # every learnable parameter by name: diff_args.params would leave out those the
        # values do not contain, and shift the columns after them
        params = [hy.par[j] for j in range(model.n_learn)]
        grad = hy.diff_tensors(values, diff_args=params, diff_order=1).jacobian
        rows = [grad[i, j] for i in range(len(values)) for j in range(model.n_learn)]
        return hy.cfunc([*values, *rows], vars=list(POSITION), compact_mode=True)

    return _cached((model.key(), name), build)


def _evaluate_with_gradient(function, model: Model, params, points, n_values: int = 1):
    """(values (k, n_values), gradients (k, n_values, n_learn)) of a cfunc of
    :func:`_with_parameter_gradient` at ``points`` (k, 3)."""
    points = np.ascontiguousarray(np.atleast_2d(np.asarray(points, dtype=float)).T)
    n, k = model.n_learn, points.shape[1]
    # a cfunc counts parameters up to the last one its outputs use (none when no output
    # contains one: an SH gradient, linear in them)
    used = function.nparams
    if used:
        theta = np.asarray(params, float)[:used, None]
        out = function(points, pars=np.ascontiguousarray(np.broadcast_to(theta, (used, k))))
    else:
        out = function(points)
    return out[:n_values].T, out[n_values:].reshape(n_values, n, k).transpose(2, 0, 1)


def evaluate_laplacian(model: Model, params: np.ndarray, points: np.ndarray):
    """The Laplacian of the learnable term (k,) [canonical] at ``points`` (k, 3) and its
    gradient (k, n_learn) with respect to the learnable parameters ``params[:n_learn]``."""
    values, grad = _evaluate_with_gradient(laplacian_function(model), model, params, points)
    return values[:, 0], grad[:, 0]


def evaluate_field_parameter_gradient(model: Model, params: np.ndarray, points: np.ndarray):
    """The learnable term's potential and spatial gradient (N, dN/dx, dN/dy, dN/dz) (k, 4)
    [canonical] at ``points`` (k, 3), and their gradients (k, 4, n_learn) with respect to the
    learnable parameters ``params[:n_learn]``."""
    function = field_parameter_gradient_function(model)
    return _evaluate_with_gradient(function, model, params, points, n_values=4)


def hamiltonian_values(model: Model, states: np.ndarray, params=None, time: float = 0.0):
    """The value of H (the Jacobi integral when H does not depend on time) at canonical states
    (..., 6), with the model's runtime parameters ``params`` (n_system_params,)."""

    def build():
        return hy.cfunc([model.hamiltonian()], vars=list(STATE_VARIABLES), compact_mode=True)

    f = _cached((model.key(), "energy"), build)
    states = np.asarray(states, dtype=float)
    flat = np.ascontiguousarray(states.reshape(-1, 6).T)
    kwargs = {"time": np.full(flat.shape[1], float(time))}
    if model.n_system_params:
        p = np.asarray(params, float).reshape(-1, 1)
        kwargs["pars"] = np.ascontiguousarray(np.broadcast_to(p, (len(p), flat.shape[1])))
    return f(flat, **kwargs)[0].reshape(states.shape[:-1])
