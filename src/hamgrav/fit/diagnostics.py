"""Fit diagnostics: did the fit learn anything, and how many directions do the data constrain.

- ``relative_cost``: the fitted model's cost on the validation arcs (the training arcs when
  there are none) divided by the cost of no correction (learnable parameters zero, the known
  part alone) on the same arcs: 1 means the fit explains nothing the known part did not.
- ``improved``: ``relative_cost`` below ``IMPROVEMENT_THRESHOLD``.
- ``held_out_to_training`` (with validation arcs): the fitted cost per validation arc over
  the fitted cost per training arc; ``overfit``: it exceeds ``OVERFIT_FACTOR``.
- ``arc_costs``: the per-arc costs behind ``relative_cost`` (:class:`ArcCosts`); the estimator
  keeps them as ``checked_arc_costs_``, out of its reported diagnostics.
- ``inside_expansion`` (SH fits): the arcs that dip inside the series' reference sphere
  (:func:`inside_expansion`), where the field the fit learns need not converge.
- ``constrained_parameters``: the numerical rank of A^T A on the training arcs at the fitted
  parameters (eigenvalues above 1e-12 of the largest, i.e. singular values of A above 1e-6 of
  the largest): how many parameter directions the arcs determine.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..core.problem import ArcProblem
from ..errors import PropagationError

__all__ = [
    "IMPROVEMENT_THRESHOLD",
    "OVERFIT_FACTOR",
    "ArcCosts",
    "constrained_parameters",
    "diagnose",
    "inside_expansion",
]

#: A fit "clearly improves" over no correction when its held-out cost is below this fraction
#: of the no-correction cost.
IMPROVEMENT_THRESHOLD = 0.9
#: A fit is flagged overfit when its cost per held-out arc exceeds this many times its cost
#: per training arc. When noise limits a fit, an arc's whitened cost r.r / 2 is half a
#: chi-square of about 6 (m - 1) degrees of freedom (234 for m = 40 samples), 9 % from arc to
#: arc, and unwhitened it grows with the arc's distance (momentum noise carries omega x q):
#: fits to a point-mass truth (tests' 12 arcs, 2 held out, SH 2-4, three seeds) measured
#: 0.8-1.5x. When the model error limits it, an arc's cost depends on where it flies: SH 2
#: (5 coefficients, which cannot overfit 7 arcs of 40 samples) to a head-tail truth measured
#: 0.06-9.2x, 9.2 when both held-out arcs came from the orbit the training arcs cover once.
#: Ten times is above both; SH 3-4 fitted to those 7 arcs measured up to 2000x, and SH 8
#: fitted to 10 point-mass arcs (the issue's failure in miniature) 1e5x.
OVERFIT_FACTOR = 10.0


class ArcCosts(NamedTuple):
    """Per-arc costs r.r / 2 (canonical units; dimensionless for a whitened fit) on the arcs
    a fit was checked on, in the order of its validation indices (its training indices when
    none are held out): ``fitted`` at the fitted parameters, ``none`` with no correction;
    ``relative_cost`` is their sums' ratio."""

    fitted: np.ndarray
    none: np.ndarray


def diagnose(
    problem: ArcProblem,
    params: np.ndarray,
    no_correction: np.ndarray,
    train: np.ndarray | None,
    validation: np.ndarray | None,
    *,
    rank: bool = True,
    normal: np.ndarray | None = None,
    training_cost: float | None = None,
) -> dict:
    """Diagnostics of ``params`` against ``no_correction`` (see the module docstring);
    ``rank=False`` leaves out ``constrained_parameters`` (it needs A^T A of every parameter:
    an ensemble reports it per member instead); ``normal``: the training arcs' A^T A at
    ``params`` when the solver has it (else it is computed); ``training_cost``: the training
    arcs' cost at ``params`` without a regulariser when the solver has it (canonical, else
    computed)."""
    held_out = validation is not None and len(validation) > 0
    arcs = validation if held_out else train
    try:
        fitted_arcs = problem.arc_costs(params, arcs)
    except PropagationError:
        if not held_out:
            raise
        # the fit does not even propagate the arcs it did not see: the worst of overfits
        fitted_arcs = np.full(len(arcs), np.inf)
    none_arcs = problem.arc_costs(no_correction, arcs)
    fitted, none = float(fitted_arcs.sum()), float(none_arcs.sum())
    relative = fitted / none if none > 0 else float("nan")
    out = {
        "checked_on": "validation arcs" if held_out else "training arcs",
        "relative_cost": float(relative),
        "improved": bool(relative < IMPROVEMENT_THRESHOLD),
        "n_params": int(problem.n_params),
        "arc_costs": ArcCosts(fitted_arcs, none_arcs),
    }
    if held_out:
        if training_cost is None:
            training_cost = problem.cost(params, train)
        n_train = problem.arcs.n_arcs if train is None else len(train)
        per_train = float(training_cost) / n_train
        ratio = (fitted / len(arcs)) / per_train if per_train > 0 else float("inf")
        out["held_out_to_training"] = float(ratio)
        out["overfit"] = bool(ratio > OVERFIT_FACTOR)
    if rank:
        out["constrained_parameters"] = constrained_parameters(problem, params, train, normal)
    return out


def inside_expansion(radii: np.ndarray, reference_radius: float) -> dict | None:
    """The arcs that fly inside the reference sphere of a series expansion (SH about the
    Brillouin sphere), where the series need not converge: ``radii`` (n_arcs, m) of the
    fitted arcs' samples and the sphere's radius, in one unit. Returns None when every
    sample is outside, else {"arcs": how many dip inside, "of": n_arcs, "lowest": the lowest
    sample's radius over the reference radius}."""
    lowest = np.min(radii, axis=1) / float(reference_radius)
    inside = int(np.count_nonzero(lowest < 1.0))
    if not inside:
        return None
    return {"arcs": inside, "of": int(len(lowest)), "lowest": float(lowest.min())}


def constrained_parameters(
    problem: ArcProblem,
    params: np.ndarray,
    train: np.ndarray | None,
    normal: np.ndarray | None = None,
) -> int:
    """The numerical rank of A^T A on the ``train`` arcs at ``params`` (see the module
    docstring); 0 without parameters. ``normal``: that A^T A when the caller has it (the LM
    solver's at its returned iterate, :attr:`~hamgrav.fit.base.SolveResult.data_normal`),
    else it is computed."""
    if not problem.n_params:
        return 0
    if normal is None:
        _, _, normal = problem.normal_equations(params, train, regularised=False)
    elif normal.shape != (problem.n_params, problem.n_params):
        raise ValueError(f"normal matrix of shape {normal.shape} for {problem.n_params} parameters")
    ata = normal
    eig = np.linalg.eigvalsh(ata)
    top = float(eig.max())
    return int(np.sum(eig > 1e-12 * top)) if top > 0 else 0
