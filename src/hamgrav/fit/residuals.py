"""What a fitted model says about arcs without a truth: residuals against the noise.

Tracking imported from files has no truth, so the relative field error cannot be computed.
What can be: how well the model predicts the arcs, measured against the stated noise.

Each arc is anchored at its first noisy sample (as in the fit), so its first sample has no
residual and is left out. Per arc: the RMS over its other samples and the three components
of the position residual [m] and of the rotating-frame velocity residual [mm/s]. Over all
arcs: chi^2 = sum over arcs of e^T S^-1 e, with e the arc's canonical (q, p) residuals and
S their covariance under the tracking noise: white noise on every sample
(:func:`hamgrav.fit.covariance.sample_covariance`) plus the anchor's noise carried along the
arc by the state transition matrix (cov(e_k, e_l) = delta_kl S_s + Phi_k S_s Phi_l^T). With
N = arcs x (m - 1) x 6 terms, chi^2 / (N - n_params) is near 1 when the model explains the
arcs down to the noise; the same figure for no correction (the known part alone, with the
same S) is reported beside it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_triangular

from ..core.arcs import Arcs
from ..core.fields import central_potential
from ..core.model import evaluate_field
from ..core.problem import ArcProblem
from ..core.propagation import state_transition
from ..units import CanonicalUnits, momentum_to_velocity
from .covariance import sample_covariance
from .estimator import require_noise
from .fitted import FittedModel

__all__ = ["ResidualSeries", "residual_series", "residual_report", "field_summary"]


@dataclass(frozen=True, eq=False)
class ResidualSeries:
    """Per-sample residuals (observed minus predicted) of arcs under a fitted model, each arc
    anchored at its first sample, which is left out (it has no residual).

    Attributes:
        time_s: (n_arcs, m - 1) the samples' times [s], as the arcs hold them.
        position_m: (n_arcs, m - 1, 3) body-fixed position residuals [m].
        velocity_m_s: (n_arcs, m - 1, 3) rotating-frame velocity residuals [m/s].
    """

    time_s: np.ndarray
    position_m: np.ndarray
    velocity_m_s: np.ndarray


def _residuals(problem: ArcProblem, params: np.ndarray, units: CanonicalUnits) -> ResidualSeries:
    arcs = problem.arcs
    pred = problem.predict(params).states[:, 1:]
    obs = arcs.states[:, 1:]
    dr = units.from_length(obs[..., :3] - pred[..., :3])
    v_obs = momentum_to_velocity(obs[..., :3], obs[..., 3:])
    v_pred = momentum_to_velocity(pred[..., :3], pred[..., 3:])
    dv = units.from_velocity(v_obs - v_pred)
    return ResidualSeries(units.from_time(arcs.times[:, 1:]), dr, dv)


def _problem(fitted: FittedModel, arcs: Arcs) -> ArcProblem:
    if arcs.samples_per_arc < 2:
        raise ValueError("arcs need at least two samples (the first is the anchor)")
    return ArcProblem(
        fitted.model, arcs, estimate_trajectory_params=fitted.estimate_trajectory_params
    )


def residual_series(fitted: FittedModel, arcs: Arcs) -> ResidualSeries:
    """The per-sample residuals of ``fitted`` on ``arcs`` (what :func:`residual_report`
    summarises per arc, and the residual figure plots)."""
    units = CanonicalUnits(arcs.gm_m3_s2, arcs.spin_period_s)
    return _residuals(_problem(fitted, arcs), np.asarray(fitted.params, dtype=float), units)


def residual_report(fitted: FittedModel, arcs: Arcs, series: ResidualSeries | None = None) -> dict:
    """Residuals of ``fitted`` on ``arcs`` against their noise (see the module docstring);
    ``series``: their :func:`residual_series` when already computed (not propagated again).

    Returns plain data: ``rms_position_m`` and ``rms_velocity_mm_s`` (one per arc),
    ``sigma_r_m``, ``sigma_v_mm_s``, ``chi2``, ``dof``, ``chi2_per_dof`` and
    ``chi2_per_dof_no_correction`` (learnable parameters zero).
    """
    units = CanonicalUnits(arcs.gm_m3_s2, arcs.spin_period_s)
    problem = _problem(fitted, arcs)
    params = np.asarray(fitted.params, dtype=float)
    none = params.copy()
    none[: fitted.model.n_learn] = 0.0

    runtime = problem._runtime_params(params, np.arange(arcs.n_arcs))
    phi = state_transition(fitted.model, arcs.states[:, 0], arcs.times, runtime)[:, 1:]
    sigmas = require_noise(arcs, "the residuals against the noise")
    s_sample = sample_covariance(sigmas[0], sigmas[3])
    m = arcs.samples_per_arc - 1
    white = np.kron(np.eye(m), s_sample)
    factors = []
    for a in range(arcs.n_arcs):
        stacked = phi[a].reshape(6 * m, 6)
        factors.append(np.linalg.cholesky(white + stacked @ s_sample @ stacked.T))

    def chi2(p):
        pred = problem.predict(p).states[:, 1:]
        e = (arcs.states[:, 1:] - pred).reshape(arcs.n_arcs, 6 * m)
        return float(
            sum(
                np.sum(solve_triangular(f, ea, lower=True) ** 2)
                for f, ea in zip(factors, e, strict=True)
            )
        )

    value = chi2(params)
    value_none = chi2(none)
    series = series if series is not None else _residuals(problem, params, units)
    dr, dv = series.position_m, series.velocity_m_s
    n_obs = dr.size + dv.size
    dof = max(1, n_obs - fitted.model.n_learn)
    return {
        "rms_position_m": np.sqrt(np.mean(dr**2, axis=(1, 2))).tolist(),
        "rms_velocity_mm_s": (1e3 * np.sqrt(np.mean(dv**2, axis=(1, 2)))).tolist(),
        "sigma_r_m": float(arcs.sigma_r_m),
        "sigma_v_mm_s": 1e3 * float(arcs.sigma_v_m_s),
        "chi2": value,
        "dof": int(dof),
        "chi2_per_dof": value / dof,
        "chi2_per_dof_no_correction": value_none / dof,
    }


def field_summary(fitted: FittedModel, sets: dict[str, np.ndarray]) -> dict[str, dict]:
    """The fitted field on named canonical point sets (n, 3): per set, the RMS of the
    model's perturbing potential (everything but the central term GM/r) and of its learnable
    term alone [m^2/s^2], and the RMS magnitude of the perturbing acceleration [m/s^2]."""
    units = CanonicalUnits(fitted.gm_m3_s2, fitted.spin_period_s)
    out = {}
    for name, pts in sets.items():
        v, a = evaluate_field(fitted.model, fitted.params, pts, which="total")
        r = np.linalg.norm(pts, axis=1, keepdims=True)
        a_pert = a + pts / r**3  # minus the central acceleration -q / r^3
        row = {
            "rms_perturbing_potential_m2_s2": float(
                units.from_potential(np.sqrt(np.mean((v - central_potential(pts)) ** 2)))
            ),
            "rms_perturbing_acceleration_m_s2": float(
                units.from_acceleration(np.sqrt(np.mean(np.sum(a_pert**2, axis=1))))
            ),
        }
        if fitted.model.learnable is not None:
            n, _ = evaluate_field(fitted.model, fitted.params, pts, which="learnable")
            row["rms_learnable_potential_m2_s2"] = float(
                units.from_potential(np.sqrt(np.mean(n**2)))
            )
        out[name] = row
    return out
