"""Truth-free model selection: k-fold cross-validation over whole arcs or whole trajectories.

One helper chooses any hyperparameter of a fit (the Kaula weight alpha, the SH degree, the
network's harmonic-penalty weight) from the arcs alone:

- :func:`fold_assignment`: the seeded split of a set of arcs into ``k`` folds of whole arcs
  (``group="arc"``) or of whole trajectories (``group="trajectory"``: every arc of an orbit,
  descent or particle in the same fold, so that neighbouring arcs of one trajectory, whose
  errors are correlated, never sit on both sides of a split), or in bands of altitude
  (``group="altitude"``: the arcs sorted by their lowest radius and dealt into ``k``
  contiguous bands, so that the lowest band is predicted from the arcs above it: a check of
  the downward continuation, which random folds of arcs that all fly at the same altitudes do
  not make).
- :func:`cross_validate`: every candidate fitted on k - 1 folds and scored by its per-arc cost
  on the held-out fold. Every arc is held out exactly once, so every candidate is scored on
  the same arcs and the candidates' paired differences give the standard error.
- :func:`choose`: the selection rule, the one implementation every scan of hamgrav uses (the
  swarm's harmonic scan, :func:`hamgrav.fit.kaula.scan_kaula`, the estimator's ``"cv"``).

Order convention: candidates are given from the simplest (most strongly regularised: the
largest Kaula alpha, the lowest degree, the largest harmonic weight) to the most flexible.

The rule, on the costs c[j, u] of candidate j on held-out unit u (a unit is an arc, or with
``group="trajectory"`` the sum over a trajectory's arcs: the units are independent) for
n units (with ``group="altitude"`` the units are arcs):

- ``lowest``: the candidate of lowest total (equivalently mean) cost over the units.
- ``one-standard-error``: with b the lowest, d[j, u] = c[j, u] - c[b, u] and
  se_j = std(d[j, :], ddof=1) / sqrt(n) (the standard error of candidate j's mean excess
  over the lowest, paired over the units), keep the *first* (simplest) candidate j with
  mean(d[j, :]) <= se_j: the held-out arcs cannot tell it from the lowest, so the simpler
  field is kept. With a single unit (se = 0) this is the lowest.

A candidate whose fit does not propagate (:class:`~hamgrav.errors.PropagationError`) or whose
held-out cost is not finite on any unit is never kept; if none is finite, the selection fails
with :class:`~hamgrav.errors.PropagationError`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial

import numpy as np

from ..errors import InputError, PropagationError

__all__ = ["GROUPS", "RULES", "Selection", "choose", "cross_validate", "fold_assignment"]

#: Selection rules (see the module docstring); the first is the default.
RULES = ("one-standard-error", "lowest")
#: What a fold holds out whole.
GROUPS = ("arc", "trajectory", "altitude")
_PLURAL = {"arc": "arcs", "trajectory": "trajectories", "altitude": "arcs"}


def choose(costs, rule: str = "one-standard-error") -> int:
    """Index of the candidate ``rule`` keeps (module docstring), given ``costs`` (n_candidates,
    n_units): each candidate's costs on the same held-out units, candidates ordered simplest
    first, in any common unit (absolute costs: units with larger residuals weigh more, as in
    the total cost). Raises :class:`PropagationError` when no candidate's costs are all
    finite, ``ValueError`` for an unknown rule (a bug: callers check their options)."""
    if rule not in RULES:
        raise ValueError(f"unknown rule {rule!r}; one of {RULES}")
    costs = np.atleast_2d(np.asarray(costs, dtype=float))
    finite = np.isfinite(costs).all(axis=1)
    if not finite.any():
        raise PropagationError("no candidate's fit has a finite held-out cost")
    best = int(np.argmin(np.where(finite, costs.sum(axis=1), np.inf)))
    if rule == "lowest":
        return best
    excess, se = paired_excess(costs, best)
    within = finite & (excess <= se)
    within[best] = True
    return int(np.flatnonzero(within)[0])


def paired_excess(costs: np.ndarray, best: int) -> tuple[np.ndarray, np.ndarray]:
    """(mean excess over candidate ``best``, its standard error) per candidate, paired over
    the units (columns) of ``costs``; the standard error is 0 with a single unit and NaN for a
    candidate with non-finite costs."""
    costs = np.atleast_2d(np.asarray(costs, dtype=float))
    n = costs.shape[1]
    with np.errstate(invalid="ignore"):
        diff = costs - costs[best]
        excess = diff.mean(axis=1)
        se = diff.std(axis=1, ddof=1) / math.sqrt(n) if n > 1 else np.zeros(len(costs))
    bad = ~np.isfinite(costs).all(axis=1)
    excess[bad], se[bad] = math.inf, math.nan
    return excess, se


def fold_assignment(
    trajectory: np.ndarray,
    arcs: Sequence[int],
    folds: int,
    group: str = "arc",
    seed: int = 0,
    radius: np.ndarray | None = None,
) -> list[np.ndarray]:
    """The held-out arc indices of each fold: ``arcs`` (indices into ``trajectory``, the
    trajectory index of every arc) shuffled by ``seed`` in whole ``group``s (arcs, or whole
    trajectories) and dealt into ``folds`` folds of as equal size in groups as possible
    (each sorted). Fewer groups than ``folds``: one fold per group. With ``group``
    "altitude", the arcs sorted by ``radius`` (every arc's lowest radius, any unit; ties by
    index) and split into ``folds`` contiguous bands, lowest first (no shuffle). Raises
    :class:`InputError` with fewer than two groups to fold."""
    if group not in GROUPS:
        raise InputError(
            f"the cross-validation group must be one of {', '.join(GROUPS)}, got {group!r}"
        )
    arcs = np.asarray(arcs, dtype=int)
    if group == "altitude":
        if radius is None:
            raise ValueError("altitude folds need every arc's radius")  # a caller's bug
        if len(arcs) < 2 or int(folds) < 2:
            raise InputError(
                f"cross-validation needs two folds or more of arcs; the training arcs hold "
                f"{len(arcs)} for {folds} fold(s): use more arcs, or give the value"
            )
        by_height = arcs[np.lexsort((arcs, np.asarray(radius, dtype=float)[arcs]))]
        return [np.sort(b) for b in np.array_split(by_height, min(int(folds), len(arcs)))]
    keys = arcs if group == "arc" else np.asarray(trajectory)[arcs]
    groups = np.unique(keys)
    if len(groups) < 2 or int(folds) < 2:
        raise InputError(
            f"cross-validation needs two folds or more of whole {_PLURAL[group]}; the training "
            f"arcs hold {len(groups)} for {folds} fold(s): use more arcs, or give the value"
        )
    shuffled = np.random.default_rng(seed).permutation(groups)
    dealt = np.array_split(shuffled, min(int(folds), len(groups)))
    return [np.sort(arcs[np.isin(keys, part)]) for part in dealt]


@dataclass(frozen=True)
class Selection:
    """The record of a cross-validated choice (plain data through :meth:`describe`).

    Attributes:
        name: what was chosen ("kaula_alpha", "degree", "harmonic").
        candidates: the candidates, simplest first.
        rule: the rule that chose (:data:`RULES`).
        group: what a fold held out whole (:data:`GROUPS`).
        seed: the fold assignment's seed.
        folds: each fold's held-out arc indices (indices of the arcs given).
        unit_costs: (n_candidates, n_units) held-out costs per unit (arc or trajectory),
            canonical units (dimensionless when whitened); inf where a fit did not propagate.
        reference: (n_units,) the same units' cost with no correction, or None.
        fold_costs: (n_candidates, n_folds) each fold's held-out cost (relative to no
            correction when ``reference`` is given).
        index: the chosen candidate's index; ``lowest``: the lowest's.
    """

    name: str
    candidates: tuple
    rule: str
    group: str
    seed: int
    folds: tuple[np.ndarray, ...]
    unit_costs: np.ndarray
    reference: np.ndarray | None
    fold_costs: np.ndarray
    index: int
    lowest: int

    @property
    def chosen(self):
        """The kept candidate."""
        return self.candidates[self.index]

    def summary(self) -> tuple[np.ndarray, np.ndarray]:
        """(mean held-out cost, its standard error) per candidate, both relative to no
        correction's total cost when a reference is given (otherwise per unit, canonical):
        the standard error is that of the paired excess over the lowest, so candidate j is
        within one standard error when mean[j] - mean[lowest] <= se[j]."""
        n = self.unit_costs.shape[1]
        scale = n / float(self.reference.sum()) if self.reference is not None else 1.0
        mean = self.unit_costs.mean(axis=1) * scale
        _, se = paired_excess(self.unit_costs, self.lowest)
        return mean, se * scale

    def describe(self) -> dict:
        """Plain data for results.json and model files (non-finite values as None)."""
        mean, se = self.summary()
        return {
            "name": self.name,
            "candidates": [_plain(c) for c in self.candidates],
            "chosen": _plain(self.chosen),
            "lowest": _plain(self.candidates[self.lowest]),
            "rule": self.rule,
            "group": self.group,
            "folds": len(self.folds),
            "seed": int(self.seed),
            "relative_to": "no correction" if self.reference is not None else None,
            "held_out_cost": [_finite(v) for v in mean],
            "standard_error": [_finite(v) for v in se],
            "fold_costs": [[_finite(v) for v in row] for row in self.fold_costs],
            "n_held_out_arcs": int(sum(len(f) for f in self.folds)),
        }

    def lines(self, label: str | None = None) -> list[str]:
        """A few printable lines: candidate, mean held-out cost, standard error, chosen."""
        mean, se = self.summary()
        what = "relative to no correction" if self.reference is not None else "per unit"
        over = (
            "bands of altitude (lowest first)"
            if self.group == "altitude"
            else f"whole {_PLURAL[self.group]}"
        )
        out = [
            f"{label or self.name} by {len(self.folds)}-fold cross-validation over {over} "
            f"({self.rule} rule; held-out cost {what} +- standard error):"
        ]
        for k, c in enumerate(self.candidates):
            mark = " <- kept" if k == self.index else (" (lowest)" if k == self.lowest else "")
            cost = f"{mean[k]:.4g} +- {se[k]:.2g}" if math.isfinite(mean[k]) else "no propagation"
            out.append(f"  {_plain(c)!s:>8}  {cost}{mark}")
        return out


def _plain(value):
    if isinstance(value, np.generic):
        return value.item()
    return value


def _finite(value) -> float | None:
    value = float(value)
    return round(value, 8) if math.isfinite(value) else None


def _run(score, job):
    candidate, train, held = job
    try:
        costs = np.asarray(score(candidate, train, held), dtype=float)
    except PropagationError:
        return np.full(len(held), math.inf)
    return np.where(np.isfinite(costs), costs, math.inf)


def cross_validate(
    score: Callable,
    candidates: Sequence,
    trajectory: np.ndarray,
    arcs: Sequence[int],
    *,
    name: str = "candidate",
    folds: int = 5,
    group: str = "arc",
    rule: str = "one-standard-error",
    seed: int = 0,
    reference: Callable | None = None,
    mapper: Callable = map,
    radius: np.ndarray | None = None,
) -> Selection:
    """Choose among ``candidates`` (simplest first) by k-fold cross-validation on ``arcs``.

    ``score(candidate, train, held)`` fits ``candidate`` on the arc indices ``train`` (the
    other folds) and returns its costs (one per arc of ``held``, in that order; canonical,
    r.r / 2); it may raise :class:`PropagationError` (scored inf: never kept). It must be
    picklable for a Dask ``mapper``: the (candidate, fold) fits are independent work units
    run by ``mapper`` (builtin ``map`` or a Dask client's). ``trajectory``: the trajectory
    index of every arc (:attr:`hamgrav.core.arcs.Arcs.trajectory`), for ``group``
    "trajectory" and the units of the standard error. ``reference(held)``: the no-correction
    costs of those arcs, for the relative costs reported (optional). ``radius``: every arc's
    lowest radius, for ``group`` "altitude". Fold assignment (:func:`fold_assignment`) is
    seeded by ``seed``; the rule is :func:`choose`."""
    if rule not in RULES:
        raise InputError(f"the selection rule must be one of {', '.join(RULES)}, got {rule!r}")
    candidates = tuple(candidates)
    if not candidates:
        raise InputError(f"no {name} candidates to choose from")
    parts = fold_assignment(trajectory, arcs, folds, group, seed, radius)
    everything = np.sort(np.concatenate(parts))
    jobs = [(c, np.setdiff1d(everything, held), held) for c in candidates for held in parts]
    results = list(mapper(partial(_run, score), jobs))
    held_all = np.concatenate(parts)
    k = len(parts)  # the jobs run candidate by candidate, fold by fold
    arc_costs = np.stack([np.concatenate(results[j : j + k]) for j in range(0, len(jobs), k)])
    ref_arcs = None if reference is None else np.asarray(reference(held_all), dtype=float)
    # the units of the standard error: arcs, or whole trajectories (their arcs' sum)
    keys = np.asarray(trajectory)[held_all] if group == "trajectory" else held_all
    units, inverse = np.unique(keys, return_inverse=True)
    unit_costs = np.zeros((len(candidates), len(units)))
    np.add.at(unit_costs, (slice(None), inverse), arc_costs)
    unit_ref = None
    if ref_arcs is not None:
        unit_ref = np.zeros(len(units))
        np.add.at(unit_ref, inverse, ref_arcs)
    bounds = np.cumsum([0] + [len(p) for p in parts])
    fold_costs = np.array(
        [
            [
                arc_costs[j, a:b].sum() / (ref_arcs[a:b].sum() if ref_arcs is not None else 1.0)
                for a, b in zip(bounds[:-1], bounds[1:], strict=True)
            ]
            for j in range(len(candidates))
        ]
    )
    index = choose(unit_costs, rule)
    return Selection(
        name=name,
        candidates=candidates,
        rule=rule,
        group=group,
        seed=int(seed),
        folds=tuple(parts),
        unit_costs=unit_costs,
        reference=unit_ref,
        fold_costs=fold_costs,
        index=index,
        lowest=choose(unit_costs, "lowest"),
    )
