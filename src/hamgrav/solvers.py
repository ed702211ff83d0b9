"""Solvers of the arc least-squares problem: Levenberg-Marquardt (+ Kaula) and Adam.

Both act on an :class:`~hamgrav.sensitivity.ArcProblem` through the same exact sensitivities
(``normal_equations`` for LM, ``gradient`` for Adam), so a comparison between them, or between
representations, never mixes different gradient information.

Every solver returns a :class:`SolveResult` with the final (best) parameters and a per-
iteration history; ``callback(iteration, record)`` reports progress.
"""

from __future__ import annotations

import json
import math
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from .sensitivity import ArcProblem, PropagationError
from .terms import SphericalHarmonics, sh_index

__all__ = [
    "SolveResult",
    "LevenbergMarquardt",
    "Adam",
    "kaula_diagonal",
    "split_validation",
    "scan_kaula",
]


@dataclass
class SolveResult:
    params: np.ndarray
    cost: float
    iterations: int
    converged: bool
    message: str
    history: dict = field(default_factory=dict)
    wall_s: float = 0.0
    best_iteration: int = 0


def kaula_diagonal(problem: ArcProblem) -> np.ndarray:
    """K = diag(l^4) on the SH block of the parameters, 0 elsewhere (Kaula's rule)."""
    k = np.zeros(problem.n_params)
    term = problem.model.learnable
    if isinstance(term, SphericalHarmonics):
        k[: term.n_params] = [float(l) ** 4 for _, l, _ in sh_index(term.degree)]
    return k


def split_validation(n_arcs: int, fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Seeded split of arc indices into (training, validation)."""
    if not 0.0 <= fraction < 0.5:
        raise ValueError("validation fraction must lie in [0, 0.5)")
    rng = np.random.default_rng(seed)
    order = rng.permutation(n_arcs)
    n_val = int(round(fraction * n_arcs))
    return np.sort(order[n_val:]), np.sort(order[:n_val])


def _solve_spd(matrix: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    try:
        with warnings.catch_warnings():
            # near-singular normal matrices are expected (weakly observed directions); the
            # damping and the accept/reject test handle them
            warnings.simplefilter("ignore", scipy.linalg.LinAlgWarning)
            return scipy.linalg.solve(matrix, rhs, assume_a="pos")
    except (np.linalg.LinAlgError, scipy.linalg.LinAlgError):
        return np.linalg.lstsq(matrix, rhs, rcond=None)[0]


@dataclass
class LevenbergMarquardt:
    """Gauss-Newton with Levenberg-Marquardt damping (the paper's schedule).

    (A^T A + lambda diag(A^T A) + alpha K) dc = -(A^T r + alpha K c); a step is accepted when
    the (regularised) cost drops (lambda /= 3, floored), else rejected (lambda *= 10). Stops at
    a relative cost change below ``rtol`` or after ``max_iter`` iterations. With validation
    arcs, the iterate with the lowest validation cost is returned.
    """

    lambda0: float = 1e-6
    lambda_floor: float = 1e-14
    lambda_down: float = 3.0
    lambda_up: float = 10.0
    rtol: float = 1e-6
    max_iter: int = 50
    kaula_alpha: float = 0.0

    def describe(self) -> dict:
        return {"name": "levenberg-marquardt", **self.__dict__}

    def solve(
        self,
        problem: ArcProblem,
        theta0: np.ndarray | None = None,
        *,
        train: np.ndarray | None = None,
        validation: np.ndarray | None = None,
        callback: Callable[[int, dict], None] | None = None,
        checkpoint: Callable[[np.ndarray, dict], None] | None = None,
        resume: dict | None = None,
    ) -> SolveResult:
        """Run LM. ``checkpoint(theta, state)`` is called after every accepted step; passing
        the state back as ``resume`` (with theta as ``theta0``) continues from there."""
        start = time.perf_counter()
        theta = np.zeros(problem.n_params) if theta0 is None else np.array(theta0, dtype=float)
        kaula = self.kaula_alpha * kaula_diagonal(problem)

        def reg_cost(c, th):
            return c + 0.5 * float(th @ (kaula * th))

        try:
            cost, atr, ata = problem.normal_equations(theta, train)
        except PropagationError as exc:
            raise PropagationError(f"the initial parameters do not propagate: {exc}") from None
        cost = reg_cost(cost, theta)
        lam = self.lambda0 if resume is None else float(resume["lambda"])
        history = {"cost": [cost], "lambda": [lam], "accepted": [True], "time_s": [0.0]}
        best = (np.inf, theta.copy(), 0)
        if validation is not None and len(validation):
            history["validation"] = [problem.cost(theta, validation)]
            best = (history["validation"][0], theta.copy(), 0)
        converged, message, it = False, "iteration cap reached", 0
        for it in range(1, self.max_iter + 1):
            lhs = ata + lam * np.diag(np.diag(ata)) + np.diag(kaula)
            step = _solve_spd(lhs, -(atr + kaula * theta))
            trial = theta + step
            try:
                trial_cost = reg_cost(problem.cost(trial, train), trial)
                accepted = trial_cost < cost
                if accepted:
                    _, trial_atr, trial_ata = problem.normal_equations(trial, train)
            except PropagationError:
                trial_cost, accepted = math.inf, False
            if accepted:
                rel = (cost - trial_cost) / max(cost, 1e-300)
                theta, cost = trial, trial_cost
                lam = max(lam / self.lambda_down, self.lambda_floor)
            else:
                lam *= self.lambda_up
            history["cost"].append(cost)
            history["lambda"].append(lam)
            history["accepted"].append(accepted)
            history["time_s"].append(time.perf_counter() - start)
            if "validation" in history:
                val = problem.cost(theta, validation) if accepted else history["validation"][-1]
                history["validation"].append(val)
                if val < best[0]:
                    best = (val, theta.copy(), it)
            if callback is not None:
                callback(it, {k: v[-1] for k, v in history.items()})
            if accepted and rel < self.rtol:
                converged, message = True, f"relative cost change {rel:.2e} < {self.rtol:g}"
                break
            if lam > 1e12:
                converged, message = True, "damping saturated: no further decrease possible"
                break
            if accepted:
                atr, ata = trial_atr, trial_ata
                if checkpoint is not None:
                    checkpoint(
                        theta, {"solver": "levenberg-marquardt", "iteration": it, "lambda": lam}
                    )
        if "validation" in history:
            theta, best_it = best[1], best[2]
        else:
            best_it = it
        return SolveResult(
            theta, cost, it, converged, message, history, time.perf_counter() - start, best_it
        )


@dataclass
class Adam:
    """Adam on the exact gradient, mini-batches of arcs, cosine learning-rate schedule.

    The cost of a mini-batch is normalised by its number of residual components, so the
    learning rate does not depend on the batch size. With validation arcs, the validation cost
    is evaluated every ``eval_every`` steps and the best iterate is returned.
    """

    learning_rate: float = 1e-2
    final_learning_rate_ratio: float = 0.02
    steps: int = 300
    batch_size: int = 24
    beta1: float = 0.9
    beta2: float = 0.999
    epsilon: float = 1e-8
    eval_every: int = 10
    seed: int = 0

    def describe(self) -> dict:
        return {"name": "adam", **self.__dict__}

    def learning_rate_at(self, step: int) -> float:
        lo = self.learning_rate * self.final_learning_rate_ratio
        return lo + 0.5 * (self.learning_rate - lo) * (1 + math.cos(math.pi * step / self.steps))

    def solve(
        self,
        problem: ArcProblem,
        theta0: np.ndarray | None = None,
        *,
        train: np.ndarray | None = None,
        validation: np.ndarray | None = None,
        callback: Callable[[int, dict], None] | None = None,
        checkpoint: Callable[[np.ndarray, dict], None] | None = None,
        checkpoint_every: int = 25,
        resume: dict | None = None,
    ) -> SolveResult:
        """Run Adam. ``checkpoint(theta, state)`` is called every ``checkpoint_every`` steps
        with everything needed to continue; passing that state back as ``resume`` continues
        the run exactly where it stopped."""
        start = time.perf_counter()
        rng = np.random.default_rng(self.seed)
        theta = np.zeros(problem.n_params) if theta0 is None else np.array(theta0, dtype=float)
        train = np.arange(problem.arcs.n_arcs) if train is None else np.asarray(train)
        per_arc = problem.arcs.samples_per_arc * 6
        m = np.zeros_like(theta)
        v = np.zeros_like(theta)
        history = {"step": [], "train": [], "validation": [], "time_s": []}
        has_val = validation is not None and len(validation) > 0

        def val_cost(th):
            return problem.cost(th, validation) / (len(validation) * per_arc)

        best = (val_cost(theta) if has_val else np.inf, theta.copy(), 0)
        order = rng.permutation(train)
        cursor = 0
        train_cost = np.nan
        first = 1
        if resume is not None:
            first = int(resume["step"]) + 1
            m, v = np.asarray(resume["m"]), np.asarray(resume["v"])
            best = (
                float(resume["best_val"]),
                np.asarray(resume["best_theta"]),
                int(resume["best_step"]),
            )
            order, cursor = np.asarray(resume["order"]), int(resume["cursor"])
            rng.bit_generator.state = json.loads(resume["rng"])
            history = {k: list(v_) for k, v_ in json.loads(resume["history"]).items()}
            train_cost = float(resume["train_cost"])
        for step in range(first, self.steps + 1):
            if cursor + self.batch_size > len(order):
                order, cursor = rng.permutation(train), 0
            batch = order[cursor : cursor + self.batch_size]
            cursor += self.batch_size
            cost, grad = problem.gradient(theta, batch)
            scale = 1.0 / (len(batch) * per_arc)
            grad = grad * scale
            train_cost = cost * scale
            m = self.beta1 * m + (1 - self.beta1) * grad
            v = self.beta2 * v + (1 - self.beta2) * grad * grad
            m_hat = m / (1 - self.beta1**step)
            v_hat = v / (1 - self.beta2**step)
            theta = theta - self.learning_rate_at(step - 1) * m_hat / (
                np.sqrt(v_hat) + self.epsilon
            )
            if step % self.eval_every == 0 or step == self.steps:
                val = val_cost(theta) if has_val else np.nan
                history["step"].append(step)
                history["train"].append(train_cost)
                history["validation"].append(val)
                history["time_s"].append(time.perf_counter() - start)
                if has_val and val < best[0]:
                    best = (val, theta.copy(), step)
                if callback is not None:
                    callback(step, {"train": train_cost, "validation": val})
            if checkpoint is not None and (step % checkpoint_every == 0):
                checkpoint(
                    theta,
                    {
                        "solver": "adam",
                        "step": step,
                        "m": m,
                        "v": v,
                        "best_val": best[0],
                        "best_theta": best[1],
                        "best_step": best[2],
                        "order": order,
                        "cursor": cursor,
                        "rng": json.dumps(rng.bit_generator.state),
                        "history": json.dumps(history),
                        "train_cost": train_cost,
                    },
                )
        if has_val:
            theta, best_step = best[1], best[2]
        else:
            best_step = self.steps
        return SolveResult(
            theta,
            float(train_cost),
            self.steps,
            True,
            f"{self.steps} steps; best validation at step {best_step}",
            history,
            time.perf_counter() - start,
            best_step,
        )


def scan_kaula(
    problem: ArcProblem,
    metric: Callable[[np.ndarray], float],
    alphas=(1e-8, 1e-7, 1e-6, 1e-5, 1e-4),
    solver: LevenbergMarquardt | None = None,
    theta0: np.ndarray | None = None,
):
    """Fit with each Kaula weight and keep the one with the lowest ``metric(params)``
    (the caller supplies the metric, e.g. a truth-based field error, as in the paper).

    Returns (best alpha, best SolveResult, list of (alpha, metric value))."""
    solver = solver or LevenbergMarquardt()
    scores = []
    best = None
    for alpha in alphas:
        lm = LevenbergMarquardt(**{**solver.__dict__, "kaula_alpha": float(alpha)})
        result = lm.solve(problem, theta0)
        score = float(metric(result.params))
        scores.append((float(alpha), score))
        if best is None or score < best[2]:
            best = (float(alpha), result, score)
    return best[0], best[1], scores
