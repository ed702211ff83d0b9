"""The field least-squares problem: the learnable term fitted to sampled potential values.

Where :class:`~hamgrav.core.problem.ArcProblem` fits a model to tracked arcs, a
:class:`FieldProblem` fits its learnable term N directly to values V_k of a perturbing
potential at points x_k: residuals r_k = s (V_k - N(x_k)) with one scale s, and their exact
parameter gradients from a compiled ``cfunc``
(:func:`hamgrav.core.model.evaluate_potential_gradient`). It is the oracle of a
representation: how well the term can carry a known field where it is sampled, and away from
it. The solvers see it through :class:`~hamgrav.core.problem.LeastSquaresProblem` (each
sample point is one unit they select by index, as they select arcs), so the same
Levenberg-Marquardt runs on both.
"""

from __future__ import annotations

import hashlib
import json

import numpy as np

from .model import Model, evaluate_field, evaluate_potential_gradient
from .problem import LeastSquaresProblem, Regulariser

__all__ = ["FieldProblem"]


class FieldProblem(LeastSquaresProblem):
    """Least squares of the learnable term of ``model`` on potential ``values`` (k,) at
    ``points`` (k, 3), canonical: r = ``scale`` (values - N(points)).

    Args:
        model: a model with a learnable term (its known terms are not used).
        points: (k, 3) body-fixed sample points, canonical.
        values: (k,) the perturbing potential to fit at them, canonical.
        scale: the residuals' factor s > 0; default 1 / (rms(values) sqrt(k)), which makes
            J half the squared relative error of the fit over the points.
        regulariser: optional :class:`~hamgrav.core.problem.Regulariser` of the learnable
            parameters (e.g. the harmonic penalty), added to the training objective.
    """

    def __init__(
        self,
        model: Model,
        points: np.ndarray,
        values: np.ndarray,
        *,
        scale: float | None = None,
        regulariser: Regulariser | None = None,
    ):
        if model.learnable is None or model.n_learn == 0:
            raise ValueError("a field fit needs a model with learnable parameters")
        points = np.array(points, dtype=float)
        values = np.array(values, dtype=float).reshape(-1)
        if points.ndim != 2 or points.shape[1] != 3 or len(points) != len(values):
            raise ValueError(
                f"points must be (k, 3) and values (k,), got {points.shape} and {values.shape}"
            )
        if not len(values) or not (np.isfinite(points).all() and np.isfinite(values).all()):
            raise ValueError("points and values must be finite and not empty")
        if scale is None:
            rms = float(np.sqrt(np.mean(values**2)))
            if rms == 0:
                raise ValueError("values are all zero: give a scale")
            scale = 1.0 / (rms * np.sqrt(len(values)))
        if not scale > 0:
            raise ValueError(f"scale must be positive, got {scale}")
        for array in (points, values):
            array.flags.writeable = False
        self.model = model
        self.points = points
        self.values = values
        self.scale = float(scale)
        self.regulariser = regulariser
        self.n_params = model.n_learn
        self._fingerprints: dict[bytes, str] = {}

    def _indices(self, arc_indices) -> np.ndarray:
        return np.arange(len(self.values)) if arc_indices is None else np.asarray(arc_indices)

    def residuals(self, theta, arc_indices=None) -> np.ndarray:
        """r = s (V - N) at the selected points, shape (k,)."""
        idx = self._indices(arc_indices)
        potential, _ = evaluate_field(self.model, theta, self.points[idx])
        return self.scale * (self.values[idx] - potential)

    def design(self, theta, arc_indices=None) -> tuple[np.ndarray, np.ndarray]:
        """(r, A) at the selected points: r (k,), A = dr/dtheta = -s dN/dtheta (k, n_params)."""
        idx = self._indices(arc_indices)
        potential, grad = evaluate_potential_gradient(self.model, theta, self.points[idx])
        return self.scale * (self.values[idx] - potential), -self.scale * grad

    def fingerprint(self, arc_indices=None) -> str:
        """SHA-256 (hex) of the selected points and values, the scale and the model."""
        idx = np.asarray(self._indices(arc_indices), dtype=np.intp)
        key = idx.tobytes()
        if key not in self._fingerprints:
            h = hashlib.sha256(np.ascontiguousarray(self.points[idx]).tobytes())
            h.update(np.ascontiguousarray(self.values[idx]).tobytes())
            h.update(repr(self.scale).encode())
            h.update(json.dumps(self.model.describe(), sort_keys=True, default=repr).encode())
            self._fingerprints[key] = h.hexdigest()
        return self._fingerprints[key]
