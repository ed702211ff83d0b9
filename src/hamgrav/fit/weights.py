"""Arc weights for a fit (:class:`hamgrav.core.problem.ArcProblem`'s ``arc_weights``): a set
of arcs weighed as a whole at a chosen share of the cost.

Arcs of different kinds carry information at different scales: a descent arc near the
surface under a wrong deep field has residuals orders of magnitude above an orbital arc's,
so a handful of them take nearly all of an unweighted cost and the fit trades the orbits
for them. :func:`share_weights` gives a set of arcs the weight at which, measured by what
no correction leaves on each side
(:meth:`hamgrav.fit.estimator.GravityEstimator.no_correction_costs`), the set holds
``share`` of the cost and the other arcs the rest, each side's error counted relative to
its own no-correction value; the other arcs keep weight 1, so a regulariser calibrated
against them keeps its strength. Nothing here needs a truth.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError

__all__ = ["share_weights"]


def share_weights(no_correction: np.ndarray, in_set: np.ndarray, share: float) -> np.ndarray:
    """Per-arc weights (n,): 1 outside the set, and for every arc of the set
    ``share / (1 - share)`` times the others' summed no-correction cost over the set's, so
    that with no correction the set holds ``share`` of the weighted cost.

    Args:
        no_correction: (n,) each arc's cost with no correction (any consistent unit), >= 0.
        in_set: (n,) booleans, the arcs of the set.
        share: the set's share of the cost, in (0, 1).

    Raises InputError when the share is outside (0, 1), a side has no arc, or a side's
    no-correction cost is zero or not finite (nothing to measure it by)."""
    costs = np.asarray(no_correction, dtype=float)
    in_set = np.asarray(in_set, dtype=bool)
    if costs.shape != in_set.shape or costs.ndim != 1:
        raise InputError(
            f"no_correction {costs.shape} and in_set {in_set.shape} must be one entry per arc"
        )
    if not 0.0 < share < 1.0:
        raise InputError(f"a set's share of the cost must lie in (0, 1), got {share}")
    inside, outside = costs[in_set].sum(), costs[~in_set].sum()
    for what, total, count in (("set", inside, in_set.sum()), ("other", outside, (~in_set).sum())):
        if count == 0 or not (np.isfinite(total) and total > 0):
            raise InputError(
                f"the {what} arcs' cost with no correction is {total:g} over {count} arcs: "
                "a share needs arcs on both sides that no correction leaves residuals on"
            )
    weights = np.ones(len(costs))
    weights[in_set] = share / (1.0 - share) * outside / inside
    return weights
