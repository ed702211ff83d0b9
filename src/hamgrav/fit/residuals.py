"""What a fitted model says about arcs without a truth: residuals against the noise.

Tracking imported from files has no truth, so the relative field error cannot be computed.
What can be: how well the model predicts the arcs, measured against the stated noise.

Each arc is anchored at its first noisy sample (as in the fit), so its first sample has no
residual and is left out. Per arc: the RMS over its other samples and the three components
of the position residual [m] and of the rotating-frame velocity residual [mm/s]. Over all
arcs: chi^2 = sum (dr / sigma_r)^2 + (dv / sigma_v)^2 with N = arcs x (m - 1) x 6 terms,
and chi^2 / (N - n_params). The anchor's own noise propagates along the arc (a position
error at the anchor becomes a velocity error of about n delta_r, n the orbit's mean motion,
which can exceed sigma_v), so even the true field gives chi^2 / dof above 1: compare models
on the same arcs, and with the figure for no correction (the known part alone), also
reported.
"""

from __future__ import annotations

import numpy as np

from ..core.arcs import Arcs
from ..core.fields import central_potential
from ..core.model import evaluate_field
from ..core.problem import ArcProblem
from ..units import CanonicalUnits, momentum_to_velocity
from .fitted import FittedModel

__all__ = ["residual_report", "field_summary"]


def _residuals(problem: ArcProblem, params: np.ndarray, units: CanonicalUnits):
    arcs = problem.arcs
    pred = problem.predict(params).states[:, 1:]
    obs = arcs.states[:, 1:]
    dr = units.from_length(obs[..., :3] - pred[..., :3])
    v_obs = momentum_to_velocity(obs[..., :3], obs[..., 3:])
    v_pred = momentum_to_velocity(pred[..., :3], pred[..., 3:])
    dv = units.from_velocity(v_obs - v_pred)
    return dr, dv


def residual_report(fitted: FittedModel, arcs: Arcs) -> dict:
    """Residuals of ``fitted`` on ``arcs`` against their noise (see the module docstring).

    Returns plain data: ``rms_position_m`` and ``rms_velocity_mm_s`` (one per arc),
    ``sigma_r_m``, ``sigma_v_mm_s``, ``chi2``, ``dof``, ``chi2_per_dof`` and
    ``chi2_per_dof_no_correction`` (learnable parameters zero).
    """
    if arcs.samples_per_arc < 2:
        raise ValueError("arcs need at least two samples (the first is the anchor)")
    units = CanonicalUnits(arcs.gm_m3_s2, arcs.spin_period_s)
    problem = ArcProblem(
        fitted.model, arcs, estimate_trajectory_params=fitted.estimate_trajectory_params
    )
    params = np.asarray(fitted.params, dtype=float)
    none = params.copy()
    none[: fitted.model.n_learn] = 0.0

    def chi2(p):
        dr, dv = _residuals(problem, p, units)
        value = float(np.sum((dr / arcs.sigma_r_m) ** 2) + np.sum((dv / arcs.sigma_v_m_s) ** 2))
        return value, dr, dv

    value, dr, dv = chi2(params)
    value_none, _, _ = chi2(none)
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
