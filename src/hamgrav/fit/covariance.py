"""Formal covariance of fitted learnable parameters from the arcs' noise.

The fit solved min |r_f|^2 / 2 (+ alpha theta^T K theta / 2 with the Kaula weight), with r_f
the residuals as the fit saw them: canonical (unweighted) or divided by the noise sigmas
(weighted). Linearised at the fitted parameters, with A_f = d r_f / d theta and S the
covariance of r_f (diag(sigma^2) unweighted, the identity weighted):

    C = M^-1 (A_f^T S A_f) M^-1,   M = A_f^T A_f + alpha K,

which is (A^T W A)^-1 for a weighted fit without Kaula when S is diagonal. Formal: the
noise is white with the arcs' per-component sigmas on positions and rotating-frame
velocities (:func:`sample_covariance` maps it to the canonical momenta, where the position
noise dominates), and each arc starts at its first noisy
sample, whose noise propagates along the arc (``anchors=True``, see
:func:`formal_covariance`; without it C is several times too small). Model error (e.g.
the degrees an SH expansion leaves out) is not in C.

Only SH models: a network's parameters are far from identifiable (A^T A is singular in
most directions), and network-best is a mean of separately fitted members with a
Laplacian penalty, which this formula does not describe.

:func:`uncertainty_report` turns C into sigma_V(q) = sqrt(g^T C g) on point sets and,
with a truth, checks it: z = (V_model - V_truth) / sigma_V on the perturbing potential has
RMS 1 when the formal errors are calibrated (above 1: they are optimistic, e.g. because the
omitted higher degrees or the anchors' noise dominate).
"""

from __future__ import annotations

import numpy as np

from ..core.arcs import Arcs
from ..core.fields import model_perturbing_potential, perturbing_potential
from ..core.mascons import MasconSet
from ..core.problem import ArcProblem
from ..core.propagation import state_transition
from ..core.terms import SphericalHarmonics
from ..core.uncertainty import potential_sigma
from ..errors import InputError, PropagationError
from ..units import CanonicalUnits
from .estimator import noise_sigmas
from .fitted import FittedModel
from .lm import kaula_diagonal

__all__ = ["formal_covariance", "sample_covariance", "uncertainty_report"]


def sample_covariance(sigma_r: float, sigma_v: float) -> np.ndarray:
    """The (6, 6) covariance of one sample's canonical (q, p) noise: white noise sigma_r on
    each position component and sigma_v on each rotating-frame velocity component (the
    tracking model), mapped to momenta p = v + omega x q (omega = 1 along z), so the position
    noise enters p_x, p_y too (canonical units)."""
    t = np.eye(6)
    t[3, 1], t[4, 0] = -1.0, 1.0  # p_x = v_x - y, p_y = v_y + x
    d = np.diag([sigma_r**2] * 3 + [sigma_v**2] * 3)
    return t @ d @ t.T


def formal_covariance(
    fitted: FittedModel, arcs: Arcs, *, anchors: bool = True, chunk: int = 32
) -> np.ndarray:
    """C (n_learn, n_learn) of the learnable parameters [canonical] (module docstring),
    from ``arcs`` (the arcs the model was fitted to). With ``anchors`` (the default) the
    noise of each arc's anchor is propagated along the arc with the state transition matrix
    Phi_k = d x_k / d x_0: the noise of the residual at sample k is n_k - Phi_k n_0, so
    S is block-diagonal per arc rather than diagonal. Models other than SH and models with
    per-trajectory terms raise InputError."""
    model = fitted.model
    if not isinstance(model.learnable, SphericalHarmonics):
        raise InputError(
            "formal covariances are computed for SH models only (see hamgrav.fit.covariance)"
        )
    if model.per_trajectory:
        raise InputError("formal covariance of models with per-trajectory terms (e.g. SRP)")
    n = model.n_learn
    sigmas = noise_sigmas(arcs)
    weighted = bool(fitted.solver.get("weighted", False))
    w2 = 1.0 / sigmas**2 if weighted else np.ones(6)  # W^2: the fit's weights, squared
    sample_cov = sample_covariance(sigmas[0], sigmas[3])
    problem = ArcProblem(model, arcs)  # unweighted residuals: A = d r / d theta, canonical
    theta = np.asarray(fitted.params, dtype=float)
    lhs, middle = np.zeros((n, n)), np.zeros((n, n))
    m = arcs.samples_per_arc
    for start in range(0, arcs.n_arcs, chunk):
        idx = np.arange(start, min(start + chunk, arcs.n_arcs))
        _, a = problem.design(theta, idx)
        a = a.reshape(len(idx), m, 6, n)
        k = a * w2[None, None, :, None]  # W A_f = W^2 A
        lhs += np.einsum("akin,akim->nm", a, k)  # A_f^T A_f = A^T W^2 A
        h = k.copy()
        if anchors:
            phi = state_transition(
                model, arcs.states[idx, 0], arcs.times[idx], np.tile(theta[:, None], len(idx))
            )
            if not np.all(np.isfinite(phi)):
                raise PropagationError("an arc's state transition did not propagate")
            h[:, 0] = -np.einsum("akij,akin->ajn", phi[:, 1:], k[:, 1:])
        middle += np.einsum("akin,ij,akjm->nm", h, sample_cov, h)
    alpha = float(fitted.solver.get("kaula_alpha", 0.0) or 0.0)
    if alpha:
        lhs += np.diag(alpha * kaula_diagonal(problem))
    inv = np.linalg.pinv(lhs, rcond=1e-14, hermitian=True)
    cov = inv @ middle @ inv
    return 0.5 * (cov + cov.T)


def uncertainty_report(
    fitted: FittedModel,
    covariance: np.ndarray,
    sets: dict[str, np.ndarray],
    truth: MasconSet | None = None,
) -> dict[str, dict]:
    """Per named canonical point set (n, 3): ``rms_sigma_v_m2_s2`` and ``max_sigma_v_m2_s2``
    (sigma_V [m^2/s^2], module docstring) and, with a ``truth``, ``rms_z`` (the RMS of the
    error of the perturbing potential in units of sigma_V; 1 = calibrated) and
    ``within_2_sigma`` (the fraction of points with |error| < 2 sigma_V)."""
    units = CanonicalUnits(fitted.gm_m3_s2, fitted.spin_period_s)
    out = {}
    for name, pts in sets.items():
        sigma = potential_sigma(fitted.model, fitted.params, covariance, pts)
        row = {
            "rms_sigma_v_m2_s2": float(units.from_potential(np.sqrt(np.mean(sigma**2)))),
            "max_sigma_v_m2_s2": float(units.from_potential(np.max(sigma))),
        }
        if truth is not None:
            err = model_perturbing_potential(fitted.model, fitted.params, pts)
            err = err - perturbing_potential(truth, pts)
            z = err / np.where(sigma > 0, sigma, np.nan)
            row["rms_z"] = float(np.sqrt(np.nanmean(z**2)))
            row["within_2_sigma"] = float(np.mean(np.abs(err) < 2 * sigma))
        out[name] = row
    return out
