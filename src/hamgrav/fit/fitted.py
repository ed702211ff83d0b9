"""A fitted model: structure, parameters, body, units and how it was obtained; its gravity
field at points in metres."""

from __future__ import annotations

import hashlib
import math
import os
import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from ..core.arcs import BodyRecord
from ..core.model import Model, evaluate_field
from ..errors import HamgravWarning, InputError
from ..units import CanonicalUnits

__all__ = ["FittedModel", "FIELD_PARTS", "FRAME_TOLERANCE_M"]

#: Frame origins [m] closer than this are the same frame (see :meth:`FittedModel.same_frame`).
FRAME_TOLERANCE_M = 1e-6

#: The parts of a fitted field that :meth:`FittedModel.potential` and
#: :meth:`FittedModel.acceleration` evaluate: "total" = "central" + "known" + "correction"
#: ("learnable" is another name for "correction"). Per-trajectory terms (SRP) are never part
#: of the field.
FIELD_PARTS = ("total", "central", "known", "correction", "learnable")


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

    @property
    def units(self) -> CanonicalUnits:
        """The canonical units of the fit (from ``gm_m3_s2`` and ``spin_period_s``)."""
        return CanonicalUnits(self.gm_m3_s2, self.spin_period_s)

    # ------------------------------------------------------------ belonging together
    def same_frame(self, origin_m) -> bool:
        """Whether ``origin_m`` [m, mesh frame] is this model's frame origin: within a
        micrometre (truths of one body drawn with other seeds differ by round-off in their
        centre of mass; their own digests tell them apart)."""
        return math.dist(tuple(origin_m), tuple(self.body_origin_m)) <= FRAME_TOLERANCE_M

    def check_arcs(self, arcs, source, name: str, fix: str) -> None:
        """Refuse ``arcs`` (read from ``source``) that do not belong with this model (called
        ``name`` in the message): another body, another body model (GM, spin period: the
        canonical units would not fit) or another frame origin; ``fix`` ends the message."""
        if arcs.body_name != self.body_name:
            raise InputError(
                f"arcs {source} are of body {arcs.body_name!r}, {name} of {self.body_name!r}; {fix}"
            )
        for what, unit in (("gm_m3_s2", "m^3/s^2"), ("spin_period_s", "s")):
            if not math.isclose(getattr(arcs, what), getattr(self, what), rel_tol=1e-12):
                raise InputError(
                    f"arcs {source} have {what} {getattr(arcs, what)!r} {unit}, {name} "
                    f"{getattr(self, what)!r} {unit} (another body model); {fix}"
                )
        if not self.same_frame(arcs.body_origin_m):
            raise InputError(
                f"arcs {source} are in a frame with origin {arcs.body_origin_m} m, {name} in "
                f"one with origin {self.body_origin_m} m (another campaign); {fix}"
            )

    def recorded_arcs_file(self):
        """The file of the arcs this model was fitted to, as recorded at the fit (its
        ``training`` record, else its ``solver`` record; an absolute path when written by
        :meth:`with_arcs_file`), or None when none is recorded. Returned as stored: a file
        that lies may record something that is not a path (callers check)."""
        return self.training.get("arcs_file") or self.solver.get("arcs_file") or None

    def check_truth(
        self,
        arcs,
        source,
        name: str = "the model",
        fix: str = "pass the arcs of this model's campaign",
        record: str | None = None,
    ) -> None:
        """Refuse ``arcs`` (read from ``source``) whose truth is not the one this model was
        fitted against (their :meth:`Arcs.truth_digest` differs from ``training``'s
        ``truth_sha256``); ``name`` names the model in the message, ``fix`` ends it. A model
        fitted to arcs without a truth (imported tracking) accepts any truth; a model that
        records no truth digest (older hamgrav) is compared unchecked, with a
        :class:`HamgravWarning` naming ``record`` (default ``name``)."""
        if "truth_sha256" not in self.training:
            warnings.warn(
                f"{record or name} does not record the truth it was fitted against "
                f"(older hamgrav); comparing with the truth of {source} unchecked",
                HamgravWarning,
                3,
            )
            return
        truth = self.training["truth_sha256"]
        if truth is not None and arcs.truth_digest() != truth:
            raise InputError(
                f"arcs {source} hold another truth than the one {name} was fitted against "
                f"(truth digests differ); {fix}"
            )

    def sh_expansion(self) -> tuple[int, float] | None:
        """(degree, reference radius [canonical]) when the learned term is an SH expansion
        of its own (exported exactly at that degree and radius), else None (a network, or
        no learned term)."""
        term = self.model.learnable
        return None if term is None else term.expansion()

    def params_sha256(self) -> str:
        """SHA-256 (hex) of the parameter vector's float64 bytes (what a continued fit
        started from)."""
        return hashlib.sha256(np.ascontiguousarray(self.params, np.float64).tobytes()).hexdigest()

    def stage_record(self) -> dict:
        """This fit as a stage of a continual fit (plain data): arcs, validation arcs, solver,
        outcome, iterations, cost, wall time, held-out cost relative to no correction and
        where it was checked, and the arcs file."""
        keys = ("n_arcs", "n_validation", "solver", "outcome", "iterations", "cost", "wall_s")
        diagnostics = self.solver.get("diagnostics") or {}
        return (
            {k: self.solver.get(k) for k in keys}
            | {k: diagnostics.get(k) for k in ("relative_cost", "checked_on")}
            | {"arcs_file": self.solver.get("arcs_file")}
        )

    def with_arcs_file(self, path) -> FittedModel:
        """This model recording ``path`` (absolute) as the file of the arcs it was fitted to,
        in its solver and training records and in its last stage."""
        path = os.path.abspath(path)
        stages = [dict(stage) for stage in self.stages]
        if stages:
            stages[-1]["arcs_file"] = path
        return replace(
            self,
            solver={**self.solver, "arcs_file": path},
            training={**self.training, "arcs_file": path},
            stages=stages,
        )

    def potential(self, points_m, which: str = "total") -> np.ndarray:
        """Gravitational potential V [m^2/s^2] at ``points_m`` [m], shape (n, 3) or (3,);
        returns (n,) or a scalar array.

        Frame: the fit's body-fixed frame, whose origin is ``body_origin_m`` in the body mesh's
        frame (a point p of the mesh's frame is ``p - body_origin_m`` here). Sign: hamgrav's V
        is positive, V = GM / r for a point mass, and the acceleration is +grad V.

        ``which`` (default "total"): "total" is the whole gravity field, known part plus
        learned correction; "central" is GM / r with the body's GM (``gm_m3_s2``); "known" is
        the known part beyond the central term (the shape prior's departure from a point mass;
        zero for a point-mass known part); "correction" (or "learnable") is the learned term
        (zero for a model without one). The parts add up to the total. Note that
        :func:`hamgrav.core.model.evaluate_field`'s "known" includes the central term.
        Per-trajectory terms (SRP) are never part of the field. The field is not finite at
        the origin (nor at a mascon of the model).
        """
        return self._field(points_m, which)[0]

    def acceleration(self, points_m, which: str = "total") -> np.ndarray:
        """Gravitational acceleration grad V [m/s^2] of ``which`` part at ``points_m`` [m],
        shape (n, 3) or (3,); returns (n, 3) or (3,). Frame, sign and parts as in
        :meth:`potential` (it points towards the body: -GM r / r^3 for a point mass)."""
        return self._field(points_m, which)[1]

    def _field(self, points_m, which: str) -> tuple[np.ndarray, np.ndarray]:
        """Potential [m^2/s^2] and acceleration [m/s^2] of part ``which`` at points [m]."""
        if which not in FIELD_PARTS:
            raise InputError(
                f"which must be one of {', '.join(FIELD_PARTS)}, got {which!r}; "
                "'total' is the whole gravity field"
            )
        points, single = _points_m(points_m)
        if not len(points):
            return np.zeros(0), np.zeros((0, 3))
        units = self.units
        q = units.to_length(points)
        with np.errstate(divide="ignore", invalid="ignore"):  # the origin: inf or NaN, no warning
            v, a = self._canonical_field(q, which)
        v, a = units.from_potential(v), units.from_acceleration(a)
        return (v[0], a[0]) if single else (v, a)

    def _canonical_field(self, q: np.ndarray, which: str) -> tuple[np.ndarray, np.ndarray]:
        """Potential and acceleration [canonical] of part ``which`` at canonical points q."""
        if which in ("total", "central", "known"):
            r = np.linalg.norm(q, axis=1)
            v_central, a_central = 1.0 / r, -q / r[:, None] ** 3  # GM = 1 canonical
        if which == "total":
            return evaluate_field(self.model, self.params, q, "total")
        if which == "central":
            return v_central, a_central
        if which == "known":
            # the numerics' known part holds the central term (a point mass, or the prior's
            # whole mass): take it out so that the parts add up to the total
            v, a = evaluate_field(self.model, self.params, q, "known")
            return v - v_central, a - a_central
        if self.model.learnable is None:
            return np.zeros(len(q)), np.zeros_like(q)
        return evaluate_field(self.model, self.params, q, "learnable")


def _points_m(points_m) -> tuple[np.ndarray, bool]:
    """``points_m`` as a finite (n, 3) float array [m], and whether one point (3,) was given."""
    try:
        points = np.array(points_m, dtype=float)
    except (TypeError, ValueError):
        raise InputError(
            "points_m must be numbers [m] of shape (n, 3) or (3,); give x, y, z per point"
        ) from None
    single = points.shape == (3,)
    if single:
        points = points[None]
    if points.ndim != 2 or points.shape[1] != 3:
        raise InputError(
            f"points_m must have shape (n, 3) or (3,), got {points.shape}; give x, y, z [m] "
            "per point"
        )
    bad = ~np.isfinite(points).all(axis=1)
    if bad.any():
        raise InputError(
            f"points_m has {int(bad.sum())} point(s) with a non-finite coordinate (first: row "
            f"{int(np.argmax(bad))}); give finite x, y, z [m]"
        )
    return points, single
