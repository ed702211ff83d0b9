"""Levenberg-Marquardt (the paper's schedule), with the problem's regulariser."""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from ..errors import DatasetError, PropagationError
from .base import Outcome, Solver, SolveResult

__all__ = ["LevenbergMarquardt"]


def _solve_spd(matrix: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    # Cholesky directly, without a condition estimate. numpy's factorisation rather than
    # scipy's: the normal equations were just formed by numpy's BLAS, whose threads are still
    # spinning, and scipy's own BLAS threads competed with them (34 ms against 4 ms per
    # factorisation of 721 parameters inside a fit). Near-singular normal matrices are
    # expected (weakly observed directions); the damping and the accept/reject test handle them
    try:
        lower = np.linalg.cholesky(matrix)
        y = scipy.linalg.solve_triangular(lower, rhs, lower=True, check_finite=False)
        return scipy.linalg.solve_triangular(lower.T, y, lower=False, check_finite=False)
    except (np.linalg.LinAlgError, scipy.linalg.LinAlgError):
        return np.linalg.lstsq(matrix, rhs, rcond=None)[0]


@dataclass(frozen=True)
class LevenbergMarquardt(Solver):
    """Gauss-Newton with Levenberg-Marquardt damping.

    (A^T A + lambda diag(A^T A) + D) dc = -(A^T r + D c); a step is accepted when the
    problem's objective drops (lambda /= ``lambda_down``, floored at ``lambda_floor``), else
    rejected (lambda *= ``lambda_up``). Stops at a relative cost change below ``rtol``, when
    lambda exceeds ``lambda_ceiling`` or after ``max_iter`` iterations. A regulariser of the
    problem (:class:`~hamgrav.core.problem.Regulariser`) of residual rows is part of A^T A and
    A^T r; a quadratic prior 0.5 c.(D c) (Kaula's rule: D = alpha diag(l^4),
    :class:`~hamgrav.fit.kaula.KaulaPrior`) is D above, out of the damping scale.
    ``damping_floor`` > 0 floors the Marquardt scaling diag(A^T A) at
    that fraction of its largest entry, so that parameters the data barely see (weights of
    saturated tanh units, diag ~ 1e-50) are damped too. With validation arcs and
    ``patience``, the fit stops after ``patience`` accepted steps in a row that do not lower
    the best validation cost (rejected trials leave the iterate unchanged and do not count).
    ``validation_gate`` (with validation arcs): once an accepted step has lowered the
    validation cost, a step must lower the best validation cost as well as the training cost
    to be accepted; one that lowers only the training cost is rejected like any other trial
    (lambda *= ``lambda_up``; it does not count towards the patience), so the next trial is a
    shorter, more gradient-like step from the same iterate. From the first gain on every
    iterate is the best so far, and only those have their normal equations formed. Before
    it, steps are taken on the training cost alone (a warm start may have to leave its basin
    first).
    """

    lambda0: float = 1e-6
    lambda_floor: float = 1e-14
    lambda_down: float = 3.0
    lambda_up: float = 10.0
    lambda_ceiling: float = 1e12
    rtol: float = 1e-6
    max_iter: int = 50
    damping_floor: float = 0.0
    patience: int | None = None
    validation_gate: bool = False

    name = "levenberg-marquardt"

    def _iterate(
        self, problem, theta, train, validation, callback, checkpoint, resume, known
    ) -> SolveResult:
        start = time.perf_counter()
        prior = problem.prior_diagonal()

        try:
            # the arcs' own sums are kept beside the objective's: the fit diagnostics count the
            # directions the arcs constrain at the returned iterate without recomputing them,
            # and a warm start on more arcs adds to them
            normals = problem.arc_normals(theta, train, known=known)
        except PropagationError as exc:
            raise PropagationError(f"the initial parameters do not propagate: {exc}") from None
        cost, atr, ata = problem.regularise(theta, normals.cost, normals.atr, normals.ata)
        cost = problem.with_prior(theta, cost) if prior.any() else cost
        initial_cost = cost
        lam = self.lambda0 if resume is None else float(resume["lambda"])
        history = {"cost": [cost], "lambda": [lam], "accepted": [True], "time_s": [0.0]}
        best = (np.inf, theta.copy(), 0, normals)
        has_val = validation is not None
        if has_val:
            history["validation"] = [problem.cost(theta, validation)]
            best = (history["validation"][0], theta.copy(), 0, normals)
        outcome, message, it, n_accepted = Outcome.ITERATION_CAP, "iteration cap reached", 0, 0
        stale = 0  # accepted steps since the best validation cost
        if resume is not None and "history" in resume:
            it, cost, initial_cost, history, best, stale, n_accepted = self._restore(
                problem, resume, train, known, normals
            )
        first = it + 1
        for it in range(first, self.max_iter + 1):
            scaling = np.diag(ata)
            if self.damping_floor > 0:
                scaling = np.maximum(scaling, self.damping_floor * scaling.max())
            lhs = ata + lam * np.diag(scaling) + np.diag(prior)
            step = _solve_spd(lhs, -(atr + prior * theta))
            trial = theta + step
            try:
                trial_cost = problem.objective(trial, train)
            except PropagationError:
                trial_cost = math.inf
            accepted = trial_cost < cost
            if accepted:
                rel = (cost - trial_cost) / max(cost, 1e-300)
                val = problem.cost(trial, validation) if has_val else math.inf
                gains = val < best[0]
                # once a gated fit has lowered the validation cost, it takes only steps that
                # lower it further; the others are rejected like a rise of the training cost,
                # at the price of a propagation instead of the normal equations
                accepted = not (self.validation_gate and has_val and not gains and best[2] > 0)
            if accepted:
                ends = (
                    rel < self.rtol
                    or it == self.max_iter
                    or (has_val and self.patience is not None and stale + 1 >= self.patience)
                )
                # the normal equations at the new iterate serve the next step or, when the
                # fit stops here, the returned iterate: a fit that stops at an iterate it
                # does not return (a validation fit's last step without a gain) skips them
                trial_atr = trial_ata = trial_normals = None
                if not (has_val and ends and not gains):
                    try:
                        trial_normals = problem.arc_normals(trial, train)
                        _, trial_atr, trial_ata = problem.regularise(
                            trial, trial_normals.cost, trial_normals.atr, trial_normals.ata
                        )
                    except PropagationError:
                        accepted = False
            if accepted:
                n_accepted += 1
                theta, cost, normals = trial, trial_cost, trial_normals
                lam = max(lam / self.lambda_down, self.lambda_floor)
            else:
                lam *= self.lambda_up
            history["cost"].append(cost)
            history["lambda"].append(lam)
            history["accepted"].append(accepted)
            history["time_s"].append(time.perf_counter() - start)
            if has_val:
                history["validation"].append(val if accepted else history["validation"][-1])
                if accepted and gains:
                    best, stale = (val, theta.copy(), it, normals), 0
                elif accepted:
                    stale += 1
            if callback is not None:
                callback(it, {k: v[-1] for k, v in history.items()})
            if accepted and rel < self.rtol:
                outcome = Outcome.CONVERGED
                message = f"relative cost change {rel:.2e} < {self.rtol:g}"
                break
            if has_val and self.patience is not None and stale >= self.patience:
                outcome = Outcome.CONVERGED
                message = f"validation cost not lowered by {self.patience} accepted steps"
                break
            if lam > self.lambda_ceiling:
                outcome = Outcome.DAMPING_SATURATED
                message = "damping saturated: no further decrease possible"
                break
            if accepted:
                atr, ata = trial_atr, trial_ata
                if checkpoint is not None:
                    checkpoint(
                        theta,
                        {
                            "solver": self.name,
                            "iteration": it,
                            "lambda": lam,
                            "cost": np.float64(cost),
                            "initial_cost": np.float64(initial_cost),
                            "best_val": np.float64(best[0]),
                            "best_theta": best[1],
                            "best_iteration": best[2],
                            "stale": stale,
                            "accepted_steps": n_accepted,
                            "history": json.dumps(history),
                        },
                    )
        best_it = best[2] if has_val else it
        if has_val:
            theta, normals = best[1], best[3]
        if n_accepted == 0 or (has_val and best_it == 0):
            outcome, message = Outcome.NO_IMPROVEMENT, f"no improvement ({message})"
        return SolveResult(
            theta,
            cost,
            initial_cost,
            it,
            best_it,
            outcome,
            message,
            history,
            normals=normals,
            params_cost=None if normals is None else float(normals.cost),
        )

    def _restore(self, problem, resume: dict, train, known, normals):
        """The iteration, costs, history, best iterate, stale count and accepted steps of a
        checkpoint, so that a resumed fit takes exactly the steps the interrupted one would
        have (a checkpoint of an older hamgrav holds only the damping: its fit resumes from
        the iterate with a fresh count). ``normals``: those at the checkpoint's iterate."""
        try:
            it = int(resume["iteration"])
            best_it = int(resume["best_iteration"])
            best_theta = np.asarray(resume["best_theta"], dtype=float)
            if not (
                0 <= best_it <= it
                and best_theta.shape == normals.params.shape
                and np.all(np.isfinite(best_theta))
            ):
                raise DatasetError(
                    "the checkpoint's LM state does not fit this run (its iteration or best "
                    "iterate); remove the checkpoint and fit again without --resume"
                )
            if best_it == it:  # the iterate itself, whose normals are already formed
                best_normals = normals
            else:  # formed again at the best iterate, as the interrupted fit had them
                best_normals = problem.arc_normals(best_theta, train, known=known)
            history = {k: list(v) for k, v in json.loads(resume["history"]).items()}
            best = (float(resume["best_val"]), best_theta, best_it, best_normals)
            return (
                it,
                float(resume["cost"]),
                float(resume["initial_cost"]),
                history,
                best,
                int(resume["stale"]),
                int(resume["accepted_steps"]),
            )
        except (KeyError, TypeError, ValueError, AttributeError, OverflowError) as exc:
            raise DatasetError(
                f"the checkpoint's LM state cannot be read ({exc}); remove the checkpoint and "
                "fit again without --resume"
            ) from None
