"""Adam on the exact gradient, mini-batches of arcs, cosine learning-rate schedule."""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass

import numpy as np

from ..errors import DatasetError
from .base import Outcome, Solver, SolveResult

__all__ = ["Adam"]


@dataclass(frozen=True)
class Adam(Solver):
    """Adam with a cosine learning-rate schedule from ``learning_rate`` down to
    ``learning_rate * final_learning_rate_ratio`` over ``steps`` steps of ``batch_size`` arcs.

    The cost of a mini-batch is normalised by its number of residual components, so the
    learning rate does not depend on the batch size. With validation arcs, the validation cost
    is evaluated every ``eval_every`` steps and the best iterate is returned. ``seed`` seeds the
    mini-batch order.
    """

    learning_rate: float = 1e-2
    final_learning_rate_ratio: float = 0.02
    steps: int = 1500
    batch_size: int = 24
    beta1: float = 0.9
    beta2: float = 0.999
    epsilon: float = 1e-8
    eval_every: int = 10
    checkpoint_every: int = 25
    seed: int = 0

    name = "adam"

    def learning_rate_at(self, step: int) -> float:
        """The scheduled learning rate at 0-based ``step``."""
        lo = self.learning_rate * self.final_learning_rate_ratio
        return lo + 0.5 * (self.learning_rate - lo) * (1 + math.cos(math.pi * step / self.steps))

    def _iterate(
        self, problem, theta, train, validation, callback, checkpoint, resume, known
    ) -> SolveResult:
        del known  # no normal equations to add to
        start = time.perf_counter()
        rng = np.random.default_rng(self.seed)
        train = np.arange(problem.arcs.n_arcs) if train is None else np.asarray(train)
        per_arc = problem.arcs.samples_per_arc * 6
        m = np.zeros_like(theta)
        v = np.zeros_like(theta)
        history = {"step": [], "train": [], "validation": [], "time_s": []}
        has_val = validation is not None

        def val_cost(th):
            return problem.cost(th, validation) / (len(validation) * per_arc)

        best = (val_cost(theta) if has_val else np.inf, theta.copy(), 0)
        initial_cost = best[0] if has_val else np.nan
        order = rng.permutation(train)
        cursor = 0
        train_cost = np.nan
        first = 1
        if resume is not None:
            try:
                first = int(resume["step"]) + 1
                m, v = np.asarray(resume["m"], float), np.asarray(resume["v"], float)
                best = (
                    float(resume["best_val"]),
                    np.asarray(resume["best_theta"], float),
                    int(resume["best_step"]),
                )
                order, cursor = np.asarray(resume["order"]), int(resume["cursor"])
                rng.bit_generator.state = json.loads(resume["rng"])
                history = {k: list(v_) for k, v_ in json.loads(resume["history"]).items()}
                train_cost = float(resume["train_cost"])
                initial_cost = float(resume.get("initial_cost", np.nan))
                consistent = (
                    2 <= first <= self.steps + 1
                    and 0 <= best[2] < first
                    and m.shape == v.shape == best[1].shape == theta.shape
                    and np.all(np.isfinite(best[1]))
                    and np.all(np.isfinite(m))
                    and np.all(np.isfinite(v))
                    and np.all(v >= 0)
                    and order.dtype.kind in "iu"
                    and set(order.tolist()) <= set(np.asarray(train).tolist())
                    and cursor >= 0  # past the end: the next step draws a new order
                )
            except (KeyError, TypeError, ValueError, AttributeError, OverflowError) as exc:
                raise DatasetError(
                    f"the checkpoint's Adam state cannot be read ({exc}); remove the "
                    "checkpoint and fit again without --resume"
                ) from None
            if not consistent:
                raise DatasetError(
                    "the checkpoint's Adam state does not fit this run (its step, moments or "
                    "batch order); remove the checkpoint and fit again without --resume"
                )
        for step in range(first, self.steps + 1):
            if cursor + self.batch_size > len(order):
                order, cursor = rng.permutation(train), 0
            batch = order[cursor : cursor + self.batch_size]
            cursor += self.batch_size
            cost, grad = problem.gradient(theta, batch)
            scale = 1.0 / (len(batch) * per_arc)
            grad = grad * scale
            train_cost = cost * scale
            if step == 1 and not has_val:
                initial_cost = train_cost
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
            if checkpoint is not None and (step % self.checkpoint_every == 0):
                checkpoint(
                    theta,
                    {
                        "solver": self.name,
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
                        "initial_cost": initial_cost,
                    },
                )
        best_step = best[2] if has_val else self.steps
        if has_val:
            theta = best[1]
        if not np.all(np.isfinite(theta)):
            outcome, message = Outcome.DIVERGED, "the parameters became non-finite"
        elif has_val and best_step == 0:
            outcome = Outcome.NO_IMPROVEMENT
            message = f"{self.steps} steps; no step lowered the validation cost"
        else:
            outcome = Outcome.COMPLETED
            message = f"{self.steps} steps; best validation at step {best_step}"
        return SolveResult(
            theta,
            float(train_cost),
            float(initial_cost),
            self.steps,
            best_step,
            outcome,
            message,
            history,
        )
