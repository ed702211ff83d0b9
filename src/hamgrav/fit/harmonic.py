"""The harmonic penalty: a network's Laplacian pushed towards zero outside the body.

Outside the body a perturbing potential is harmonic. An SH expansion is harmonic by
construction; the network is not, and fitted to arcs it can bend freely between and below
them. The penalty adds 0.5 w sum_k ((r_k / R_w)^5 lap N(x_k))^2 over collocation points x_k
outside the body (canonical units) to the training objective of the LM fit (never to the
validation cost or the diagnostics): k residual rows with their exact parameter gradients.
The factor (r / R_w)^5 measures the Laplacian against the envelope's own scale (N ~ r^-3, so
lap N ~ r^-5): without it the points nearest the body, where the envelope is largest, would
outweigh all others.
"""

from __future__ import annotations

import numpy as np

from ..core.model import Model, evaluate_laplacian
from ..core.problem import Regulariser
from ..errors import InputError

__all__ = ["HarmonicPenalty", "DEFAULT_COLLOCATION_POINTS"]

#: Collocation points of the harmonic penalty (the weight is on their sum); drawn by
#: :func:`hamgrav.bodies.evaluation.exterior_points`.
DEFAULT_COLLOCATION_POINTS = 1500


class HarmonicPenalty(Regulariser):
    """0.5 ``weight`` sum_k ((r_k / R_w)^5 lap N(x_k))^2 for the learnable network of
    ``model`` at ``points`` (k, 3), canonical (R_w: the network's envelope radius);
    ``weight`` is dimensionless. The learnable term is one whose natural regulariser is this
    penalty (``natural_regulariser`` "harmonic": the network), with an ``envelope_radius``.

    :meth:`terms` gives the residual rows sqrt(weight) (r_k / R_w)^5 lap N(x_k) and their
    Jacobian with respect to the learnable parameters (the first ``n_learn`` of a problem's
    parameters)."""

    def __init__(self, model: Model, points: np.ndarray, weight: float):
        term = model.learnable
        if term is None or term.natural_regulariser != "harmonic":
            raise InputError("the harmonic penalty applies to a network (SH are harmonic already)")
        if not weight > 0:
            raise InputError(f"the harmonic penalty's weight must be positive, got {weight}")
        points = np.asarray(points, dtype=float)
        if points.ndim != 2 or points.shape[1] != 3 or not np.isfinite(points).all():
            raise InputError("collocation points must be a finite (k, 3) array")
        self.model = model
        self.points = points
        self.weight = float(weight)
        radius = model.learnable.envelope_distance(points)
        self._row_scale = np.sqrt(self.weight) * radius**5

    def terms(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Residual rows (k,) and their Jacobian (k, n_learn) at ``params``."""
        lap, grad = evaluate_laplacian(self.model, params, self.points)
        return self._row_scale * lap, self._row_scale[:, None] * grad

    def value(self, params: np.ndarray) -> float:
        """The penalty 0.5 w sum_k (lap N(x_k))^2 at ``params``."""
        rows, _ = self.terms(params)
        return 0.5 * float(rows @ rows)

    def describe(self) -> dict:
        """Plain-data summary for fit records."""
        return {"weight": self.weight, "collocation_points": len(self.points)}

    def record(self) -> dict:
        """The fit record's "harmonic" entry: :meth:`describe`."""
        return {"harmonic": self.describe()}
