"""A fitted model: structure, parameters, body, units and how it was obtained."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.arcs import BodyRecord
from ..core.model import Model

__all__ = ["FittedModel"]


@dataclass(frozen=True, eq=False)
class FittedModel:
    """The result of a fit, in canonical units of its body (plain data; saved by
    :func:`hamgrav.io.models.save_model`).

    Attributes:
        model: the dynamical model (known terms, learnable term, per-trajectory terms).
        params: the global parameter vector: learnable parameters, then (when
            ``estimate_trajectory_params``) each trajectory's own parameters,
            trajectory-major (e.g. SRP area-to-mass [m^2/kg]).
        body_name: the body; gm_m3_s2 [m^3/s^2] and spin_period_s [s] fix the units.
        body_origin_m: the frame origin [m] in the body mesh's frame.
        estimate_trajectory_params: whether ``params`` carries per-trajectory parameters.
        prior: description of the known part (e.g. the shape-prior report), plain data.
        solver: solver name, settings and outcome, plain data.
        history: per-iteration records (lists of numbers keyed by name), plain data.
        stages: per-stage summaries of a continual fit.
        training: what the model was fitted to, so that it is evaluated against the same
            truth anywhere: ``arcs_sha256`` and ``truth_sha256`` (:meth:`Arcs.digest`,
            :meth:`Arcs.truth_digest`) and, when fitted from a file, ``arcs_file`` (absolute).
            Empty for files written before hamgrav recorded it.
        body: the body the model was fitted for (mesh, constants, provenance, in the
            model's frame), or None in files written before hamgrav recorded it.
    """

    model: Model
    params: np.ndarray
    body_name: str
    gm_m3_s2: float
    spin_period_s: float
    body_origin_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    estimate_trajectory_params: bool = False
    prior: dict = field(default_factory=dict)
    solver: dict = field(default_factory=dict)
    history: dict = field(default_factory=dict)
    stages: list = field(default_factory=list)
    training: dict = field(default_factory=dict)
    body: BodyRecord | None = None

    @property
    def learnable_params(self) -> np.ndarray:
        """The learnable term's parameters (n_learn,)."""
        return np.asarray(self.params)[: self.model.n_learn]
