"""The Kaula scan: fit with each regularisation weight, keep the best by a caller's metric."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from functools import partial

import numpy as np

from ..core.problem import ArcProblem
from ..errors import PropagationError
from .base import SolveResult
from .lm import LevenbergMarquardt
from .selection import choose

__all__ = ["KAULA_ALPHAS", "scan_kaula"]

#: The paper's scan of the Kaula weight alpha.
KAULA_ALPHAS = (1e-8, 1e-7, 1e-6, 1e-5, 1e-4)


def _solve_with_alpha(problem, solver, theta0, train, alpha) -> SolveResult:
    return replace(solver, kaula_alpha=float(alpha)).solve(problem, theta0, train=train)


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
