"""The field least-squares problem: the learnable term fitted to sampled potential values.

Where :class:`~hamgrav.core.problem.ArcProblem` fits a model to tracked arcs, a
:class:`FieldProblem` fits its learnable term N directly to values V_k of a perturbing
potential at points x_k, and optionally to its gradient a_k there (the acceleration it
adds): residuals s_V (V_k - N(x_k)) and s_a (a_k - grad N(x_k)), and their exact parameter
gradients from a compiled ``cfunc``
(:func:`hamgrav.core.model.evaluate_field_parameter_gradient`). It is the oracle of a
representation: how well the term can carry a known field where it is sampled, and away from
it. The solvers see it through :class:`~hamgrav.core.problem.LeastSquaresProblem` (each
sample point is one unit they select by index, as they select arcs), so the same
Levenberg-Marquardt runs on both.
"""

from __future__ import annotations

import hashlib
import json

import numpy as np

from .model import Model, evaluate_field, evaluate_field_parameter_gradient
from .problem import LeastSquaresProblem, Regulariser

__all__ = ["FieldProblem"]


class FieldProblem(LeastSquaresProblem):
    """Least squares of the learnable term of ``model`` on potential ``values`` (k,) and,
    when given, ``accelerations`` (k, 3) at ``points`` (k, 3), canonical: per point the rows
    s_V (V - N) and s_a (a - grad N).

    Args:
        model: a model with a learnable term (its known terms are not used).
        points: (k, 3) body-fixed sample points, canonical.
        values: (k,) the perturbing potential to fit at them, canonical.
        accelerations: optional (k, 3) its gradient there (canonical acceleration).
        scale: s_V > 0; default 1 / (rms(V) sqrt(k)): the potential's part of J is half the
            squared relative error of the fit over the points.
        acceleration_scale: s_a > 0; default 1 / (rms(|a|) sqrt(k)), likewise.
        groups: optional (k,) labels: the default scales are then each group's own (rms and
            count over its points), so that every group's relative errors weigh the same in
            J however large its field and however many its points.
        group_weights: optional {label: w >= 0}: group ``label``'s share of J is multiplied
            by w (1 for a label not given), e.g. to weigh one set's relative errors below
            another's.
        regulariser: optional :class:`~hamgrav.core.problem.Regulariser` of the learnable
            parameters (e.g. the harmonic penalty), added to the training objective.
    """

    def __init__(
        self,
        model: Model,
        points: np.ndarray,
        values: np.ndarray,
        accelerations: np.ndarray | None = None,
        *,
        scale: float | None = None,
        acceleration_scale: float | None = None,
        groups: np.ndarray | None = None,
        group_weights: dict | None = None,
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
        labels = np.zeros(len(values), int) if groups is None else np.asarray(groups)
        if labels.shape != values.shape:
            raise ValueError(f"groups must have one label per point, got {labels.shape}")
        targets = values[:, None]
        columns = [_scales(values, labels, scale, "values")]
        if accelerations is not None:
            accelerations = np.array(accelerations, dtype=float)
            if accelerations.shape != points.shape or not np.isfinite(accelerations).all():
                raise ValueError(f"accelerations must be finite and {points.shape}")
            targets = np.column_stack([values, accelerations])
            s_a = _scales(accelerations, labels, acceleration_scale, "accelerations")
            columns += [s_a] * 3
        scales = np.column_stack(columns)
        if group_weights:
            scales *= _group_factors(labels, group_weights)[:, None]
        targets.flags.writeable = False
        points.flags.writeable = False
        self.model = model
        self.points = points
        self.targets = targets
        self.scales = scales
        self.regulariser = regulariser
        self.n_params = model.n_learn
        self._fingerprints: dict[bytes, str] = {}

    @property
    def values(self) -> np.ndarray:
        """The potential values fitted, (k,)."""
        return self.targets[:, 0]

    def _indices(self, arc_indices) -> np.ndarray:
        return np.arange(len(self.points)) if arc_indices is None else np.asarray(arc_indices)

    def _fields(self, theta, idx, gradient: bool):
        n_rows = self.targets.shape[1]
        points = self.points[idx]
        if gradient:
            fields, grad = evaluate_field_parameter_gradient(self.model, theta, points)
        else:  # costs of trial steps: the field alone, not its P parameter gradients
            potential, acceleration = evaluate_field(self.model, theta, points)
            fields = np.column_stack([potential, acceleration])
        scales = self.scales[idx]
        r = scales * (self.targets[idx] - fields[:, :n_rows])
        if not gradient:
            return r, None
        return r, -scales[:, :, None] * grad[:, :n_rows]

    def residuals(self, theta, arc_indices=None) -> np.ndarray:
        """r at the selected points, shape (k,), or (k, 4) with accelerations."""
        r = self._fields(theta, self._indices(arc_indices), False)[0]
        return r[:, 0] if r.shape[1] == 1 else r

    def design(self, theta, arc_indices=None) -> tuple[np.ndarray, np.ndarray]:
        """(r, A) at the selected points: r flattened point by point, A = dr/dtheta
        (rows, n_params)."""
        r, a = self._fields(theta, self._indices(arc_indices), True)
        return r.reshape(-1), a.reshape(-1, self.n_params)

    def fingerprint(self, arc_indices=None) -> str:
        """SHA-256 (hex) of the selected points and targets, the scales and the model."""
        idx = np.asarray(self._indices(arc_indices), dtype=np.intp)
        key = idx.tobytes()
        if key not in self._fingerprints:
            h = hashlib.sha256(np.ascontiguousarray(self.points[idx]).tobytes())
            h.update(np.ascontiguousarray(self.targets[idx]).tobytes())
            h.update(np.ascontiguousarray(self.scales[idx]).tobytes())
            h.update(json.dumps(self.model.describe(), sort_keys=True, default=repr).encode())
            self._fingerprints[key] = h.hexdigest()
        return self._fingerprints[key]


def _group_factors(labels: np.ndarray, group_weights: dict) -> np.ndarray:
    """Per point (k,): sqrt of its group's weight (1 for a group not weighted); checked."""
    known = set(np.unique(labels).tolist())
    unknown = sorted(set(group_weights) - known, key=str)
    if unknown:
        raise ValueError(f"group_weights names groups with no point: {unknown}")
    factors = np.ones(len(labels))
    for group, weight in group_weights.items():
        if not (np.isfinite(weight) and weight >= 0):
            raise ValueError(f"the weight of group {group!r} must be finite and >= 0, got {weight}")
        factors[labels == group] = np.sqrt(float(weight))
    return factors


def _scales(target: np.ndarray, labels: np.ndarray, scale: float | None, what: str):
    """Per point (k,): the given scale, or 1 / (rms of the target's magnitude x sqrt(points))
    over each point's group; checked."""
    if scale is not None:
        if not scale > 0:
            raise ValueError(f"scale of the {what} must be positive, got {scale}")
        return np.full(len(target), float(scale))
    magnitude = np.sqrt(np.sum(target.reshape(len(target), -1) ** 2, axis=1))
    out = np.empty(len(target))
    for label in np.unique(labels):
        mine = labels == label
        rms = float(np.sqrt(np.mean(magnitude[mine] ** 2)))
        if rms == 0:
            raise ValueError(f"{what} are all zero: give a scale")
        out[mine] = 1.0 / (rms * np.sqrt(np.count_nonzero(mine)))
    return out
