"""Formal covariance of fitted learnable parameters from the arcs' noise.

The fit solved min |r_f|^2 / 2 (+ alpha theta^T K theta / 2 with the Kaula weight), with r_f
the residuals as the fit saw them: canonical (unweighted) or whitened sample by sample,
r_f = W r with W the noise whitening (weighted; :func:`hamgrav.fit.estimator.noise_whitening`,
W S_s W^T = I for the sample covariance S_s). Write W^2 = W^T W (the identity unweighted,
S_s^-1 weighted), so that |r_f|^2 = r^T W^2 r. Linearised at the fitted parameters, with
A_f = d r_f / d theta and S the covariance of r_f:

    C = M^+ (A_f^T S A_f) M^+,   M = A_f^T A_f + alpha K,

which is (A^T W^2 A)^-1 for a weighted fit without Kaula when the samples' noise is white
(S = I). Formal: the noise is white with the arcs' per-component sigmas on positions and
rotating-frame velocities (:func:`sample_covariance` maps it to the canonical momenta, where
the position noise dominates), and each arc starts at its first noisy sample, whose noise
propagates along the arc (``anchors=True``; without it C is several times too small): S is
then not the identity even for a weighted fit. Model error (e.g. the degrees an SH expansion
leaves out) is not in C.

M^+ is the pseudo-inverse over the directions the arcs constrain: the eigenvectors of M with
eigenvalues above ``threshold`` (default :data:`RANK_THRESHOLD`) times the largest; their
number is the rank. SH models are constrained in every direction (rank = parameters). A
network is not: most of its directions leave the arcs unchanged, the fit does not move them
away from the initialisation, and the noise does not either, so they carry no formal
variance (the error that lives there is model error, see below).

Networks. M is by default the *data-only* normal matrix: the harmonic penalty's rows (part
of the LM objective, :mod:`hamgrav.fit.harmonic`) are left out, so C describes what the arcs
alone constrain. Given the penalty (``penalty=``), its Gauss-Newton rows J^T J join M as the
Kaula weight does for SH, and C is the noise response of the penalised fit: smaller in the
directions the penalty also fixes. An ensemble (members > 1, the learned potential the
members' mean) is the stacked vector of the members' parameters, each member fitted on its
own to the *same* arcs: member k's estimate moves by M_k^+ A_k^T W^2 n under the common
noise n, so

    C_kl = M_k^+ (A_k^T W^2 S_e W^2 A_l) M_l^+,   S_e the covariance of the noise n,

including the cross blocks k != l: the members share the noise, so their errors are
correlated and the mean's sigma does not shrink like 1 / sqrt(members) (the block-diagonal
covariance scaled by 1 / members^2 would assume independent noise per member and be too
small by up to sqrt(members) in sigma). The 1 / members of the mean is in g = dN / d theta
(:mod:`hamgrav.core.uncertainty`).

A posteriori. C above is a priori: the stated noise, sigma_0 = 1. The variance factor
s_0^2 = Q / E[Q] estimates sigma_0^2 from the fit itself, with Q = r^T W^2 r the fit's own
(data) residual sum on its training arcs and E[Q] its expected value under the stated noise
with the fit linearised: for r = (I - A G) e, G = M^+ A^T W^2,

    E[Q] = tr(W^2 S_e) - 2 tr(M^+ A^T W^2 S_e W^2 A) + tr(A^T W^2 A C),

which is N - rank for a weighted fit of white noise (the textbook r^T S^-1 r / (N - p)). The
anchors make S_e far from white and an unweighted fit far from efficient, so N - rank would
be wrong: on a point-mass truth an unweighted fit of a small network (2 hidden units, the
tests' 12 arcs; measured once, with the diagonal weighting used before whitening) has C
some 600 times the weighted (Gauss-Markov) covariance and the whitened chi^2 per degree of
freedom 2.3 with the right model.
:meth:`ParameterCovariance.scaled` multiplies member k's block by s_k, the (k, l) block by
s_k s_l. A factor above 1 says the model does not explain the arcs down to the noise (model
error, or a noise larger than stated); scaling by it inflates C accordingly, but only along
the directions the data constrain.

:func:`uncertainty_report` turns C into sigma_V(q) = sqrt(g^T C g) on point sets and,
with a truth, checks it: z = (V_model - V_truth) / sigma_V on the perturbing potential has
RMS 1 when the formal errors are calibrated (above 1: they are optimistic, e.g. because the
omitted higher degrees or the anchors' noise dominate).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..core.arcs import Arcs
from ..core.fields import model_perturbing_potential, perturbing_potential
from ..core.mascons import MasconSet
from ..core.problem import ArcProblem
from ..core.propagation import state_transition
from ..core.uncertainty import potential_sigma
from ..errors import InputError, PropagationError
from ..units import CanonicalUnits
from .estimator import (
    fitted_harmonic_penalty,
    noise_whitening,
    require_noise,
    validation_split,
)
from .fitted import FittedModel
from .kaula import kaula_diagonal

__all__ = [
    "RANK_THRESHOLD",
    "NormalSystem",
    "ParameterCovariance",
    "fit_arc_weights",
    "formal_covariance",
    "normal_system",
    "parameter_covariance",
    "potential_uncertainty",
    "sample_covariance",
    "training_arcs",
    "uncertainty_report",
]

#: Relative eigenvalue threshold of the pseudo-inverse: directions of M with an eigenvalue
#: below this fraction of the largest are not constrained by the arcs (singular values of A
#: below 1e-6 of the largest), the same cut as the fit diagnostics' rank
#: (:mod:`hamgrav.fit.diagnostics`).
RANK_THRESHOLD = 1e-12


def sample_covariance(sigma_r: float, sigma_v: float) -> np.ndarray:
    """The (6, 6) covariance of one sample's canonical (q, p) noise: white noise sigma_r on
    each position component and sigma_v on each rotating-frame velocity component (the
    tracking model), mapped to momenta p = v + omega x q (omega = 1 along z), so the position
    noise enters p_x, p_y too (canonical units)."""
    t = np.eye(6)
    t[3, 1], t[4, 0] = -1.0, 1.0  # p_x = v_x - y, p_y = v_y + x
    d = np.diag([sigma_r**2] * 3 + [sigma_v**2] * 3)
    return t @ d @ t.T


def training_arcs(fitted: FittedModel, arcs: Arcs) -> np.ndarray | None:
    """The arc indices ``fitted`` was trained on when ``arcs`` are its arcs and it held some
    out for validation (the estimator's seeded split, recomputed from the recorded fraction
    and seed); None (all arcs) otherwise. A fit given its validation arcs explicitly
    (continual stages) is not recorded that way: pass its training arcs yourself."""
    info = fitted.solver
    n_val = int(info.get("n_validation", 0) or 0)
    if not n_val or int(info.get("n_arcs", -1)) != arcs.n_arcs:
        return None
    train, validation = validation_split(
        arcs.n_arcs, float(info["validation_fraction"]), int(info["seed"])
    )
    return train if len(validation) == n_val else None


def fit_arc_weights(fitted: FittedModel, arcs: Arcs) -> np.ndarray | None:
    """Each of ``arcs``' weight in ``fitted``'s cost (its solver record's ``arc_weights``,
    :meth:`~hamgrav.fit.estimator.GravityEstimator.fit`), or None for a fit that weighed
    every arc 1. InputError when the record has no weights per arc (a model file written
    before they were recorded) or they are not one per arc of ``arcs``."""
    record = fitted.solver.get("arc_weights")
    if not record:
        return None
    values = record.get("values")
    if values is None:
        raise InputError(
            "the fit weighed its arcs, but its model file does not record the weights per "
            "arc: refit it with this version of hamgrav for its formal covariance"
        )
    values = np.asarray(values, dtype=float)
    if values.shape != (arcs.n_arcs,):
        raise InputError(
            f"the fit weighed {len(values)} arcs and {arcs.n_arcs} are given: give the arcs "
            "it was fitted to"
        )
    return values


def _members(fitted: FittedModel) -> tuple[object, list[np.ndarray]]:
    """(the model of one member, the members' parameter blocks): the model itself and its
    parameters (SH, one network), or each network of an ensemble on its own."""
    model = fitted.model
    term = model.learnable
    if model.per_trajectory:
        raise InputError("formal covariance of models with per-trajectory terms (e.g. SRP)")
    if term is None:
        raise InputError(
            "formal covariances are computed for models with a learnable term (SH, a network); "
            "this one has the known part alone"
        )
    theta = np.asarray(fitted.params, dtype=float)[: model.n_learn]
    return model.member(), term.split_members(theta)


@dataclass(frozen=True, eq=False)
class NormalSystem:
    """The pieces of the formal covariance of a fit, accumulated over its training arcs in
    one pass (canonical units; module docstring). Per member k: ``data_normal`` A_k^T W^2 A_k
    (n_b, n_b), ``prior`` its addition in the fit's normal matrix (alpha K for a Kaula-weighted
    SH fit, else zeros), ``cost`` r_k^T W^2 r_k (the fit's data residuals, twice its cost) and
    ``noise_trace`` tr(W^2 S_e) (the expected value of that sum for the noise alone, before
    the fit); ``middle`` (K n_b, K n_b) the covariance of the members' normal-equation
    right-hand sides A_k^T W^2 e under the common noise e. :meth:`covariance` forms C."""

    data_normal: tuple[np.ndarray, ...]
    prior: tuple[np.ndarray, ...]
    middle: np.ndarray
    cost: tuple[float, ...]
    noise_trace: tuple[float, ...]
    penalised: bool = False

    def with_penalty(self, penalty, fitted: FittedModel) -> NormalSystem:
        """The same system with a regulariser's Gauss-Newton rows J_k^T J_k added to each
        member's normal matrix (``penalty.terms(theta_k) -> (rows, J_k)`` at member k's
        fitted parameters; see :func:`normal_system`)."""
        _, blocks = _members(fitted)
        prior = tuple(
            p + jac.T @ jac
            for p, (_, jac) in zip(self.prior, (penalty.terms(b) for b in blocks), strict=True)
        )
        return replace(self, prior=prior, penalised=True)

    def covariance(self, threshold: float = RANK_THRESHOLD) -> ParameterCovariance:
        """C with the pseudo-inverse over eigenvalues above ``threshold`` x the largest, and
        the a posteriori variance factors (module docstring)."""
        pinvs, ranks = [], []
        for d, p in zip(self.data_normal, self.prior, strict=True):
            lam, vec = np.linalg.eigh(d + p)
            top = lam.max()
            keep = lam > threshold * top if top > 0 else np.zeros(len(lam), bool)
            v = vec[:, keep]
            pinvs.append((v / lam[keep]) @ v.T)
            ranks.append(int(keep.sum()))
        n_b = len(pinvs[0])
        cov = np.empty_like(self.middle)
        for k, pk in enumerate(pinvs):
            for l, pl in enumerate(pinvs):
                block = self.middle[k * n_b : (k + 1) * n_b, l * n_b : (l + 1) * n_b]
                cov[k * n_b : (k + 1) * n_b, l * n_b : (l + 1) * n_b] = pk @ block @ pl
        cov = 0.5 * (cov + cov.T)
        expected = []
        for k, (pk, d) in enumerate(zip(pinvs, self.data_normal, strict=True)):
            own = slice(k * n_b, (k + 1) * n_b)
            # E r^T W^2 r = tr(W^2 S_e) - 2 tr(M^+ mid) + tr(A^T W^2 A C) for r = (I - A G) e
            expected.append(
                self.noise_trace[k]
                - 2.0 * float(np.sum(pk * self.middle[own, own]))
                + float(np.sum(d * cov[own, own]))
            )
        return ParameterCovariance(
            matrix=cov,
            ranks=tuple(ranks),
            variance_factors=tuple(c / e for c, e in zip(self.cost, expected, strict=True)),
            cost=self.cost,
            expected_cost=tuple(expected),
            threshold=float(threshold),
            penalised=self.penalised,
        )


@dataclass(frozen=True, eq=False)
class ParameterCovariance:
    """The formal covariance of a fit's learnable parameters (module docstring).

    Attributes:
        matrix: C (n_learn, n_learn), a priori (the stated noise), canonical units.
        ranks: per member, the directions the arcs constrain (eigenvalues kept).
        variance_factors: per member, the a posteriori sigma_0^2 = cost / expected_cost.
        cost: per member, r^T W^2 r of its fitted residuals on the training arcs
            (canonical, weighted as in the fit).
        expected_cost: per member, the expected value of that sum under the stated noise
            with the fit linearised (module docstring; N - rank for a weighted fit of white
            noise).
        threshold: the relative eigenvalue threshold of the pseudo-inverse.
        penalised: whether a network's harmonic penalty is in the normal matrix.
    """

    matrix: np.ndarray
    ranks: tuple[int, ...]
    variance_factors: tuple[float, ...]
    cost: tuple[float, ...]
    expected_cost: tuple[float, ...]
    threshold: float
    penalised: bool = False

    @property
    def members(self) -> int:
        """Members of the ensemble (1 for SH and a single network)."""
        return len(self.ranks)

    def scaled(self) -> np.ndarray:
        """C scaled by the a posteriori variance factors: block (k, l) by s_k s_l."""
        n_b = len(self.matrix) // self.members
        s = np.repeat(np.sqrt(self.variance_factors), n_b)
        return self.matrix * np.outer(s, s)

    def block_diagonal(self, matrix: np.ndarray | None = None) -> np.ndarray:
        """``matrix`` (default C; e.g. :meth:`scaled`) without its cross-member blocks: as if
        each member had been fitted to its own noise draw."""
        matrix = self.matrix if matrix is None else matrix
        n_b = len(matrix) // self.members
        member = np.arange(len(matrix)) // n_b
        return np.where(member[:, None] == member[None, :], matrix, 0.0)

    def describe(self) -> dict:
        """Plain-data summary: ranks, parameters per member, variance factors, threshold."""
        return {
            "members": self.members,
            "parameters_per_member": len(self.matrix) // self.members,
            "ranks": list(self.ranks),
            "variance_factors": [round(float(f), 4) for f in self.variance_factors],
            "threshold": self.threshold,
            "harmonic_penalty": self.penalised,
        }


def normal_system(
    fitted: FittedModel,
    arcs: Arcs,
    *,
    train: np.ndarray | None = None,
    anchors: bool = True,
    penalty=None,
    chunk: int = 16,
) -> NormalSystem:
    """One pass over the ``train`` arcs (default: :func:`training_arcs`) of ``arcs`` (the
    arcs ``fitted`` was fitted to): each member's design matrix A_k and residuals at its
    fitted parameters, accumulated into a :class:`NormalSystem`. With ``anchors`` (the
    default) the noise of each arc's anchor is propagated along the arc with the state
    transition matrix Phi_k = d x_k / d x_0: the noise of the residual at sample k is
    e_k = n_k - Phi_k n_0, so S_e is block-diagonal per arc rather than diagonal.
    ``penalty`` (a network's :class:`~hamgrav.fit.harmonic.HarmonicPenalty` on one member's
    model, e.g. from :meth:`~hamgrav.fit.estimator.GravityEstimator.harmonic_penalty`) adds
    its Gauss-Newton rows J^T J at each member's parameters to that member's normal matrix,
    as the Kaula weight does for SH: C is then the noise response of the penalised fit
    instead of what the arcs alone constrain. Models with a learnable term only; models with
    per-trajectory terms raise InputError."""
    arc_weights = fit_arc_weights(fitted, arcs)
    member_model, blocks = _members(fitted)
    if train is None:
        train = training_arcs(fitted, arcs)
    idx_all = np.arange(arcs.n_arcs) if train is None else np.asarray(train, dtype=int)
    n_b, n_m = member_model.n_learn, len(blocks)
    sigmas = require_noise(arcs, "the formal covariance")
    # the fit's whitening W of each sample's residual (the identity unweighted) and
    # W^2 = W^T W, the weight of the fit's cost r^T W^2 r
    w = noise_whitening(arcs) if fitted.solver.get("weighted", False) else np.eye(6)
    w2 = w.T @ w
    sample_cov = sample_covariance(sigmas[0], sigmas[3])
    root = np.linalg.cholesky(sample_cov)  # S = L L^T: H^T S H = (L^T H)^T (L^T H) by BLAS
    problem = ArcProblem(member_model, arcs)  # unweighted residuals: A = d r / d theta
    # tr(W^2 S) of one sample's white noise (6 weighted)
    white_trace = float(np.sum(np.diag(w @ sample_cov @ w.T)))
    normal = [np.zeros((n_b, n_b)) for _ in blocks]
    middle = np.zeros((n_m * n_b, n_m * n_b))
    cost, trace = np.zeros(n_m), np.zeros(n_m)
    m = arcs.samples_per_arc
    for start in range(0, len(idx_all), chunk):
        idx = idx_all[start : start + chunk]
        # each arc's weight in the fit's cost (1 without arc weights): its W^2 is w_i W^2
        arc_w = np.ones(len(idx)) if arc_weights is None else arc_weights[idx]
        stacked = []
        for k, theta in enumerate(blocks):
            r, a = problem.design(theta, idx)
            r = r.reshape(len(idx), m, 6)
            wr = r @ w.T  # W r; the fit saw sqrt(w_i) W r
            cost[k] += float(np.sum(arc_w[:, None, None] * wr**2))
            a = a.reshape(len(idx), m, 6, n_b)
            # W^T A_f = W^2 A, sample by sample, times the arc's weight
            h = np.matmul(w2, a) * arc_w[:, None, None, None]
            normal[k] += a.reshape(-1, n_b).T @ h.reshape(-1, n_b)  # A^T W^2 A
            # tr(W^2 S_e) over the samples after the anchor: white noise plus the anchor's
            trace[k] += float(arc_w.sum()) * (m - 1) * white_trace
            if anchors:
                transition = state_transition(
                    member_model,
                    arcs.states[idx, 0],
                    arcs.times[idx],
                    np.tile(theta[:, None], len(idx)),
                )
                phi = transition[:, 1:]
                if not np.all(np.isfinite(phi)):
                    raise PropagationError("an arc's state transition did not propagate")
                # tr(W^2 Phi S Phi^T) = the diagonal of (W Phi) S (W Phi)^T, summed (W Phi
                # laid out as Phi is: einsum's order of summation, so the unweighted sum's
                # rounding, depends on the operands' strides)
                w_phi = np.matmul(w, transition)[:, 1:]
                if arc_weights is not None:
                    w_phi = w_phi * np.sqrt(arc_w)[:, None, None, None]
                trace[k] += float(
                    np.einsum("i,akij,jl,akil->", np.ones(6), w_phi, sample_cov, w_phi)
                )
                h[:, 0] = -np.einsum("akij,akin->ajn", phi, h[:, 1:])
            stacked.append(np.einsum("ji,akjn->akin", root, h).reshape(-1, n_b))
        lt_h = np.concatenate(stacked, axis=1)
        middle += lt_h.T @ lt_h
    prior = [np.zeros((n_b, n_b)) for _ in blocks]
    alpha = float(fitted.solver.get("kaula_alpha", 0.0) or 0.0)
    if alpha and member_model.learnable.kaula_weights() is not None:
        prior[0] = np.diag(alpha * kaula_diagonal(problem))
    system = NormalSystem(
        tuple(normal), tuple(prior), middle, tuple(cost.tolist()), tuple(trace.tolist())
    )
    return system if penalty is None else system.with_penalty(penalty, fitted)


def parameter_covariance(
    fitted: FittedModel,
    arcs: Arcs,
    *,
    train: np.ndarray | None = None,
    anchors: bool = True,
    penalty=None,
    threshold: float = RANK_THRESHOLD,
) -> ParameterCovariance:
    """The :class:`ParameterCovariance` of ``fitted`` from its ``arcs`` (see
    :func:`normal_system` and the module docstring)."""
    system = normal_system(fitted, arcs, train=train, anchors=anchors, penalty=penalty)
    return system.covariance(threshold)


def formal_covariance(
    fitted: FittedModel, arcs: Arcs, *, anchors: bool = True, chunk: int = 16
) -> np.ndarray:
    """C (n_learn, n_learn) of the learnable parameters [canonical], a priori (the stated
    noise, no variance factor), from ``arcs`` (the arcs the model was fitted to; its
    training arcs when it held some out): :func:`parameter_covariance`'s matrix."""
    return normal_system(fitted, arcs, anchors=anchors, chunk=chunk).covariance().matrix


def uncertainty_report(
    fitted: FittedModel,
    covariance: np.ndarray,
    sets: dict[str, np.ndarray],
    truth: MasconSet | None = None,
) -> dict[str, dict]:
    """Per named canonical point set (n, 3): ``rms_sigma_v_m2_s2`` and ``max_sigma_v_m2_s2``
    (sigma_V [m^2/s^2], module docstring) and, with a ``truth``, ``rms_z`` (the RMS of the
    error of the perturbing potential in units of sigma_V; 1 = calibrated),
    ``within_1_sigma`` and ``within_2_sigma`` (the fractions of points with |error| below 1
    and 2 sigma_V: 0.68 and 0.95 for calibrated Gaussian errors) and ``median_abs_z`` (the
    median |error| / sigma_V: 0.67 when calibrated)."""
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
            row |= calibration(err, sigma)
        out[name] = row
    return out


def calibration(error: np.ndarray, sigma: np.ndarray) -> dict:
    """How honest ``sigma`` is about ``error`` (same units, per point): ``rms_z`` (RMS of
    error / sigma), ``within_1_sigma``, ``within_2_sigma`` (fractions of points with |error|
    below 1 and 2 sigma; 0.68 and 0.95 for calibrated Gaussian errors) and ``median_abs_z``
    (median |error| / sigma; 0.67 when calibrated). Points with sigma = 0 count as outside."""
    error, sigma = np.abs(np.asarray(error, float)), np.asarray(sigma, float)
    z = error / np.where(sigma > 0, sigma, np.nan)
    return {
        "rms_z": float(np.sqrt(np.nanmean(z**2))),
        "within_1_sigma": float(np.mean(error < sigma)),
        "within_2_sigma": float(np.mean(error < 2 * sigma)),
        "median_abs_z": float(np.nanmedian(z)),
    }


def potential_uncertainty(
    fitted: FittedModel, arcs: Arcs, body, sets: dict[str, np.ndarray]
) -> dict:
    """The formal uncertainty of the potential of ``fitted`` on each named canonical point
    set (n, 3), as ``hamgrav evaluate --uncertainty`` reports it: ``covariance``
    (:meth:`ParameterCovariance.describe`) and, per set, :func:`uncertainty_report`'s row
    (sigma_V [m^2/s^2]; with the arcs' truth, its calibration). C comes from the tracking
    noise of ``arcs`` (the fit's arcs) through the fit's normal equations, with a network's
    harmonic penalty rebuilt on ``body`` when the fit had one
    (:func:`hamgrav.fit.estimator.fitted_harmonic_penalty`), scaled by the a posteriori
    variance factor. Arcs without a noise level raise :class:`InputError`."""
    require_noise(arcs, "the formal uncertainty of the potential")
    penalty = fitted_harmonic_penalty(fitted, arcs, body)
    covariance = parameter_covariance(fitted, arcs, penalty=penalty)
    truth = arcs.truth if arcs.has_truth else None
    report = uncertainty_report(fitted, covariance.scaled(), sets, truth)
    return {"covariance": covariance.describe(), **report}
