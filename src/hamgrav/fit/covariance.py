"""Formal covariance of fitted learnable parameters from the arcs' noise.

The fit solved min |r_f|^2 / 2 (+ alpha theta^T K theta / 2 with the Kaula weight), with r_f
the residuals as the fit saw them: canonical (unweighted) or divided by the noise sigmas
(weighted). Linearised at the fitted parameters, with A_f = d r_f / d theta and S the
covariance of r_f (diag(sigma^2) unweighted, the identity weighted):

    C = M^-1 (A_f^T S A_f) M^-1,   M = A_f^T A_f + alpha K,

which is (A^T W A)^-1 for a weighted fit without Kaula. Formal: the noise is taken as
white with the arcs' per-component sigmas, and each arc's anchor (its first noisy sample)
as exact; the anchors' noise and any model error are not in C.
"""

from __future__ import annotations

import numpy as np

from ..core.arcs import Arcs
from ..core.problem import ArcProblem
from .estimator import noise_sigmas
from .fitted import FittedModel
from .lm import kaula_diagonal

__all__ = ["formal_covariance"]


def formal_covariance(fitted: FittedModel, arcs: Arcs, chunk: int = 32) -> np.ndarray:
    """C (n_learn, n_learn) of the learnable parameters [canonical] (module docstring),
    from ``arcs`` (the arcs the model was fitted to). Models that estimate per-trajectory
    parameters are not supported (ValueError)."""
    if fitted.estimate_trajectory_params:
        raise ValueError("formal covariance of models with per-trajectory parameters")
    model = fitted.model
    n = model.n_learn
    if n == 0:
        return np.zeros((0, 0))
    sigmas = noise_sigmas(arcs)
    weighted = bool(fitted.solver.get("weighted", False))
    problem = ArcProblem(model, arcs)  # unweighted residuals: A = d r / d theta, canonical
    theta = np.asarray(fitted.params, dtype=float)
    n_unw, n_cov, n_w = np.zeros((n, n)), np.zeros((n, n)), np.zeros((n, n))
    var = np.tile(sigmas**2, arcs.samples_per_arc)
    for start in range(0, arcs.n_arcs, chunk):
        idx = np.arange(start, min(start + chunk, arcs.n_arcs))
        _, a = problem.design(theta, idx)
        v = np.tile(var, len(idx))[:, None]
        n_unw += a.T @ a
        n_cov += a.T @ (a * v)
        n_w += a.T @ (a / v)
    alpha = float(fitted.solver.get("kaula_alpha", 0.0) or 0.0)
    kaula = alpha * kaula_diagonal(problem) if alpha else np.zeros(n)
    if weighted:
        lhs, middle = n_w + np.diag(kaula), n_w
    else:
        lhs, middle = n_unw + np.diag(kaula), n_cov
    inv = np.linalg.pinv(lhs, rcond=1e-14, hermitian=True)
    cov = inv @ middle @ inv
    return 0.5 * (cov + cov.T)
