"""Predicted arcs and their exact parameter sensitivities, for any model.

One function path for every learnable term (network, spherical harmonics, none) and for SRP
coefficients: each arc is anchored at its first noisy sample and propagated with the model's
variational equations (heyoka ``var_ode_sys`` w.r.t. the runtime parameters, first order), in
SIMD batches of arcs, over threads.

Global parameter vector ``theta`` = [learnable parameters, then (when ``estimate_srp``) one SRP
area-to-mass coefficient per trajectory]. Residuals r = y - x(t; y_0, theta) on canonical
states (optionally divided by per-component sigmas), cost J = r.r / 2, design matrix
A = dr/dtheta = -Phi, gradient A^T r, normal matrix A^T A.

Solvers talk to :class:`ArcProblem` only through ``cost``, ``gradient`` and
``normal_equations``; a gradient computed by an adjoint system can later replace the forward
sensitivities inside ``gradient`` without touching them.
"""

from __future__ import annotations

import copy
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from .model import DEFAULT_FIT_TOLERANCE, Model, compiled_integrator
from .tracking import Arcs

__all__ = ["ArcProblem", "Prediction", "PropagationError"]


class PropagationError(RuntimeError):
    """An arc could not be propagated under the model (e.g. it diverged)."""


class _StepLimit:
    """Step callback stopping a propagation after ``limit`` steps: a well-posed arc takes a
    few Taylor steps, so a runaway count means the trial parameters are unphysical (solvers
    then reject the trial instead of waiting on it)."""

    def __init__(self, limit: int):
        self.limit = limit
        self.steps = 0
        self.exceeded = False

    def __call__(self, ta) -> bool:
        self.steps += 1
        if self.steps > self.limit:
            self.exceeded = True
            return False
        return True


@dataclass(frozen=True)
class Prediction:
    """States (n_arcs, m, 6) and, when asked, sensitivities (n_arcs, m, 6, n_params)."""

    states: np.ndarray
    jacobian: np.ndarray | None


class ArcProblem:
    """The least-squares problem of fitting ``model`` to ``arcs``.

    Args:
        model: the dynamical model.
        arcs: the observations.
        estimate_srp: estimate one SRP coefficient per trajectory (model must have SRP).
        srp_coefficients: per-trajectory SRP coefficients [m^2/kg] when they are known.
        sigmas: optional per-component scale (6,) of the residuals (canonical); None = the
            paper's unweighted canonical residuals.
        tol: integrator tolerance.
        threads: worker threads (default: the number of CPUs).
        max_steps: Taylor steps allowed per batch of arcs before giving up on it.
    """

    def __init__(
        self,
        model: Model,
        arcs: Arcs,
        *,
        estimate_srp: bool = False,
        srp_coefficients: np.ndarray | None = None,
        sigmas: np.ndarray | None = None,
        tol: float = DEFAULT_FIT_TOLERANCE,
        threads: int | None = None,
        max_steps: int = 500,
    ):
        self.model = model
        self.arcs = arcs
        self.tol = tol
        n_traj = len(arcs.trajectory_kind)
        if estimate_srp and model.srp is None:
            raise ValueError("estimate_srp needs a model with an SRP term")
        self.estimate_srp = estimate_srp
        if model.srp is not None and not estimate_srp:
            if srp_coefficients is None or len(srp_coefficients) != n_traj:
                raise ValueError(f"give srp_coefficients for all {n_traj} trajectories")
        self.srp_coefficients = (
            None if srp_coefficients is None else np.asarray(srp_coefficients, dtype=float)
        )
        self.n_trajectories = n_traj
        self.n_params = model.n_learn + (n_traj if estimate_srp else 0)
        self.weights = None if sigmas is None else 1.0 / np.asarray(sigmas, dtype=float)
        self.threads = int(threads or os.cpu_count() or 1)
        self.max_steps = int(max_steps)

    # ---------------------------------------------------------------- parameter mapping
    def _runtime_params(self, theta: np.ndarray, arc_idx: np.ndarray) -> np.ndarray:
        """Runtime parameters (n_sys, len(arc_idx)) of the compiled system for these arcs."""
        m = self.model
        out = np.zeros((m.n_system_params, len(arc_idx)))
        out[: m.n_learn] = np.asarray(theta[: m.n_learn])[:, None]
        if m.srp is not None:
            traj = self.arcs.trajectory[arc_idx]
            coeff = theta[m.n_learn :] if self.estimate_srp else self.srp_coefficients
            out[m.n_learn] = np.asarray(coeff)[traj]
        return out

    def _scatter_columns(self, jac_sys: np.ndarray, arc_idx: np.ndarray) -> np.ndarray:
        """Map d state / d runtime-par (k, m, 6, n_sys) to d state / d theta."""
        m = self.model
        if not self.estimate_srp:
            return jac_sys[..., : m.n_learn]
        out = np.zeros((*jac_sys.shape[:-1], self.n_params))
        out[..., : m.n_learn] = jac_sys[..., : m.n_learn]
        cols = m.n_learn + self.arcs.trajectory[arc_idx]
        for k, c in enumerate(cols):
            out[k, ..., c] = jac_sys[k, ..., m.n_learn]
        return out

    # ---------------------------------------------------------------- propagation
    def _integrators(self, variational: bool):
        base = compiled_integrator(self.model, variational=variational, tol=self.tol)
        key = "_var_copies" if variational else "_plain_copies"
        copies = getattr(self, key, None)
        if copies is None:
            copies = [base] + [copy.deepcopy(base) for _ in range(self.threads - 1)]
            setattr(self, key, copies)
        return copies

    def predict(self, theta, arc_indices=None, *, sensitivities: bool = False) -> Prediction:
        """Predicted states (and sensitivities) of the selected arcs at their sample times."""
        theta = np.asarray(theta, dtype=float)
        if theta.shape != (self.n_params,):
            raise ValueError(f"theta must have {self.n_params} entries, got {theta.shape}")
        idx = np.arange(self.arcs.n_arcs) if arc_indices is None else np.asarray(arc_indices)
        variational = sensitivities and self.model.n_system_params > 0
        integrators = self._integrators(variational)
        batch = integrators[0].batch_size
        n_sys = self.model.n_system_params
        n_m = self.arcs.samples_per_arc
        states = np.empty((len(idx), n_m, 6))
        jac_sys = np.empty((len(idx), n_m, 6, n_sys)) if variational else None
        chunks = [idx[i : i + batch] for i in range(0, len(idx), batch)]
        starts = list(range(0, len(idx), batch))

        def work(worker: int):
            ta = integrators[worker]
            for c in range(worker, len(chunks), len(integrators)):
                sel = chunks[c]
                pad = np.concatenate([sel, np.repeat(sel[-1:], batch - len(sel))])
                times = self.arcs.times[pad]
                ta.set_time(times[:, 0].copy())
                st = ta.state
                st[:] = 0.0
                st[:6] = self.arcs.states[pad, 0].T
                if n_sys:
                    ta.pars[:] = self._runtime_params(theta, pad)
                limit = _StepLimit(self.max_steps)
                res = ta.propagate_grid(np.ascontiguousarray(times.T), callback=limit)
                if limit.exceeded:
                    raise PropagationError(
                        f"arcs {sel.tolist()} needed more than {self.max_steps} Taylor steps: "
                        "the parameters make the dynamics stiff or singular"
                    )
                grid_states = res[-1]  # (m, n_state, batch)
                if not np.all(np.isfinite(grid_states)) or grid_states.shape[0] != n_m:
                    raise PropagationError(f"arcs {sel.tolist()} did not propagate to the end")
                k0 = starts[c]
                k1 = k0 + len(sel)
                states[k0:k1] = np.transpose(grid_states[:, :6, : len(sel)], (2, 0, 1))
                if variational:
                    sens = grid_states[:, 6:, : len(sel)].reshape(n_m, 6, n_sys, len(sel))
                    jac_sys[k0:k1] = np.transpose(sens, (3, 0, 1, 2))

        n_workers = min(len(integrators), len(chunks))
        if n_workers <= 1:
            work(0)
        else:
            with ThreadPoolExecutor(n_workers) as pool:
                for f in [pool.submit(work, w) for w in range(n_workers)]:
                    f.result()
        jac = self._scatter_columns(jac_sys, idx) if variational else None
        if sensitivities and jac is None:
            jac = np.zeros((len(idx), n_m, 6, self.n_params))
        return Prediction(states, jac)

    # ---------------------------------------------------------------- least squares
    def residuals(self, theta, arc_indices=None) -> np.ndarray:
        """r = y - x (weighted when sigmas were given), shape (n_arcs, m, 6)."""
        idx = np.arange(self.arcs.n_arcs) if arc_indices is None else np.asarray(arc_indices)
        r = self.arcs.states[idx] - self.predict(theta, idx).states
        return r if self.weights is None else r * self.weights

    def cost(self, theta, arc_indices=None) -> float:
        r = self.residuals(theta, arc_indices)
        return 0.5 * float(np.sum(r * r))

    def design(self, theta, arc_indices=None):
        """(r, A) with r (N,) and A (N, n_params) for N = arcs x samples x 6 (materialised)."""
        idx = np.arange(self.arcs.n_arcs) if arc_indices is None else np.asarray(arc_indices)
        pred = self.predict(theta, idx, sensitivities=True)
        r = self.arcs.states[idx] - pred.states
        a = -pred.jacobian
        if self.weights is not None:
            r = r * self.weights
            a = a * self.weights[:, None]
        return r.reshape(-1), a.reshape(-1, self.n_params)

    def normal_equations(self, theta, arc_indices=None, chunk: int = 64):
        """(J, A^T r, A^T A), accumulated over chunks of arcs without materialising A."""
        idx = np.arange(self.arcs.n_arcs) if arc_indices is None else np.asarray(arc_indices)
        n = self.n_params
        cost, atr, ata = 0.0, np.zeros(n), np.zeros((n, n))
        for i in range(0, len(idx), chunk):
            r, a = self.design(theta, idx[i : i + chunk])
            cost += 0.5 * float(r @ r)
            atr += a.T @ r
            ata += a.T @ a
        return cost, atr, ata

    def gradient(self, theta, arc_indices=None, chunk: int = 64):
        """(J, A^T r): the cost and its gradient."""
        idx = np.arange(self.arcs.n_arcs) if arc_indices is None else np.asarray(arc_indices)
        cost, atr = 0.0, np.zeros(self.n_params)
        for i in range(0, len(idx), chunk):
            r, a = self.design(theta, idx[i : i + chunk])
            cost += 0.5 * float(r @ r)
            atr += a.T @ r
        return cost, atr
