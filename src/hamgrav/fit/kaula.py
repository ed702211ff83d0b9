"""Kaula's rule as a regulariser of SH fits, and the scan of its weight: fit with each
weight, keep the best by a caller's metric."""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import partial

import numpy as np

from ..core.model import Model
from ..core.problem import ArcProblem, Regulariser
from ..errors import InputError, PropagationError
from .base import SolveResult
from .lm import LevenbergMarquardt
from .selection import choose

__all__ = ["KAULA_ALPHAS", "KaulaPrior", "kaula_diagonal", "scan_kaula"]

#: The paper's scan of the Kaula weight alpha.
KAULA_ALPHAS = (1e-8, 1e-7, 1e-6, 1e-5, 1e-4)


def kaula_diagonal(problem: ArcProblem) -> np.ndarray:
    """K = diag(l^4) on the SH block of the problem's parameters, 0 elsewhere (Kaula's rule:
    the learnable term's :meth:`~hamgrav.core.terms.GravityTerm.kaula_weights`; all 0 for a
    term the rule does not apply to)."""
    k = np.zeros(problem.n_params)
    term = problem.model.learnable
    weights = None if term is None else term.kaula_weights()
    if weights is not None:
        k[: term.n_params] = weights
    return k


class KaulaPrior(Regulariser):
    """Kaula's rule on the learnable SH coefficients of ``model``: the prior 0.5 alpha
    sum_lm l^4 (C_lm^2 + S_lm^2) added to the training objective, alpha >= 0 dimensionless
    (canonical coefficients). A diagonal prior (:class:`~hamgrav.core.problem.Regulariser`):
    Levenberg-Marquardt adds alpha diag(l^4) to its normal matrix outside the damping scale,
    the paper's (A^T A + alpha K) dc = -(A^T r + alpha K c)."""

    def __init__(self, model: Model, alpha: float):
        term = model.learnable
        weights = None if term is None else term.kaula_weights()
        if weights is None:
            raise InputError("Kaula's rule applies to spherical harmonics (term 'sh')")
        if not alpha >= 0:
            raise InputError(f"the Kaula weight alpha must be >= 0, got {alpha}")
        self.alpha = float(alpha)
        self._diagonal = self.alpha * np.asarray(weights, dtype=float)

    def diagonal(self) -> np.ndarray:
        """alpha l^4 per learnable coefficient (n_learn,)."""
        return self._diagonal

    def describe(self) -> dict:
        """Plain-data summary for fit records."""
        return {"kaula_alpha": self.alpha}

    def record(self) -> dict:
        """The fit record's "kaula_alpha" entry."""
        return self.describe()


def _solve_with_alpha(problem, solver, theta0, train, alpha) -> SolveResult:
    prior = KaulaPrior(problem.model, alpha) if alpha else None
    return solver.solve(problem.with_regulariser(prior), theta0, train=train)


def scan_kaula(
    problem: ArcProblem,
    metric: Callable[[np.ndarray], float],
    alphas=KAULA_ALPHAS,
    solver: LevenbergMarquardt | None = None,
    theta0: np.ndarray | None = None,
    *,
    train: np.ndarray | None = None,
    mapper: Callable = map,
):
    """Fit with each Kaula weight on the ``train`` arcs (all if None) and keep the one with the
    lowest ``metric(params)`` (the caller supplies the metric: a truth-based field error as in
    the paper, or the cost on arcs held out of ``train``).

    The fits are independent work units of plain data: ``mapper`` (builtin ``map`` by default,
    or a Dask client's) runs them; the metric is evaluated here.

    A fit whose parameters do not propagate the metric's arcs (a weak weight can let a high
    degree blow up along an arc that grazes the surface) scores infinity, and is never kept
    while another weight scores finite; if none does, :class:`PropagationError`. The choice
    is :func:`hamgrav.fit.selection.choose`'s "lowest" rule (one score per weight: no standard
    error). Without a truth, :mod:`hamgrav.fit.selection` chooses alpha by cross-validation
    (the estimator's ``kaula="cv"``); this scan is the paper's protocol (``"truth-scan"``)
    and the single held-out split (``"holdout-scan"``).

    Returns (best alpha, best SolveResult, list of (alpha, metric value)).
    """
    solver = solver or LevenbergMarquardt()
    results = list(mapper(partial(_solve_with_alpha, problem, solver, theta0, train), alphas))

    def score(params) -> float:
        try:
            value = float(metric(params))
        except PropagationError:
            return math.inf
        return value if math.isfinite(value) else math.inf

    scores = [(float(a), score(r.params)) for a, r in zip(alphas, results, strict=True)]
    k = choose([[s] for _, s in scores], "lowest")
    return scores[k][0], results[k], scores
