"""The arc least-squares problem: predicted arcs and their exact parameter sensitivities.

One path for every model: each arc is anchored at its first noisy sample and propagated by
:func:`hamgrav.core.propagation.propagate_batch` with the model's variational equations
(heyoka ``var_ode_sys`` w.r.t. the runtime parameters, first order).

Global parameter vector ``theta`` = [the learnable term's parameters, then, when
``estimate_trajectory_params``, the per-trajectory parameters of every trajectory
(trajectory-major: trajectory 0's, then trajectory 1's, ...)]. Per-trajectory parameters that
are not estimated are data (``trajectory_values``). Residuals r = y - x(t; y_0, theta) on
canonical states, cost J = r.r / 2, design matrix A = dr/dtheta = -Phi, gradient A^T r,
normal matrix A^T A. With a ``whitening`` W (6, 6), every sample's residual and its rows of
A are whitened: r -> W r, A -> W A (the weighted fit, W from
:func:`hamgrav.fit.estimator.noise_whitening`); with ``arc_weights`` w (one per arc), arc k's
rows are multiplied by sqrt(w_k), so that its cost counts w_k times (a set of arcs
deweighted as a whole, as a navigation filter deweights a data type: the same as the arc's
noise scaled by 1 / sqrt(w_k)); everything above then holds for these r and A.

Solvers use an :class:`ArcProblem` only through ``cost``, ``objective``, ``gradient``,
``normal_equations``, ``regularise``, ``prior_diagonal``, ``with_prior`` and ``arc_normals``
(the arcs' sums as an :class:`ArcNormals`, which a later problem holding the same arcs, e.g.
the next stage of a continual fit, adds to instead of recomputing). An optional
``regulariser`` (a :class:`Regulariser` on the learnable parameters: the network's harmonic
penalty, Kaula's rule on SH, the term's natural one) is part of the training objective:
``objective`` includes it, ``cost`` (validation, diagnostics) never does.
"""

from __future__ import annotations

import copy
import hashlib
import json
from dataclasses import dataclass

import numpy as np

from ..errors import PropagationError
from .arcs import Arcs
from .model import DEFAULT_FIT_TOLERANCE, DEFAULT_SENSITIVITY_TOLERANCE, Model
from .propagation import adjoint_gradient, propagate_batch

__all__ = ["ArcNormals", "ArcProblem", "LeastSquaresProblem", "Prediction", "Regulariser"]


class Regulariser:
    """A term of a fit's training objective on the learnable parameters p (the first
    ``n_learn`` of theta), added by :class:`ArcProblem` to the arcs' least squares and never
    to their cost (validation, diagnostics). It comes in one of two shapes:

    - residual rows, :meth:`terms` -> (rows (k,), their Jacobian (k, n_learn)): 0.5
      rows.rows, whose Gauss-Newton normals join the arcs' (and with them the damping scale
      diag(A^T A) of Levenberg-Marquardt): a penalty measured like data (the network's
      harmonic penalty, :class:`hamgrav.fit.harmonic.HarmonicPenalty`);
    - a fixed quadratic prior 0.5 p.(d * p) on the parameters' size, :meth:`diagonal` -> d
      (n_learn,): kept out of the damping scale, so that the damping follows the data alone
      (Kaula's rule on SH coefficients, :class:`hamgrav.fit.kaula.KaulaPrior`).
    """

    def terms(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """Residual rows and their Jacobian at ``params``; None for a diagonal prior."""
        return None

    def diagonal(self) -> np.ndarray | None:
        """d of the quadratic prior 0.5 p.(d * p); None for residual rows."""
        return None

    def describe(self) -> dict:
        """Plain-data summary for fit records."""
        return {}

    def record(self) -> dict:
        """The entries a fit's solver record gains from this regulariser (plain data)."""
        return {}


@dataclass(frozen=True)
class Prediction:
    """States (n_arcs, m, 6) and, when asked, sensitivities (n_arcs, m, 6, n_params)."""

    states: np.ndarray
    jacobian: np.ndarray | None


@dataclass(frozen=True, eq=False)
class ArcNormals:
    """The arcs' own least-squares sums (no regulariser) at ``params``: ``cost`` J = r.r / 2,
    ``atr`` A^T r (n_params,) and ``ata`` A^T A (n_params, n_params), canonical, over the arcs
    ``arcs`` (indices into the problem's arcs). ``fingerprint`` identifies those arcs' data,
    the model and the whitening (:meth:`ArcProblem.fingerprint`): another problem whose arcs
    at the same indices have the same fingerprint can add to these sums instead of
    recomputing them."""

    params: np.ndarray
    arcs: np.ndarray
    fingerprint: str
    cost: float
    atr: np.ndarray
    ata: np.ndarray


class LeastSquaresProblem:
    """What every least-squares problem of a fit shares: a training objective of residual
    rows r(theta) grouped in units the solvers select by index (the arcs of an
    :class:`ArcProblem`, the sample points of a
    :class:`~hamgrav.core.field_problem.FieldProblem`), cost J = r.r / 2, design A = dr/dtheta,
    and an optional :class:`Regulariser` on the first ``model.n_learn`` parameters.

    A subclass sets ``model``, ``n_params`` and ``regulariser`` and gives :meth:`_indices`
    (all units for None), :meth:`residuals`, :meth:`design` ((r, A) of the selected units)
    and :meth:`fingerprint`. Levenberg-Marquardt uses only the methods defined here; Adam
    also reads the problem's ``arcs`` (their count and samples per arc, for its batches), so
    it runs on an :class:`ArcProblem` only."""

    model: Model
    n_params: int
    regulariser: Regulariser | None = None

    def _indices(self, arc_indices) -> np.ndarray:
        raise NotImplementedError

    def design(self, theta, arc_indices=None) -> tuple[np.ndarray, np.ndarray]:
        """(r, A) of the selected units: r (N,), A (N, n_params), materialised."""
        raise NotImplementedError

    def residuals(self, theta, arc_indices=None) -> np.ndarray:
        """The selected units' residuals r (any shape; their squares summed give 2 J)."""
        raise NotImplementedError

    def fingerprint(self, arc_indices=None) -> str:
        """What the selected units' sums at given parameters depend on (a hex digest)."""
        raise NotImplementedError

    def cost(self, theta, arc_indices=None) -> float:
        """J = r.r / 2 over the selected arcs."""
        r = self.residuals(theta, arc_indices)
        return 0.5 * float(np.sum(r * r))

    def objective(self, theta, arc_indices=None) -> float:
        """The training objective: :meth:`cost` plus the regulariser's value (0.5 rows.rows,
        or the prior 0.5 theta.(d * theta))."""
        return self.with_prior(theta, self.cost(theta, arc_indices))

    def with_prior(self, theta, cost: float) -> float:
        """``cost`` plus the regulariser's value at ``theta`` (see :meth:`objective`)."""
        if self.regulariser is None:
            return cost
        theta = np.asarray(theta, float)
        if self.regulariser.diagonal() is not None:
            prior = self.prior_diagonal()
            return cost + 0.5 * float(theta @ (prior * theta))
        rows, _ = self.regulariser.terms(theta[: self.model.n_learn])
        return cost + 0.5 * float(rows @ rows)

    def prior_diagonal(self) -> np.ndarray:
        """d (n_params,) of the regulariser's quadratic prior 0.5 theta.(d * theta), zero beyond
        the learnable parameters; all zero without one (see :class:`Regulariser`)."""
        d = np.zeros(self.n_params)
        diagonal = None if self.regulariser is None else self.regulariser.diagonal()
        if diagonal is not None:
            d[: len(diagonal)] = diagonal
        return d

    def with_regulariser(self, regulariser: Regulariser | None) -> LeastSquaresProblem:
        """This problem (the same arcs, model and settings, sharing their caches) with another
        regulariser."""
        other = copy.copy(self)
        other.regulariser = regulariser
        return other

    def normal_equations(self, theta, arc_indices=None, chunk: int = 64, *, regularised=True):
        """(J, A^T r, A^T A), accumulated over chunks of arcs without materialising A; with
        ``regularised`` (and a regulariser) the objective's: its rows are appended to r and A."""
        idx = self._indices(arc_indices)
        n = self.n_params
        cost, atr, ata = 0.0, np.zeros(n), np.zeros((n, n))
        for i in range(0, len(idx), chunk):
            r, a = self.design(theta, idx[i : i + chunk])
            cost += 0.5 * float(r @ r)
            atr += a.T @ r
            ata += a.T @ a
        if regularised:
            return self.regularise(theta, cost, atr, ata)
        return cost, atr, ata

    def arc_normals(
        self, theta, arc_indices=None, *, known: ArcNormals | None = None, chunk: int = 64
    ) -> ArcNormals:
        """The arcs' own (J, A^T r, A^T A) at ``theta`` over the selected arcs, as
        :class:`ArcNormals`. ``known`` sums of some of these arcs at the same ``theta`` (same
        fingerprint) are added to instead of recomputed; ``known`` sums that do not apply
        (other parameters, arcs or data) are ignored."""
        idx = self._indices(arc_indices)
        theta = np.array(theta, dtype=float)
        applies = known is not None and self._applies(known, theta, idx)
        rest = np.setdiff1d(idx, known.arcs) if applies else idx
        cost, atr, ata = self.normal_equations(theta, rest, chunk, regularised=False)
        if applies:
            cost, atr, ata = known.cost + cost, known.atr + atr, known.ata + ata
        for array in (theta, atr, ata):
            # kept across fits (the next stage adds to them): nobody may change them in place
            array.flags.writeable = False
        return ArcNormals(theta, idx.copy(), self.fingerprint(idx), cost, atr, ata)

    def _applies(self, known: ArcNormals, theta: np.ndarray, idx: np.ndarray) -> bool:
        return (
            known.params.shape == theta.shape
            and np.array_equal(known.params, theta)
            and np.all(np.isin(known.arcs, idx))
            and known.fingerprint == self.fingerprint(known.arcs)
        )

    def regularise(self, theta, cost: float, atr: np.ndarray, ata: np.ndarray):
        """The objective's (J, A^T r, A^T A) from the arcs' own (``normal_equations(...,
        regularised=False)``): the regulariser's rows appended; new arrays, the given ones
        are left as they are (the arcs' A^T A is what the fit diagnostics need). Without a
        regulariser of rows the same arrays are returned: a diagonal prior stays apart
        (:meth:`prior_diagonal`), out of the damping scale of LM, which adds it itself."""
        if self.regulariser is None or self.regulariser.diagonal() is not None:
            return cost, atr, ata
        k = self.model.n_learn
        rows, jac = self.regulariser.terms(np.asarray(theta, float)[:k])
        atr, ata = atr.copy(), ata.copy()
        cost += 0.5 * float(rows @ rows)
        atr[:k] += jac.T @ rows
        ata[:k, :k] += jac.T @ jac
        return cost, atr, ata

    def gradient(self, theta, arc_indices=None, chunk: int = 64):
        """(J, A^T r): the cost and its gradient."""
        idx = self._indices(arc_indices)
        cost, atr = 0.0, np.zeros(self.n_params)
        for i in range(0, len(idx), chunk):
            r, a = self.design(theta, idx[i : i + chunk])
            cost += 0.5 * float(r @ r)
            atr += a.T @ r
        return cost, atr


class ArcProblem(LeastSquaresProblem):
    """The least-squares problem of fitting ``model`` to ``arcs``.

    Args:
        model: the dynamical model.
        arcs: the observations.
        estimate_trajectory_params: estimate the per-trajectory parameters (model's
            ``per_trajectory`` terms) of every trajectory together with the learnable ones.
        trajectory_values: (n_trajectories, n_trajectory_params) values of the per-trajectory
            parameters when they are data (required then; e.g. SRP area-to-mass [m^2/kg]).
        whitening: optional (6, 6) matrix W applied to every sample's residual, r -> W r, and
            to its sensitivities, A -> W A (canonical; W S W^T = I for the sample noise
            covariance S whitens the residuals, see
            :func:`hamgrav.fit.estimator.noise_whitening`); None = the paper's unweighted
            canonical residuals.
        arc_weights: optional (n_arcs,) finite weights >= 0, one per arc: arc k's residual
            and its sensitivities are multiplied by sqrt(w_k) (after the whitening), so that
            its cost counts w_k times; None = every arc 1.
        tol: integrator tolerance of propagations of states alone (costs, residuals).
        sensitivity_tol: integrator tolerance of propagations that carry the sensitivities
            (:meth:`design`, the normal equations).
        threads: worker threads (default: the number of CPUs).
        max_steps: Taylor steps allowed per batch of arcs before a trial is declared stiff.
        regulariser: optional :class:`Regulariser` added to the training objective.
        gradient_method: how :meth:`gradient` (first-order solvers) gets A^T r: "adjoint", the
            costate from the state transition matrix, no sensitivity to the parameters
            (:func:`hamgrav.core.propagation.adjoint_gradient`), or "forward", the
            sensitivities of :meth:`design` (both exact; they agree to about 1e-12).
    """

    def __init__(
        self,
        model: Model,
        arcs: Arcs,
        *,
        estimate_trajectory_params: bool = False,
        trajectory_values: np.ndarray | None = None,
        whitening: np.ndarray | None = None,
        arc_weights: np.ndarray | None = None,
        tol: float = DEFAULT_FIT_TOLERANCE,
        sensitivity_tol: float = DEFAULT_SENSITIVITY_TOLERANCE,
        threads: int | None = None,
        max_steps: int = 500,
        regulariser=None,
        gradient_method: str = "adjoint",
    ):
        if gradient_method not in ("adjoint", "forward"):
            raise ValueError(
                f"gradient_method must be 'adjoint' or 'forward', got {gradient_method!r}"
            )
        self.gradient_method = gradient_method
        self.model = model
        self.regulariser = regulariser
        self.arcs = arcs
        self.tol = tol
        self.sensitivity_tol = sensitivity_tol
        self.n_trajectories = len(arcs.trajectory_kind)
        n_tp = model.n_trajectory_params
        if estimate_trajectory_params and n_tp == 0:
            raise ValueError("estimate_trajectory_params needs a model with per-trajectory terms")
        self.estimate_trajectory_params = bool(estimate_trajectory_params)
        if n_tp and not estimate_trajectory_params:
            values = None if trajectory_values is None else np.asarray(trajectory_values, float)
            if values is None or values.reshape(self.n_trajectories, -1).shape[1] != n_tp:
                raise ValueError(
                    f"give trajectory_values of shape ({self.n_trajectories}, {n_tp}): the "
                    "per-trajectory parameters are data when they are not estimated"
                )
            self.trajectory_values = values.reshape(self.n_trajectories, n_tp)
        else:
            self.trajectory_values = None
        self.n_params = model.n_learn + (
            self.n_trajectories * n_tp if estimate_trajectory_params else 0
        )
        if whitening is not None:
            whitening = np.array(whitening, dtype=float)  # a copy: the caller keeps theirs
            if whitening.shape != (6, 6) or not np.all(np.isfinite(whitening)):
                raise ValueError(f"whitening must be a finite (6, 6) matrix, got {whitening!r}")
            whitening.flags.writeable = False
        self.whitening = whitening
        if arc_weights is not None:
            arc_weights = np.array(arc_weights, dtype=float)
            if arc_weights.shape != (arcs.n_arcs,):
                raise ValueError(
                    f"arc_weights must be {arcs.n_arcs} finite numbers >= 0 (one per arc), got "
                    f"shape {arc_weights.shape}"
                )
            bad = np.flatnonzero(~(np.isfinite(arc_weights) & (arc_weights >= 0)))
            if len(bad):
                raise ValueError(
                    f"arc_weights must be {arcs.n_arcs} finite numbers >= 0 (one per arc), got "
                    f"{arc_weights[bad[0]]} for arc {bad[0]}"
                )
            arc_weights.flags.writeable = False
        self.arc_weights = arc_weights
        self.threads = threads
        self.max_steps = int(max_steps)
        self._fingerprints: dict[bytes, str] = {}

    # ---------------------------------------------------------------- parameter mapping
    def trajectory_params(self, theta: np.ndarray) -> np.ndarray:
        """(n_trajectories, n_trajectory_params) per-trajectory values at ``theta``."""
        n_tp = self.model.n_trajectory_params
        if self.estimate_trajectory_params:
            return np.asarray(theta[self.model.n_learn :]).reshape(self.n_trajectories, n_tp)
        if self.trajectory_values is None:
            return np.zeros((self.n_trajectories, n_tp))
        return self.trajectory_values

    def _runtime_params(self, theta: np.ndarray, arc_idx: np.ndarray) -> np.ndarray:
        """Runtime parameters (n_sys, len(arc_idx)) of the compiled system for these arcs."""
        m = self.model
        out = np.zeros((m.n_system_params, len(arc_idx)))
        out[: m.n_learn] = np.asarray(theta[: m.n_learn])[:, None]
        if m.n_trajectory_params:
            out[m.n_learn :] = self.trajectory_params(theta)[self.arcs.trajectory[arc_idx]].T
        return out

    def _scatter_columns(self, jac_sys: np.ndarray, arc_idx: np.ndarray) -> np.ndarray:
        """Map d state / d runtime-par (k, m, 6, n_sys) to d state / d theta."""
        m = self.model
        if not self.estimate_trajectory_params:
            return jac_sys[..., : m.n_learn]
        n_tp = m.n_trajectory_params
        out = np.zeros((*jac_sys.shape[:-1], self.n_params))
        out[..., : m.n_learn] = jac_sys[..., : m.n_learn]
        first = m.n_learn + n_tp * self.arcs.trajectory[arc_idx]
        for k, c in enumerate(first):
            out[k, ..., c : c + n_tp] = jac_sys[k, ..., m.n_learn :]
        return out

    # ---------------------------------------------------------------- propagation
    def _indices(self, arc_indices) -> np.ndarray:
        return np.arange(self.arcs.n_arcs) if arc_indices is None else np.asarray(arc_indices)

    def predict(self, theta, arc_indices=None, *, sensitivities: bool = False) -> Prediction:
        """Predicted states (and sensitivities) of the selected arcs at their sample times; with
        ``sensitivities`` the propagation runs at ``sensitivity_tol``, otherwise at ``tol``.

        Raises :class:`~hamgrav.errors.PropagationError` when an arc does not propagate
        (non-finite, or stiff: more than ``max_steps`` Taylor steps)."""
        theta = np.asarray(theta, dtype=float)
        if theta.shape != (self.n_params,):
            raise ValueError(f"theta must have {self.n_params} entries, got {theta.shape}")
        idx = self._indices(arc_indices)
        run = propagate_batch(
            self.model,
            self.arcs.states[idx, 0],
            self.arcs.times[idx],
            self._runtime_params(theta, idx),
            sensitivities=sensitivities,
            tol=self.sensitivity_tol if sensitivities else self.tol,
            threads=self.threads,
            max_steps=self.max_steps,
        )
        if not run.ok.all():
            bad = idx[~run.ok]
            why = (
                f"needed more than {self.max_steps} Taylor steps"
                if run.exceeded_steps.any()
                else "did not propagate to the end"
            )
            raise PropagationError(
                f"arcs {bad[:8].tolist()}{'...' if len(bad) > 8 else ''} {why}: the parameters "
                "make the dynamics stiff or singular"
            )
        jac = None
        if sensitivities:
            jac = run.sensitivities
            jac = (
                self._scatter_columns(jac, idx)
                if jac.shape[-1]
                else np.zeros((len(idx), self.arcs.samples_per_arc, 6, self.n_params))
            )
        return Prediction(run.states, jac)

    # ---------------------------------------------------------------- least squares
    def _root_weights(self, idx: np.ndarray) -> np.ndarray | None:
        """sqrt(w) of the arcs ``idx`` as (k, 1, 1); None without arc weights."""
        if self.arc_weights is None:
            return None
        return np.sqrt(self.arc_weights[idx])[:, None, None]

    def _whiten(self, r: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """sqrt(w) W r of the arcs ``idx``, W on the last axis (each factor 1 when not
        given)."""
        if self.whitening is not None:
            r = r @ self.whitening.T
        root = self._root_weights(idx)
        return r if root is None else r * root

    def residuals(self, theta, arc_indices=None) -> np.ndarray:
        """r = y - x (whitened and weighted when given), shape (n_arcs, m, 6)."""
        idx = self._indices(arc_indices)
        return self._whiten(self.arcs.states[idx] - self.predict(theta, idx).states, idx)

    def arc_costs(self, theta, arc_indices=None) -> np.ndarray:
        """r.r / 2 of each selected arc in the order given, shape (n_arcs,): canonical units,
        dimensionless when whitened, times the arc's weight (:meth:`cost` is their sum)."""
        r = self.residuals(theta, arc_indices)
        return 0.5 * np.sum(r * r, axis=(1, 2))

    def design(self, theta, arc_indices=None):
        """(r, A) with r (N,) and A (N, n_params) for N = arcs x samples x 6 (materialised;
        whitened and weighted when given)."""
        idx = self._indices(arc_indices)
        pred = self.predict(theta, idx, sensitivities=True)
        r = self._whiten(self.arcs.states[idx] - pred.states, idx)
        # in place: the prediction's arrays are this call's own, and A is the largest array
        # of a fit (chunk x samples x 6 x n_params)
        a = np.negative(pred.jacobian, out=pred.jacobian)
        if self.whitening is not None:
            for block in a:  # W A arc by arc, in place: no second array of A's size
                block[...] = np.matmul(self.whitening, block)
        root = self._root_weights(idx)
        if root is not None:
            a *= root[..., None]
        return r.reshape(-1), a.reshape(-1, self.n_params)

    def fingerprint(self, arc_indices=None) -> str:
        """SHA-256 (hex) of what the arcs' sums at given parameters depend on: the selected
        arcs' data (:meth:`Arcs.digest`), the model's description, the whitening, their arc
        weights, the parameter layout and the integrator settings. Kept per selection: a
        fit asks for it once per training set."""
        idx = np.asarray(self._indices(arc_indices), dtype=np.intp)
        key = idx.tobytes()
        if key not in self._fingerprints:
            h = hashlib.sha256(self.arcs.subset(idx).digest().encode())
            h.update(json.dumps(self.model.describe(), sort_keys=True, default=repr).encode())
            layout = (
                self.n_params,
                self.estimate_trajectory_params,
                self.tol,
                self.sensitivity_tol,
                self.max_steps,
            )
            h.update(repr(layout).encode())
            weights = None if self.arc_weights is None else self.arc_weights[idx]
            for array in (self.whitening, self.trajectory_values, weights):
                h.update(b"-" if array is None else np.ascontiguousarray(array).tobytes())
            self._fingerprints[key] = h.hexdigest()
        return self._fingerprints[key]

    def gradient(self, theta, arc_indices=None, chunk: int = 64):
        """(J, A^T r): the cost and its gradient over the selected arcs, by
        ``gradient_method``."""
        if self.gradient_method == "forward" or self.n_params == 0:
            return super().gradient(theta, arc_indices, chunk)
        theta = np.asarray(theta, dtype=float)
        idx = self._indices(arc_indices)
        run = adjoint_gradient(
            self.model,
            self.arcs.states[idx, 0],
            self.arcs.times[idx],
            self.arcs.states[idx],
            self._runtime_params(theta, idx),
            n_shared=self.model.n_learn,
            whitening=self.whitening,
            arc_weights=None if self.arc_weights is None else self.arc_weights[idx],
            tol=self.tol,
            threads=self.threads,
            max_steps=self.max_steps,
        )
        if not run.ok.all():
            why = "needed too many Taylor steps" if run.exceeded_steps.any() else "failed"
            raise PropagationError(
                f"arcs {idx[~run.ok][:8].tolist()} {why} in the gradient's propagation: the "
                "parameters make the dynamics stiff or singular"
            )
        grad = np.zeros(self.n_params)
        n_learn = self.model.n_learn
        grad[:n_learn] = run.gradient[:n_learn]
        if self.estimate_trajectory_params:
            n_tp = self.model.n_trajectory_params
            first = n_learn + n_tp * self.arcs.trajectory[idx]
            for k, c in enumerate(first):
                grad[c : c + n_tp] += run.per_arc[k]
        return float(np.sum(run.costs)), grad
