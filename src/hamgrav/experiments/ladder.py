"""The deep-region ladder of 67P: which stage loses the network's accuracy inside R_B.

The deep-region campaign (:mod:`hamgrav.experiments.deep`) leaves the network at about 0.44
in the deepest bin where the paper reports 0.29, and the nine descents do not lower it
reliably. This experiment takes the same campaign, network and evaluation sets and fits the
network (and SH of one degree, as a control) rung by rung, each one step closer to the real
problem; the first large jump between rungs names what limits the deep-region error:

- (a) ``oracle-deep``: the learnable term fitted directly to the true perturbing potential
  and its acceleration (minus the known part's) at surface-following points inside R_B, at
  altitudes other than the evaluation set's (:class:`hamgrav.core.field_problem.FieldProblem`,
  the same LM): the representation's capacity floor;
- (b) ``oracle-arcs``: the same fit at the positions the arcs sample (all at r >= 0.96 R_B),
  with the harmonic penalty at each weight of ``oracle_harmonic`` (the network only): the
  extrapolation floor, the true field and its gradient there standing in for what tracking
  can tell of them;
- (a+b) ``oracle-both``: the fit on the points of (a) and (b) together: whether the
  representation can hold the deep and the exterior field at once (what assimilating
  descents asks of it); with ``oracle_balance`` each set's relative errors weigh alike, or
  as ``oracle_deep_share`` says (without, the deep field, tens of times the exterior's,
  dominates the fit);
- (b+e) ``oracle-descents`` (run only when asked): the fit of (b) on the arcs' positions and
  the descents' together (with ``oracle_balance`` each set weighed alike, or by
  ``oracle_deep_share``): whether the
  descents' samples, known exactly, tell the network the deep field without costing the
  exterior;
- (c) ``noise-free``: the tracking fit on the arcs with their noise removed (each arc starts
  from its true state);
- (d) ``tracking``: the real fit (noisy arcs, each started from its first noisy sample), all
  orbital arcs at once;
- (e) ``descents-warm``: (d) warm-refitted with the tracked descents as a further stage, and
  ``descents-scratch``: one fit from scratch on the orbital arcs and the descents.

The network is the ``network-best`` configuration (LM, harmonic penalty, an ensemble of
three); with ``adam_rungs`` the tracking rungs named there are also fitted by the paper's
own protocol (Adam, one network, early-stopped on held-out arcs), row ``network-adam``.
With ``prior`` "shape" every model sits on the imaged shape at constant density (the known
part; the truth may be heterogeneous, see ``interior``), each rung fits what the prior leaves,
and row ``shape`` scores the prior alone: whether a known shape moves the extrapolation
floor that the network from the central term alone cannot pass.

Each rung's model is scored on the deep experiment's sets: the mean error over the exterior
shells, the 300 m surface-following set inside R_B and its radial bins. The regressions use
the truth by construction: this is an experiment's instrument, not a fit a user can run.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from ..bodies.evaluation import deep_bin_errors, significant
from ..core.arcs import join_arcs, sample_radii
from ..core.field_problem import FieldProblem
from ..core.fields import central_potential, perturbing_potential
from ..core.mascons import mascon_acceleration
from ..core.model import evaluate_field
from ..errors import InputError
from ..fit.estimator import GravityEstimator, preset
from ..fit.harmonic import HarmonicPenalty
from ..fit.lm import LevenbergMarquardt
from ..report.ladder import ladder_figure, ladder_readme
from .base import Experiment, RunContext, RunOutput
from .common import (
    committed_holdout,
    errors_of,
    fit_staged,
    network_best,
    row_estimator,
    sets_for,
    simulate,
)
from .config import label, option
from .deep import (
    SAMPLE_FLOOR_RB,
    DeepCampaignConfig,
    _bin_summary,
    campaign_descents,
    known_of,
    softening_of,
)

__all__ = ["DeepLadderConfig", "DeepLadderExperiment", "RUNGS", "oracle_fit"]

#: The rungs in order, with what each one measures (the README's first column).
RUNGS = {
    "oracle-deep": "(a) fit to the true field inside R_B: the representation's floor",
    "oracle-arcs": "(b) fit to the true field where the arcs sample: the extrapolation floor",
    "oracle-both": "(a+b) fit to the true field inside R_B and where the arcs sample",
    "oracle-descents": "(b+e) fit to the true field where the arcs and the descents sample: "
    "what the descents could tell",
    "noise-free": "(c) tracking fit, noise-free arcs, true initial states",
    "tracking": "(d) tracking fit, noisy arcs (the real fit, all orbits at once)",
    "descents-warm": "(e) (d) warm-refitted with the tracked descents",
    "descents-scratch": "(e) one fit from scratch on the orbits and the descents",
}
#: The rungs run by default: every rung but (b+e), which asks whether the descents' samples
#: hold the deep field's information (added after the first committed ladders).
DEFAULT_RUNGS = tuple(r for r in RUNGS if r != "oracle-descents")
#: The rungs that fit tracking arcs (the others fit the true field).
TRACKING_RUNGS = ("noise-free", "tracking", "descents-warm", "descents-scratch")
#: The README's text of the shape prior's own row (no correction fitted).
PRIOR_ALONE = "the shape prior alone (no correction)"
#: LM iteration cap of the oracle fits (per member): they start from the same
#: initialisation as the tracking fit and have no validation stop.
ORACLE_ITERATIONS = 40


@dataclass(frozen=True)
class DeepLadderConfig(DeepCampaignConfig):
    """The deep-region ladder: the deep campaign's arcs, network and sets, and the rungs."""

    sh_degree: int = option(8, "Degree of the SH control fitted on every rung.", at_least=2)
    oracle_altitudes_m: tuple[float, ...] = option(
        (150.0, 450.0),
        "Altitudes [m] of the surface-following points rung (a) is fitted on (those inside "
        "R_B); the evaluation set's altitude is left out.",
        above=0,
        nonempty=True,
    )
    oracle_points: int = option(
        4000,
        "Points rung (a) is fitted on: a seeded draw from the surface-following points "
        "inside R_B (each adds four rows, the potential and its gradient).",
        at_least=1,
    )
    oracle_harmonic: tuple[float, ...] = option(
        (0.0, 1e-5, 1e-4, 1e-3),
        "Harmonic-penalty weights of the network fits of rungs (b) and (b+e) (0: none); the "
        "data term is half the squared relative error over the points.",
        at_least=0,
        nonempty=True,
    )
    rungs: tuple[str, ...] = option(
        DEFAULT_RUNGS,
        f"Rungs to run, among {', '.join(RUNGS)} (e.g. the oracle rungs alone to compare "
        "network shapes).",
        nonempty=True,
    )

    oracle_balance: bool = option(
        False,
        "Weigh the two sets of rung (a+b), and of rung (b+e), alike (each set's relative "
        "errors); off: one normalisation over all points, where the deep field dominates.",
    )
    oracle_deep_share: float = option(
        0.5,
        "With oracle_balance: the share of the cost that rung (a+b)'s deep points and rung "
        "(b+e)'s descent points carry, the arcs' points the rest (0.5: each set alike).",
        above=0,
        at_most=0.5,
    )
    adam_rungs: tuple[str, ...] = option(
        (),
        "Tracking rungs also fitted by the paper's protocol (the `network` preset: one "
        "network of the same shape, Adam, early-stopped on the held-out arcs), among "
        f"{', '.join(TRACKING_RUNGS)}; empty: none.",
    )

    adam_steps: int = option(1500, "Adam steps of the paper's protocol (adam_rungs).", at_least=1)
    oracle_iterations: int = option(
        ORACLE_ITERATIONS,
        "LM iterations of each ensemble member in the oracle rungs' fits (the cap; they stop "
        "earlier only on a relative cost change below the solver's tolerance).",
        at_least=1,
    )

    def check(self) -> None:
        super().check()
        wrong = sorted(set(self.adam_rungs) - set(TRACKING_RUNGS))
        if wrong:
            raise InputError(
                f"{label('adam_rungs')}: {', '.join(wrong)} is not a tracking rung; give "
                f"some of {', '.join(TRACKING_RUNGS)}"
            )
        unknown = sorted(set(self.rungs) - set(RUNGS))
        if unknown:
            raise InputError(
                f"{label('rungs')}: unknown rung(s) {', '.join(unknown)}; known: {', '.join(RUNGS)}"
            )
        if self.oracle_deep_share != 0.5 and not self.oracle_balance:
            raise InputError(
                f"{label('oracle_deep_share')} weighs the sets of a balanced fit: give "
                f"{label('oracle_balance')} too, or leave the share at 0.5"
            )
        if "oracle-descents" in self.rungs and not self.descents:
            raise InputError(
                f"{label('rungs')}: oracle-descents fits the descents' points, and "
                f"{label('descents')} is 0: give {label('descents')} >= 1, or leave the rung out"
            )


def oracle_fit(
    estimator: GravityEstimator,
    arcs,
    points,
    truth,
    *,
    harmonic: float = 0.0,
    groups=None,
    group_weights=None,
    iterations: int = ORACLE_ITERATIONS,
):
    """(model, params, info): the estimator's learnable term (each ensemble member on its own,
    from the estimator's initialisation) fitted by LM to the truth's perturbing potential and
    its acceleration, minus the model's known part, at ``points`` (k, 3), canonical (half the
    squared relative error of each in the cost); ``harmonic`` > 0 adds the
    network's harmonic penalty at that weight (collocation points as the tracking fit's);
    ``groups`` (k,) labels weigh each group's relative errors alike, or by
    ``group_weights`` {label: weight} (see :class:`~hamgrav.core.field_problem.FieldProblem`).
    ``info``: ``on_points``, the ensemble's relative potential error on the fitted points, and each
    member's solver summary."""
    solver = estimator.make_solver()
    if not isinstance(solver, LevenbergMarquardt):
        raise InputError(
            "an oracle fit runs Levenberg-Marquardt: give an estimator whose solver is LM"
        )
    model, _ = estimator.build_model(arcs)
    known, known_acc = evaluate_field(model, np.zeros(model.n_learn), points, which="known")
    target = perturbing_potential(truth.mascons, points) - (known - central_potential(points))
    # the known part's acceleration holds the central term's: the difference is the rest
    target_acc = mascon_acceleration(truth.mascons, points) - known_acc
    member = model.member()
    penalty = None
    if harmonic:
        penalty = HarmonicPenalty(member, estimator.collocation_points(arcs), harmonic)
    problem = FieldProblem(
        member,
        points,
        target,
        target_acc,
        groups=groups,
        group_weights=group_weights,
        regulariser=penalty,
    )
    solver = replace(solver, max_iter=iterations, patience=None)
    blocks = model.learnable.split_members(estimator.initial_params(model, arcs))
    results = [solver.solve(problem, block) for block in blocks]
    params = np.concatenate([r.params for r in results])
    ensemble, _ = evaluate_field(model, params, points)
    on_points = np.sqrt(np.sum((ensemble - target) ** 2) / np.sum(target**2))  # potential
    return (
        model,
        params,
        {"on_points": significant(on_points), "members": [r.summary() for r in results]},
    )


def _scores(model, params, truth, shells, config, seed) -> dict:
    """Exterior, deep-set, deepest-bin and per-bin errors of one fitted model."""
    exterior = np.mean(list(errors_of(model, params, truth, shells).values()))
    ev = deep_bin_errors(
        {"m": (model, params)}, truth, config.altitude_m, config.deep_bins_rb, seed
    )
    deepest, worst = _bin_summary(ev["deep_bins"]["m"])
    return {
        "exterior": significant(exterior),
        "deep": ev["deep_error"]["m"],
        "deepest_bin": deepest,
        "worst_bin": worst,
        **{f"bin {k}": v for k, v in ev["deep_bins"]["m"].items()},
    }


class DeepLadderExperiment(Experiment):
    """See the module docstring."""

    name = "deep-ladder"
    title = "The deep region of 67P, rung by rung: where the network's accuracy is lost"
    config_type = DeepLadderConfig
    aggregate_keys = ("ladder",)
    default_output = "results/deep-67p-ladder"
    figure_captions = {
        "ladder.png": "relative error of the perturbing potential against r / R_B for each "
        "rung (median over the repetitions): the deep set's radial bins inside R_B, then the "
        "exterior shells; one panel per model: network-best, the SH control, and the paper's "
        "Adam protocol when run (log scale; 1 = no correction)",
    }

    def run(self, config: DeepLadderConfig, ctx: RunContext) -> RunOutput:
        start = time.perf_counter()
        truth, arcs = simulate(config, ctx)
        descents = campaign_descents(truth, config, ctx.seed)
        all_arcs = join_arcs(arcs, descents)
        orbital = np.arange(arcs.n_arcs)
        clean = replace(arcs, states=arcs.true_states, sigma_r_m=0.0, sigma_v_m_s=0.0)
        body = truth.body
        shells = sets_for(truth, config.shells_rb, (), ctx.seed)
        raised = sets_for(truth, (), config.oracle_altitudes_m, ctx.seed)
        deep_points = np.concatenate(
            [p[np.linalg.norm(p, axis=1) < body.brillouin_radius] for p in raised.values()]
        )
        if not len(deep_points):
            raise InputError(
                f"no point {', '.join(f'{h:g}' for h in config.oracle_altitudes_m)} m above "
                f"{config.body}'s surface lies inside its Brillouin sphere: give lower "
                f"{label('oracle_altitudes_m')}"
            )
        if len(deep_points) > config.oracle_points:
            draw = np.random.default_rng(ctx.seed).choice(
                len(deep_points), config.oracle_points, replace=False
            )
            deep_points = deep_points[np.sort(draw)]
        arc_points = arcs.true_states[..., :3].reshape(-1, 3)
        descent_points = descents.true_states[..., :3].reshape(-1, 3)
        descent_points = descent_points[np.isfinite(descent_points).all(axis=1)]
        known = known_of(config)
        rows = {
            "network": network_best(
                config.hidden,
                config.lm_iterations,
                harmonic=config.harmonic,
                network_start=config.network_start,
                **softening_of(config),
                **known,
            ),
            f"sh{config.sh_degree}": {"term": "sh", "degree": config.sh_degree, **known},
        }
        if config.adam_rungs:
            rows["network-adam"] = preset(
                "network",
                hidden=config.hidden,
                adam_steps=config.adam_steps,
                network_start=config.network_start,
                **softening_of(config),
                **known,
            )
        ladder, fits = {}, {}

        def score(row: str, rung: str, model, params, info: dict) -> None:
            key = f"{row}/{rung}"
            ladder[key] = _scores(model, params, truth, shells, config, ctx.seed)
            if "on_points" in info:
                ladder[key]["on_points"] = info["on_points"]
            fits[key] = info
            own = f", {info['on_points']} on its points" if "on_points" in info else ""
            ctx.say(
                f"{row} {rung}: {ladder[key]['exterior']} exterior, {ladder[key]['deep']} "
                f"deep{own}, {time.perf_counter() - start:.0f} s"
            )

        oracle_points = {
            "oracle-deep": deep_points,
            "oracle-arcs": arc_points,
            "oracle-both": np.concatenate([deep_points, arc_points]),
            "oracle-descents": np.concatenate([arc_points, descent_points]),
        }
        groups_of = {
            "oracle-both": np.repeat([1, 0], [len(deep_points), len(arc_points)]),
            "oracle-descents": np.repeat([0, 1], [len(arc_points), len(descent_points)]),
        }
        # label 1: the deep or descent points, 0: the arcs' (weights 1, 1 at a share of 0.5)
        share_weights = {0: 2 * (1 - config.oracle_deep_share), 1: 2 * config.oracle_deep_share}
        if known:  # what the prior carries before any fit: the floor the models start from
            prior_model, _ = row_estimator(
                {"term": "none", **known}, seed=ctx.seed, body=body
            ).build_model(arcs)
            score("shape", "prior-alone", prior_model, np.zeros(0), {})
        for row, settings in rows.items():
            wanted = set(config.adam_rungs if row == "network-adam" else config.rungs)
            settings = committed_holdout(settings)
            network = settings["term"] == "network"

            def estimator(settings=settings):
                return row_estimator(
                    settings, seed=ctx.seed, body=body, mapper=ctx.mapper, client=ctx.fit_client
                )

            for rung, points in oracle_points.items():
                if rung not in wanted:
                    continue
                exterior = rung in ("oracle-arcs", "oracle-descents")
                weights = config.oracle_harmonic if network and exterior else (0.0,)
                for weight in weights:
                    name = f"{rung}:{weight:g}" if len(weights) > 1 else rung
                    groups = groups_of.get(rung) if config.oracle_balance else None
                    fit = oracle_fit(
                        estimator(),
                        arcs,
                        points,
                        truth,
                        harmonic=weight,
                        groups=groups,
                        group_weights=share_weights if groups is not None else None,
                        iterations=config.oracle_iterations,
                    )
                    score(row, name, *fit)
            if "noise-free" in wanted:
                est = estimator().fit(clean)
                score(row, "noise-free", est.model_, est.params_, est.result_.summary())
            if wanted & {"tracking", "descents-warm"}:
                est, run = fit_staged(settings, all_arcs, [orbital], truth, ctx)
                record = run.records[-1]
                score(row, "tracking", est.model_, record.result.params, record.result.summary())
                if "descents-warm" in wanted:
                    record = run.add(np.arange(arcs.n_arcs, all_arcs.n_arcs))
                    summary = record.result.summary()
                    score(row, "descents-warm", est.model_, record.result.params, summary)
            if "descents-scratch" in wanted:
                est = estimator().fit(all_arcs)
                score(row, "descents-scratch", est.model_, est.params_, est.result_.summary())
        result = {
            "body": config.body,
            "n_arcs": arcs.n_arcs,
            "n_descents": descents.n_arcs,
            "radius_rb": sample_radii(arcs, body.brillouin_radius, SAMPLE_FLOOR_RB),
            "oracle_points": {
                "deep": int(len(deep_points)),
                "arcs": int(len(arc_points)),
                # recorded only when that rung runs: the results of earlier ladders stay whole
                **(
                    {"descents": int(len(descent_points))}
                    if "oracle-descents" in config.rungs
                    else {}
                ),
            },
            "ladder": ladder,
            "fits": fits,
            "wall_s": round(time.perf_counter() - start, 1),
        }
        return RunOutput(result, {})

    def readme(self, report: dict) -> list[str]:
        return ladder_readme(report, {**RUNGS, "prior-alone": PRIOR_ALONE})

    def figures(self, report: dict, artefacts: dict) -> dict:
        return {"ladder.png": ladder_figure(report)}
