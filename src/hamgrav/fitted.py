"""A fitted model: structure, parameters, body, units and how it was obtained."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .model import Model

__all__ = ["FittedModel"]


@dataclass(frozen=True, eq=False)
class FittedModel:
    """The result of a fit, in canonical units of its body.

    Attributes:
        model: the dynamical model (known terms, learnable term, SRP).
        params: the global parameter vector: learnable parameters, then (when
            ``estimate_srp``) one SRP area-to-mass coefficient [m^2/kg] per trajectory.
        estimate_srp: whether ``params`` carries SRP coefficients.
        body_name, gm_m3_s2, spin_period_s, body_origin_m: the body and the frame.
        prior: description of the known part (e.g. the shape-prior report), plain data.
        solver: solver name and settings, plain data.
        history: per-iteration records (lists of numbers keyed by name), plain data.
        stages: per-stage summaries of a continual fit.
    """

    model: Model
    params: np.ndarray
    body_name: str
    gm_m3_s2: float
    spin_period_s: float
    body_origin_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    estimate_srp: bool = False
    prior: dict = field(default_factory=dict)
    solver: dict = field(default_factory=dict)
    history: dict = field(default_factory=dict)
    stages: list = field(default_factory=list)

    @property
    def learnable_params(self) -> np.ndarray:
        return np.asarray(self.params)[: self.model.n_learn]
