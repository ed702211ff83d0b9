"""Fit diagnostics: did the fit learn anything, and how many directions do the data constrain.

- ``relative_cost``: the fitted model's cost on the validation arcs (the training arcs when
  there are none) divided by the cost of no correction (learnable parameters zero, the known
  part alone) on the same arcs: 1 means the fit explains nothing the known part did not.
- ``improved``: ``relative_cost`` below ``IMPROVEMENT_THRESHOLD``.
- ``arc_costs``: the per-arc costs behind ``relative_cost`` (:class:`ArcCosts`); the estimator
  keeps them as ``checked_arc_costs_``, out of its reported diagnostics.
- ``constrained_parameters``: the numerical rank of A^T A on the training arcs at the fitted
  parameters (eigenvalues above 1e-12 of the largest, i.e. singular values of A above 1e-6 of
  the largest): how many parameter directions the arcs determine.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..core.problem import ArcProblem

__all__ = ["IMPROVEMENT_THRESHOLD", "ArcCosts", "constrained_parameters", "diagnose"]

#: A fit "clearly improves" over no correction when its held-out cost is below this fraction
#: of the no-correction cost.
IMPROVEMENT_THRESHOLD = 0.9


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
) -> dict:
    """Diagnostics of ``params`` against ``no_correction`` (see the module docstring);
    ``rank=False`` leaves out ``constrained_parameters`` (it needs A^T A of every parameter:
    an ensemble reports it per member instead); ``normal``: the training arcs' A^T A at
    ``params`` when the solver has it (else it is computed)."""
    held_out = validation is not None and len(validation) > 0
    arcs = validation if held_out else train
    fitted_arcs = problem.arc_costs(params, arcs)
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
    if rank:
        out["constrained_parameters"] = constrained_parameters(problem, params, train, normal)
    return out


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
