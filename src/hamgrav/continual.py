"""Continual learning: data arriving in stages, each fit warm-started from the previous one.

At stage k the cost is minimised over all arcs received so far (stages 0..k), starting from
the parameters of stage k-1 (or from ``theta0`` / scratch when ``warm_start`` is off). When a
validation fraction is given, each stage holds out that fraction of its arcs (seeded), and the
solver keeps the best-validation iterate.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from .model import Model
from .sensitivity import ArcProblem, PropagationError
from .solvers import SolveResult, split_validation
from .tracking import Arcs

__all__ = ["StageRecord", "fit_continual"]


@dataclass
class StageRecord:
    stage: int
    n_arcs: int
    iterations: int
    best_iteration: int
    cost: float
    wall_s: float
    warm_started: bool
    result: SolveResult


def fit_continual(
    model: Model,
    arcs: Arcs,
    stages: Sequence[Sequence[int]],
    solver,
    theta0: np.ndarray | None = None,
    *,
    warm_start: bool = True,
    validation_fraction: float = 0.0,
    seed: int = 0,
    problem_kwargs: dict | None = None,
    on_stage: Callable[[StageRecord], None] | None = None,
) -> list[StageRecord]:
    """Fit ``model`` stage by stage; ``stages`` lists the arc indices arriving at each stage."""
    records: list[StageRecord] = []
    theta = theta0
    seen: list[int] = []
    start = None if theta0 is None else np.array(theta0, dtype=float)
    for k, new in enumerate(stages):
        seen.extend(int(i) for i in new)
        subset = arcs.subset(np.asarray(seen))
        problem = ArcProblem(model, subset, **(problem_kwargs or {}))
        train = validation = None
        if validation_fraction > 0:
            train, validation = split_validation(subset.n_arcs, validation_fraction, seed + k)
        init = theta if (warm_start and theta is not None) else start
        warm_failed = False
        try:
            result = solver.solve(problem, init, train=train, validation=validation)
        except PropagationError:
            if init is start:
                raise
            # the previous stage's model does not carry the new arcs: restart this stage
            warm_failed = True
            result = solver.solve(problem, start, train=train, validation=validation)
        theta = result.params
        record = StageRecord(
            k,
            subset.n_arcs,
            result.iterations,
            result.best_iteration,
            result.cost,
            result.wall_s,
            warm_start and k > 0 and not warm_failed,
            result,
        )
        records.append(record)
        if on_stage is not None:
            on_stage(record)
    return records
