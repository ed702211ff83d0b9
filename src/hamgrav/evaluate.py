"""Field errors of fitted models against a truth (canonical units).

The target of the learnable term is the truth's perturbing potential with respect to the
model's known part: V_truth - V_known (V_known = 1/r from tracking alone, or the shape prior's
mascon potential in residual mode). eps = 1 is the error of applying no correction.
"""

from __future__ import annotations

import numpy as np

from .bodies import Body
from .fields import mascon_potential, relative_field_error, shell_points
from .interiors import MasconSet
from .model import Model, evaluate_field

__all__ = ["evaluation_sets", "field_errors"]


def evaluation_sets(
    body: Body,
    shells_rb=(1.05, 1.1, 1.2, 1.5),
    altitudes_m=(),
    n_directions: int = 400,
    seed: int = 0,
) -> dict[str, np.ndarray]:
    """Named evaluation point sets: shells ``r<s>`` at s R_B and surface-following sets
    ``h<alt>m`` at the given altitudes [m]."""
    sets = {
        f"r{s:g}": shell_points(s * body.brillouin_radius, n_directions, seed) for s in shells_rb
    }
    for h in altitudes_m:
        sets[f"h{h:g}m"] = body.surface_points(body.altitude_to_canonical(h))
    return sets


def field_errors(
    model: Model, params: np.ndarray, truth: MasconSet, sets: dict[str, np.ndarray]
) -> dict[str, float]:
    """Relative field error of the model's learnable term on each set (1.0 when the model has
    no learnable term: no correction)."""
    out = {}
    for name, pts in sets.items():
        v_truth = mascon_potential(truth, pts)
        v_known, _ = evaluate_field(model, params, pts, which="known")
        target = v_truth - v_known
        if model.learnable is None:
            v_model = np.zeros_like(target)
        else:
            v_model, _ = evaluate_field(model, params, pts, which="learnable")
        out[name] = relative_field_error(v_model, target)
    return out
