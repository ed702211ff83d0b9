"""Continual learning: tracking arriving in stages, each fit warm-started from the previous.

At stage k the estimator is fitted to every arc received so far (stages 0..k), starting from
the parameters of stage k-1 (or from scratch when ``warm_start`` is off). Validation arcs are
chosen once: each stage's arriving arcs are split (seeded by the estimator's seed and the stage)
and an arc held out once stays held out at every later stage, so no stage ever trains on it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from ..core.arcs import Arcs
from ..errors import PropagationError
from .base import SolveResult
from .estimator import GravityEstimator, validation_split

__all__ = ["StageRecord", "fit_continual"]


@dataclass(frozen=True, eq=False)
class StageRecord:
    """One stage of a continual fit: ``arcs`` (global indices) seen so far, the validation
    arcs among them (global indices), whether the fit was warm-started, and its result."""

    stage: int
    arcs: np.ndarray
    validation: np.ndarray
    warm_started: bool
    result: SolveResult

    @property
    def n_arcs(self) -> int:
        """Arcs seen up to this stage."""
        return len(self.arcs)

    def summary(self) -> dict:
        """Plain-data summary of the stage."""
        return {
            "stage": self.stage,
            "n_arcs": self.n_arcs,
            "n_validation": int(len(self.validation)),
            "warm_started": self.warm_started,
            **self.result.summary(),
        }


def fit_continual(
    estimator: GravityEstimator,
    arcs: Arcs,
    stages: Sequence[Sequence[int]],
    *,
    warm_start: bool = True,
    on_stage: Callable[[StageRecord], None] | None = None,
) -> list[StageRecord]:
    """Fit ``estimator`` stage by stage; ``stages`` lists the arc indices arriving at each.
    Warm-started stages run the estimator's ``warm_solver`` when it has one."""
    records: list[StageRecord] = []
    seen = np.zeros(0, dtype=int)
    held_out = np.zeros(0, dtype=int)
    theta = None
    for k, new in enumerate(stages):
        new = np.asarray(new, dtype=int)
        if estimator.holdout_fraction > 0:
            _, val = validation_split(len(new), estimator.holdout_fraction, estimator.seed + k)
            held_out = np.union1d(held_out, new[val])
        seen = np.concatenate([seen, new])
        subset = arcs.subset(seen)
        local_val = np.flatnonzero(np.isin(seen, held_out)) if len(held_out) else None
        warm = warm_start and theta is not None
        try:
            estimator.fit(
                subset,
                init=theta if warm else None,
                validation=local_val,
            )
        except PropagationError:
            if not warm:
                raise
            # the previous stage's model does not carry the new arcs: restart this stage
            warm = False
            estimator.fit(subset, validation=local_val)
        theta = estimator.params_
        record = StageRecord(k, seen.copy(), held_out.copy(), warm, estimator.result_)
        records.append(record)
        if on_stage is not None:
            on_stage(record)
    if records:
        estimator.fitted_ = replace(estimator.fitted_, stages=[r.summary() for r in records])
    return records
