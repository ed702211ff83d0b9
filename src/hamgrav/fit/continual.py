"""Continual learning: tracking arriving in stages, each fit warm-started from the previous.

At stage k the estimator is fitted to every arc received so far (stages 0..k), starting from
the parameters of stage k-1 (or from scratch when ``warm_start`` is off). Validation arcs are
chosen once: each stage's arriving arcs are split (seeded by the estimator's seed and the stage)
and an arc held out once stays held out at every later stage, so no stage ever trains on it.

A warm stage's first normal equations are the previous stage's (formed at its returned
parameters, the new stage's start) plus the new training arcs'.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from ..core.arcs import Arcs
from ..errors import InputError, PropagationError
from .anchor import Anchor, AnchorSettings, anchor_points
from .base import Solver, SolveResult
from .estimator import GravityEstimator, validation_split

__all__ = ["StageRecord", "ContinualFit", "fit_continual"]


@dataclass(frozen=True, eq=False)
class StageRecord:
    """One stage of a continual fit: ``arcs`` (global indices) seen so far, the validation
    arcs among them (global indices), whether the fit was warm-started, its result, and
    ``relative_cost``: the stage's cost on its validation arcs (its training arcs when it has
    none, ``checked_on`` says which) over the cost of no correction on them
    (:mod:`hamgrav.fit.diagnostics`; None without learnable parameters); ``anchor``: the
    field anchor the stage's fit ran with (weight, clearance [canonical length], points;
    None: none)."""

    stage: int
    arcs: np.ndarray
    validation: np.ndarray
    warm_started: bool
    result: SolveResult
    relative_cost: float | None = None
    checked_on: str | None = None
    anchor: dict | None = None

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
            "relative_cost": self.relative_cost,
            "checked_on": self.checked_on,
            **({"anchor": self.anchor} if self.anchor else {}),
        }


class ContinualFit:
    """A continual fit driven one stage at a time, for campaigns that decide what arrives next
    from the current model (e.g. a D-optimal choice of the next orbits).

    ``add(new)`` fits ``estimator`` to every arc received so far plus the arc indices ``new``
    (of ``arcs``), warm-started from the previous stage's parameters when ``warm_start`` and
    there is one; it returns the stage's :class:`StageRecord`. Validation arcs follow the
    module's rule (each arriving stage split once, seeded by the estimator's seed and the
    stage number). :func:`fit_continual` is this loop over a fixed list of stages.
    """

    def __init__(self, estimator: GravityEstimator, arcs: Arcs, *, warm_start: bool = True):
        self.estimator = estimator
        self.arcs = arcs
        self.warm_start = warm_start
        self.records: list[StageRecord] = []
        self._seen = np.zeros(0, dtype=int)
        self._held_out = np.zeros(0, dtype=int)

    @property
    def params(self) -> np.ndarray | None:
        """Parameters of the last stage (None before the first)."""
        return self.records[-1].result.params if self.records else None

    def fork(self) -> ContinualFit:
        """A run that continues from this one's last stage on its own: a fresh estimator of
        the same hyperparameters, the same arcs, stages and hold-outs. Stages added to either
        leave the other as it was (e.g. the same refit with and without new arcs)."""
        twin = ContinualFit(GravityEstimator(**self.estimator.get_params()), self.arcs)
        twin.warm_start = self.warm_start
        twin.records = list(self.records)
        twin._seen, twin._held_out = self._seen.copy(), self._held_out.copy()
        return twin

    def add(
        self,
        new: Sequence[int],
        *,
        validate: bool = True,
        solver: Solver | None = None,
        arc_weights: np.ndarray | None = None,
        validation_arcs: Sequence[int] | None = None,
        anchor: AnchorSettings | None = None,
    ) -> StageRecord:
        """Fit the next stage, which brings the arcs ``new`` (indices into ``arcs``). The
        returned record's result holds the stage's normal equations (n_params^2 per member),
        which the next stage adds to; ``records`` drops them from older stages.

        ``validate`` False: none of the new arcs is held out and the fit returns its last
        iterate (no validation stop or choice); the arcs held out at earlier stages stay out
        of training. ``solver`` replaces the estimator's (warm) solver for this stage.
        ``arc_weights`` (one per arc of ``arcs``): each arc's weight in this stage's cost
        (:meth:`GravityEstimator.fit`); a stage without them weighs every arc 1.
        ``validation_arcs`` (among ``new``): the arcs this stage holds out, and its only
        validation set, in place of the module's rule: the fit returns the iterate (its start
        included) with the lowest cost on them, while the arcs held out at earlier stages stay
        out of training without a say (e.g. descents that should decide a refit on them).
        ``anchor``: a warm stage's learned field is held near the previous stage's at the
        harmonic penalty's collocation points farther than ``anchor.clearance`` from every
        sample of the new arcs (or from ``anchor.clear_of``; :mod:`hamgrav.fit.anchor`); a
        network fit by LM only, refused before the first stage or with ``warm_start`` off; a
        stage restarted cold (the previous model cannot propagate the new arcs) runs
        without it, and its fit record has no "anchor"."""
        if arc_weights is not None:
            arc_weights = np.asarray(arc_weights, dtype=float)
            if arc_weights.shape != (self.arcs.n_arcs,):
                raise InputError(
                    f"arc_weights has shape {arc_weights.shape}; give one weight per arc of "
                    f"the run ({self.arcs.n_arcs},)"
                )
        estimator = self.estimator
        k = len(self.records)
        new = np.asarray(new, dtype=int)
        # the run's arcs change only once the stage is fitted: a refused or failed stage
        # leaves the run as it was
        held_out = self._held_out
        seen = np.concatenate([self._seen, new])
        if validation_arcs is not None:
            voting = np.unique(np.asarray(validation_arcs, dtype=int))
            if not validate or not len(voting) or not np.all(np.isin(voting, new)):
                raise InputError(
                    "validation_arcs must be a nonempty subset of the stage's new arcs, with "
                    f"validate on; got {voting.tolist()} for new arcs {new.tolist()}"
                )
            # the earlier hold-outs stay out of training; only the given arcs vote
            fitted = seen[~np.isin(seen, held_out)]
            held_out = np.union1d(held_out, voting)
            local_val = np.flatnonzero(np.isin(fitted, voting))
        else:
            if validate and estimator.holdout_fraction > 0:
                _, val = validation_split(len(new), estimator.holdout_fraction, estimator.seed + k)
                held_out = np.union1d(held_out, new[val])
            # without validation the fit sees only its training arcs (none to hold out)
            fitted = seen if validate else seen[~np.isin(seen, held_out)]
            if validate:
                local_val = np.flatnonzero(np.isin(seen, held_out)) if len(held_out) else None
            else:
                local_val = np.zeros(0, dtype=int)
        subset = self.arcs.subset(fitted)
        if arc_weights is not None:
            arc_weights = arc_weights[fitted]
        theta = self.params
        warm = self.warm_start and theta is not None
        anchored = None
        if anchor is not None:
            if not warm:
                raise InputError(
                    "the field anchor holds a stage near the previous one: fit a first stage "
                    "(with warm_start on) before anchoring one"
                )
            points = anchor_points(
                estimator.collocation_points(subset),
                self.arcs.states[new][..., :3],
                anchor,
                estimator.body_of(subset).brillouin_radius,
            )
            anchored = Anchor(points, anchor.weight, anchor.quantity)
        # the previous stage's training arcs keep their indices (arcs are appended), so its
        # normal equations at theta are added to rather than formed again
        previous = self.records[-1].result if warm else None
        try:
            estimator.fit(
                subset,
                init=theta if warm else None,
                validation=local_val,
                reuse=previous,
                solver=solver,
                warm=warm,
                arc_weights=arc_weights,
                anchor=anchored,
            )
        except PropagationError:
            if not warm:
                raise
            # the previous stage's model does not carry the new arcs: restart this stage
            # (without the anchor, which holds a warm start: its record then has none)
            warm = False
            estimator.fit(subset, validation=local_val, solver=solver, arc_weights=arc_weights)
        self._seen, self._held_out = seen, held_out
        relative = estimator.diagnostics_.get("relative_cost")
        if relative is not None and not np.isfinite(relative):
            relative = None  # no correction costs nothing on these arcs: nothing to compare
        record = StageRecord(
            k,
            seen.copy(),
            held_out.copy(),
            warm,
            estimator.result_,
            relative,
            estimator.diagnostics_.get("checked_on"),
            None
            if anchored is None or not warm
            else {**anchored.record(), "clearance": anchor.clearance},
        )
        if self.records:
            # only the newest stage's normal equations are added to: drop the older ones
            # (n_params^2 per member and stage)
            last = self.records[-1]
            self.records[-1] = replace(last, result=_without_normals(last.result))
        self.records.append(record)
        estimator.fitted_ = replace(estimator.fitted_, stages=[r.summary() for r in self.records])
        return record


def _without_normals(result: SolveResult) -> SolveResult:
    """``result`` without its (and its members') normal equations."""
    members = tuple(m if m is None else replace(m, normals=None) for m in result.members)
    return replace(result, normals=None, members=members)


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
    run = ContinualFit(estimator, arcs, warm_start=warm_start)
    for new in stages:
        record = run.add(new)
        if on_stage is not None:
            on_stage(record)
    return run.records
