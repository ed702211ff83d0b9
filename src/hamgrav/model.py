"""A dynamical model: known terms plus (at most) one learnable term, compiled once.

Runtime-parameter layout of the compiled system::

    par[0 : n_learn]              the learnable term's parameters (theta)
    par[n_learn]                  the SRP area-to-mass coefficient of the arc being propagated
                                  (only when the model has an SRP term)

The global parameter vector handed to solvers is theta followed, when SRP coefficients are
estimated, by one coefficient per trajectory; :class:`Model` maps it to each arc's runtime
parameters and scatters the arc's sensitivity columns back (see :mod:`hamgrav.sensitivity`).

Compiled integrators (plain and variational, batch mode) and field functions are cached per
structure key and tolerance: changing parameters never recompiles.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import heyoka as hy
import numpy as np

from .hamiltonian import POSITION, equations_of_motion, rotating_hamiltonian
from .terms import SolarRadiationPressure, Term, term_from_description

__all__ = [
    "Model",
    "DEFAULT_FIT_TOLERANCE",
    "compiled_integrator",
    "compiled_scalar_integrator",
    "field_functions",
    "evaluate_field",
]

#: Tolerance of fit propagations (state and sensitivities).
DEFAULT_FIT_TOLERANCE = 1e-12

_CACHE: dict[tuple, object] = {}
_LOCK = threading.Lock()


@dataclass(frozen=True, eq=False)
class Model:
    """``known`` terms (each with no learnable parameters) plus an optional ``learnable`` term
    and an optional SRP term whose per-trajectory coefficients are data or estimated."""

    known: tuple[Term, ...]
    learnable: Term | None = None
    srp: SolarRadiationPressure | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "known", tuple(self.known))
        for term in self.known:
            if term.n_params or term.arc_params:
                raise ValueError(f"known term {term.key()} must not carry parameters")

    @property
    def n_learn(self) -> int:
        return 0 if self.learnable is None else self.learnable.n_params

    @property
    def n_system_params(self) -> int:
        return self.n_learn + (1 if self.srp is not None else 0)

    def key(self) -> str:
        parts = [t.key() for t in self.known]
        parts.append("learn:" + (self.learnable.key() if self.learnable else "none"))
        parts.append("srp:" + (self.srp.key() if self.srp else "none"))
        return "|".join(parts)

    def potentials(self) -> list[hy.expression]:
        terms = [t.potential() for t in self.known]
        if self.learnable is not None:
            terms.append(self.learnable.potential(0))
        if self.srp is not None:
            terms.append(self.srp.potential(self.n_learn))
        return terms

    def total_potential(self) -> hy.expression:
        return hy.sum(self.potentials())

    def hamiltonian(self) -> hy.expression:
        return rotating_hamiltonian(self.potentials())

    def system(self):
        return equations_of_motion(self.hamiltonian())

    def describe(self) -> dict:
        return {
            "known": [t.describe() for t in self.known],
            "learnable": self.learnable.describe() if self.learnable else None,
            "srp": self.srp.describe() if self.srp else None,
        }

    @classmethod
    def from_description(cls, d: dict) -> Model:
        """Rebuild a model from :meth:`describe` output."""
        return cls(
            known=tuple(term_from_description(t) for t in d["known"]),
            learnable=term_from_description(d["learnable"]) if d.get("learnable") else None,
            srp=term_from_description(d["srp"]) if d.get("srp") else None,
        )


def _cached(key: tuple, build):
    with _LOCK:
        if key not in _CACHE:
            _CACHE[key] = build()
        return _CACHE[key]


def compiled_integrator(
    model: Model,
    *,
    variational: bool,
    tol: float = DEFAULT_FIT_TOLERANCE,
    batch_size: int | None = None,
):
    """The (cached) batch-mode Taylor integrator of ``model``; with ``variational`` it also
    carries d state / d par for every runtime parameter (first order), i.e. 6 + 6 n_par
    state variables, the sensitivities after the state."""
    batch = int(batch_size or hy.recommended_simd_size())

    def build():
        sys = model.system()
        n_par = model.n_system_params
        if variational:
            if n_par == 0:
                raise ValueError("a model with no runtime parameters has no sensitivities")
            sys = hy.var_ode_sys(sys, hy.var_args.params, order=1)
            n_state = 6 * (1 + n_par)
        else:
            n_state = 6
        state = np.zeros((n_state, batch))
        state[0] = 1.0
        state[4] = 1.0
        pars = np.zeros((max(n_par, 1), batch)) if n_par else None
        kwargs = {"tol": tol, "compact_mode": True}
        if pars is not None:
            kwargs["pars"] = pars
        return hy.taylor_adaptive_batch(sys, state, **kwargs)

    return _cached((model.key(), "var" if variational else "plain", tol, batch), build)


def compiled_scalar_integrator(model: Model, tol: float = DEFAULT_FIT_TOLERANCE):
    """The (cached) scalar Taylor integrator of ``model`` (no sensitivities), for long single
    propagations such as descents; set ``ta.pars`` before use."""

    def build():
        kwargs = {"tol": tol, "compact_mode": True}
        if model.n_system_params:
            kwargs["pars"] = np.zeros(model.n_system_params)
        return hy.taylor_adaptive(model.system(), [1.0, 0, 0, 0, 1.0, 0], **kwargs)

    return _cached((model.key(), "scalar", tol), build)


def field_functions(model: Model, which: str = "learnable"):
    """Compiled (cached) potential and acceleration of part of ``model`` at body-fixed points:
    ``which`` = "learnable" (the correction N), "known" or "total". Built from the same
    expressions as the dynamics, so the field and the dynamics cannot disagree.

    Returns a heyoka ``cfunc`` with outputs (V, a_x, a_y, a_z) and inputs (x, y, z).
    """

    def build():
        if which == "learnable":
            if model.learnable is None:
                raise ValueError("the model has no learnable term")
            v = model.learnable.potential(0)
        elif which == "known":
            v = hy.sum([t.potential() for t in model.known])
        elif which == "total":
            v = hy.sum(
                [t.potential() for t in model.known]
                + ([model.learnable.potential(0)] if model.learnable else [])
            )
        else:
            raise ValueError("which must be 'learnable', 'known' or 'total'")
        acc = [hy.diff(v, q) for q in POSITION]
        return hy.cfunc([v, *acc], vars=list(POSITION), compact_mode=True)

    return _cached((model.key(), "field", which), build)


def evaluate_field(model: Model, params: np.ndarray, points: np.ndarray, which: str = "learnable"):
    """Potential (n,) and acceleration (n, 3) of part of ``model`` at ``points`` (n, 3)."""
    f = field_functions(model, which)
    points = np.ascontiguousarray(np.atleast_2d(points).T)
    n = points.shape[1]
    n_learn = model.n_learn
    if which != "known" and n_learn:
        pars = np.ascontiguousarray(
            np.broadcast_to(np.asarray(params, float)[:n_learn, None], (n_learn, n))
        )
        out = f(points, pars=pars)
    else:
        out = f(points)
    return out[0], out[1:].T
