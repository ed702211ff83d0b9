"""The field anchor: a refit's learned field held near its warm start where new arcs do not reach.

A warm refit on a few new arcs (descents, say) trains on every arc so far, but the arcs say
nothing about the field far from where they fly; an LM refit of a flexible network still moves
it there, and a refit that improves the field along the new arcs can spoil it elsewhere. The
anchor adds to the training objective (never to the validation cost) the rows

    sqrt(w) (r_k / R_w)^4 (a(x_k; p) - a(x_k; p_0))

at points x_k away from the new arcs (a: the learnable term's acceleration, canonical; p_0:
the warm start; R_w: the network's envelope radius; the factor (r / R_w)^4 weighs points by
the envelope's own fall-off, a ~ r^-4, as the harmonic penalty does its Laplacian), with their
exact Gauss-Newton Jacobians. The weight w is dimensionless and measured like the harmonic
penalty's (:mod:`hamgrav.fit.harmonic`): on the sum over the points, against the arcs' cost in
canonical units. With ``quantity="potential"`` the rows are instead

    sqrt(w) (N(x_k; p) - N(x_k; p_0))

on the learned potential N itself, with no radial factor: every point weighs the change of
the potential as the relative field error does (a sum of squared potential differences), so
the anchor holds the field near the surface (where the envelope (R_w / r)^3 amplifies a
change of the network) as firmly as the acceleration form holds it far out.

The formal covariance (:mod:`hamgrav.fit.covariance`) leaves the anchor out: it holds the fit
near an earlier fit of the same arcs, whose information the covariance already counts.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..core.model import Model, evaluate_field_parameter_gradient
from ..core.problem import Regulariser
from ..errors import InputError

ANCHOR_QUANTITIES = ("acceleration", "potential")

__all__ = [
    "ANCHOR_QUANTITIES",
    "Anchor",
    "FieldAnchor",
    "AnchorSettings",
    "RowRegularisers",
    "anchor_points",
    "points_clear_of",
]


@dataclass(frozen=True, eq=False)
class AnchorSettings:
    """How a warm refit is anchored (see the module): ``weight`` w (dimensionless, > 0) of the
    anchor's rows; ``clearance`` [canonical length, >= 0] frees the collocation points within
    that distance of any sample of the new arcs, or of the positions ``clear_of`` (..., 3)
    [canonical] when given (e.g. a control refit without the new arcs, anchored at the same
    points as the refit with them); ``quantity``: "acceleration" or "potential", the rows of
    the module."""

    weight: float
    clearance: float
    clear_of: np.ndarray | None = None
    quantity: str = "acceleration"

    def __post_init__(self):
        if not (np.isfinite(self.weight) and self.weight > 0):
            raise InputError(f"the anchor's weight must be positive, got {self.weight}")
        if not (np.isfinite(self.clearance) and self.clearance >= 0):
            raise InputError(f"the anchor's clearance must be >= 0, got {self.clearance}")
        if self.quantity not in ANCHOR_QUANTITIES:
            raise InputError(
                f"the anchor holds {' or '.join(ANCHOR_QUANTITIES)}, got {self.quantity!r}"
            )


@dataclass(frozen=True, eq=False)
class Anchor:
    """A field anchor as a fit takes it (:meth:`hamgrav.fit.estimator.GravityEstimator.fit`):
    ``points`` (k, 3) [canonical], ``weight`` w, ``quantity`` (see the module) and
    ``target``, parameters laid out as the fit's ``init`` (the learnable ones first) whose
    learned field is held (None: ``init`` itself; an ensemble's members each held near
    their own block)."""

    points: np.ndarray
    weight: float
    quantity: str = "acceleration"
    target: np.ndarray | None = None

    @classmethod
    def of(cls, value) -> Anchor | None:
        """``value`` as an :class:`Anchor`: one already, None, or a tuple (points, weight[,
        quantity[, target]])."""
        if value is None or isinstance(value, cls):
            return value
        return cls(*value)

    def record(self) -> dict:
        """The fit record's "anchor" entry (the quantity when not the acceleration)."""
        out = {"weight": float(self.weight), "points": len(self.points)}
        if self.quantity != "acceleration":
            out["quantity"] = self.quantity
        return out


def anchor_points(
    collocation: np.ndarray, new_samples: np.ndarray, settings: AnchorSettings, brillouin_radius
) -> np.ndarray:
    """The anchor's points under ``settings``: the ``collocation`` points (k, 3) farther than
    ``settings.clearance`` from every one of ``new_samples`` (..., 3), or of
    ``settings.clear_of`` when given (canonical); refused when none is left."""
    clear_of = new_samples if settings.clear_of is None else settings.clear_of
    points = points_clear_of(collocation, clear_of, settings.clearance)
    if not len(points):
        raise InputError(
            f"no collocation point lies farther than {settings.clearance:g} (canonical; "
            f"{settings.clearance / brillouin_radius:.3g} R_B) from the new arcs: give the "
            "anchor a smaller clearance (--anchor-clearance-m)"
        )
    return points


def points_clear_of(points: np.ndarray, samples: np.ndarray, clearance: float) -> np.ndarray:
    """The rows of ``points`` (k, 3) farther than ``clearance`` from every one of ``samples``
    (..., 3) (one canonical length unit for all; samples that are not finite are left
    out)."""
    points = np.asarray(points, dtype=float)
    samples = np.asarray(samples, dtype=float)
    if samples.shape[-1] != 3:
        raise InputError(f"samples must be positions (..., 3), got shape {samples.shape}")
    samples = samples.reshape(-1, 3)
    samples = samples[np.isfinite(samples).all(axis=1)]  # a sample never propagated
    if clearance <= 0 or not len(samples):
        return points
    nearest, _ = cKDTree(samples).query(points)
    return points[nearest > clearance]


class FieldAnchor(Regulariser):
    """The anchor rows of the module at ``points`` (k, 3, canonical) towards the learnable
    field of ``model`` at ``target`` (its first ``n_learn`` entries), with ``weight`` w
    (dimensionless), on the learned field's ``quantity`` ("acceleration": :meth:`terms` gives
    3k rows and their Jacobian (3k, n_learn); "potential": k rows, (k, n_learn))."""

    def __init__(
        self,
        model: Model,
        points: np.ndarray,
        target: np.ndarray,
        weight: float,
        quantity: str = "acceleration",
    ):
        term = model.learnable
        if term is None or model.n_learn == 0 or term.natural_regulariser != "harmonic":
            raise InputError(
                "the field anchor needs a network (a learnable term with the harmonic penalty)"
            )
        if not (np.isfinite(weight) and weight > 0):
            raise InputError(f"the anchor's weight must be positive, got {weight}")
        points = np.asarray(points, dtype=float)
        if points.ndim != 2 or points.shape[1] != 3 or not len(points):
            raise InputError("the anchor needs a nonempty (k, 3) array of points")
        if not np.isfinite(points).all():
            raise InputError("the anchor's points must be finite")
        if quantity not in ANCHOR_QUANTITIES:
            raise InputError(f"the anchor holds {' or '.join(ANCHOR_QUANTITIES)}, got {quantity!r}")
        self.model = model
        self.points = points
        self.weight = float(weight)
        self.quantity = quantity
        # columns of evaluate_field_parameter_gradient: N, then its spatial gradient
        self._columns = slice(0, 1) if quantity == "potential" else slice(1, 4)
        radial = 1.0
        if quantity == "acceleration":
            radial = term.envelope_distance(points) ** 4
        self._row_scale = np.sqrt(self.weight) * np.broadcast_to(radial, len(points))
        target = np.asarray(target, dtype=float)[: model.n_learn]
        values, _ = evaluate_field_parameter_gradient(model, target, points)
        self._target = values[:, self._columns].copy()

    def terms(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Residual rows (3k, or k for the potential) and their Jacobian (rows, n_learn) at
        ``params``."""
        values, grad = evaluate_field_parameter_gradient(self.model, params, self.points)
        rows = self._row_scale[:, None] * (values[:, self._columns] - self._target)
        jac = self._row_scale[:, None, None] * grad[:, self._columns, :]
        return rows.reshape(-1), jac.reshape(-1, jac.shape[-1])

    def describe(self) -> dict:
        """Plain-data summary for fit records (the quantity when not the acceleration)."""
        out = {"weight": self.weight, "points": len(self.points)}
        if self.quantity != "acceleration":
            out["quantity"] = self.quantity
        return out

    def record(self) -> dict:
        """The fit record's "anchor" entry: :meth:`describe`."""
        return {"anchor": self.describe()}


class RowRegularisers(Regulariser):
    """Several regularisers of residual rows as one: their rows stacked (e.g. the harmonic
    penalty and the field anchor); a diagonal prior is refused (it stays out of the rows)."""

    def __init__(self, *parts: Regulariser):
        self.parts = [p for p in parts if p is not None]
        if not self.parts:
            raise InputError("no regulariser to combine")
        if any(p.diagonal() is not None for p in self.parts):
            raise InputError(
                "a diagonal prior (Kaula's rule) does not combine with residual rows: "
                "anchor a network fit, not an SH one"
            )

    def terms(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The parts' rows and Jacobians, stacked in order."""
        pieces = [p.terms(params) for p in self.parts]
        return (
            np.concatenate([rows for rows, _ in pieces]),
            np.concatenate([jac for _, jac in pieces], axis=0),
        )

    def describe(self) -> dict:
        """The parts' summaries, each under its record's name (as :meth:`record`)."""
        return self.record()

    def record(self) -> dict:
        """The parts' record entries, merged."""
        out: dict = {}
        for p in self.parts:
            out |= p.record()
        return out
