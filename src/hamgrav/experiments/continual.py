"""Continual learning: the campaign arriving in stages, each stage's fit warm-started from the
previous one, against fitting all arcs so far from scratch at every stage. Warm network stages
use the preset's warm solver, :data:`~hamgrav.fit.estimator.NETWORK_WARM_SOLVER` (at most 8
iterations per member, stopping after 4 accepted steps that do not lower the validation cost;
after a member's first validation gain, only steps that lower the validation cost too).

The 112 arcs of the descent campaign arrive in ``stages`` stages of whole orbits (orbit grid
order); the network (the ``network-best`` configuration) and SH 8 are fitted at every stage,
warm and from scratch; validation arcs are drawn once per arriving stage and never trained on.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from ..fit.estimator import NETWORK_WARM_SOLVER
from ..report.continual import continual_figure, continual_readme
from .base import Experiment, RunContext, RunOutput
from .common import (
    CampaignConfig,
    errors_of,
    fit_staged,
    harmonic_option,
    lm_iterations_option,
    network_best,
    row_estimator,
    sets_for,
    simulate,
    warm_gate_option,
)
from .config import option

__all__ = ["ContinualExperimentConfig", "ContinualExperiment"]


@dataclass(frozen=True)
class ContinualExperimentConfig(CampaignConfig):
    """The continual campaign: stages of whole orbits; the network and SH 8."""

    stages: int = option(4, "Stages (orbits split evenly, in grid order).", at_least=1)
    hidden: tuple[int, ...] = option(
        (24, 24), "Hidden layer sizes of the network.", at_least=1, nonempty=True
    )
    harmonic: float = harmonic_option("network-best")
    lm_iterations: int = lm_iterations_option(
        "LM iteration cap of each network member fitted from scratch."
    )
    warm_iterations: int = option(
        NETWORK_WARM_SOLVER.max_iter,
        "LM iteration cap of each network member at warm-started stages.",
    )
    warm_patience: int = option(
        NETWORK_WARM_SOLVER.patience,
        "Accepted steps without a lower validation cost after which a warm stage stops.",
    )
    warm_gate: bool = warm_gate_option()
    sh_degree: int = option(8, "SH degree.", at_least=2)


class ContinualExperiment(Experiment):
    """See the module docstring."""

    name = "continual"
    title = "Continual learning: warm-started stages against fits from scratch"
    config_type = ContinualExperimentConfig
    aggregate_keys = ("summary",)
    default_output = "results/continual-itokawa"
    figure_captions = {
        "continual.png": "field error at 1.2 R_B against the arcs received so far, for fits "
        "warm-started from the previous stage and fits from scratch (median over the "
        "repetitions; shaded: min-max of the warm fits)",
    }

    def run(self, config: ContinualExperimentConfig, ctx: RunContext) -> RunOutput:
        truth, arcs = simulate(config, ctx)
        sets = sets_for(truth, (1.05, 1.2, 1.5), (30.0,), ctx.seed)
        groups = np.array_split(np.arange(config.orbits), config.stages)
        arriving = [arcs.arcs_of(g) for g in groups]
        models = {
            "network-best": network_best(
                config.hidden,
                config.lm_iterations,
                harmonic=config.harmonic,
                warm_solver=replace(
                    NETWORK_WARM_SOLVER,
                    max_iter=config.warm_iterations,
                    patience=config.warm_patience,
                    validation_gate=config.warm_gate,
                ),
            ),
            f"sh{config.sh_degree}": {"term": "sh", "degree": config.sh_degree},
        }
        counts = np.cumsum([len(a) for a in arriving])
        stages = [{"n_arcs": int(n)} for n in counts]
        start = time.perf_counter()
        for settings in models.values():
            # the first fit of a process would otherwise also time heyoka's compilation
            row_estimator(settings, seed=ctx.seed, body=truth.body, client=ctx.fit_client).compile(
                arcs
            )
        ctx.say(f"integrators compiled in {time.perf_counter() - start:.1f} s (not timed)")
        for mode in ("warm", "scratch"):
            for k in range(len(groups)):
                stages[k][mode] = {}
            for name, settings in models.items():
                warm = mode == "warm"
                est, run = fit_staged(settings, arcs, arriving, truth, ctx, warm_start=warm)
                records = run.records
                for k, r in enumerate(records):
                    stages[k][mode][name] = {
                        **errors_of(est.model_, r.result.params, truth, sets),
                        "iterations": r.result.iterations,
                        "wall_s": r.result.wall_s,
                        "outcome": r.result.outcome.value,
                        "warm_started": r.warm_started,
                        "relative_cost": r.relative_cost,
                    }
                ctx.say(
                    f"{mode} {name}: r1.2 by stage "
                    + ", ".join(f"{stages[k][mode][name]['r1.2']:.3f}" for k in range(len(groups)))
                    + f"; {sum(r.result.wall_s for r in records):.0f} s in all"
                )
        summary = {}
        for name in models:
            warm = [s["warm"][name] for s in stages]
            scratch = [s["scratch"][name] for s in stages]
            summary[name] = {
                "final_r1.2_warm": warm[-1]["r1.2"],
                "final_r1.2_scratch": scratch[-1]["r1.2"],
                "final_warm_over_scratch": warm[-1]["r1.2"] / scratch[-1]["r1.2"],
                "worst_stage_step": max(
                    b["r1.2"] / a["r1.2"] for a, b in zip(warm, warm[1:], strict=False)
                ),
                "wall_warm_s": sum(s["wall_s"] for s in warm),
                "wall_scratch_s": sum(s["wall_s"] for s in scratch),
                "wall_ratio": sum(s["wall_s"] for s in warm)
                / max(sum(s["wall_s"] for s in scratch), 1e-9),
            }
        result = {"body": config.body, "n_arcs": arcs.n_arcs, "stages": stages, "summary": summary}
        return RunOutput(result)

    def readme(self, report: dict) -> list[str]:
        return continual_readme(report)

    def figures(self, report: dict, artefacts: dict) -> dict:
        return {"continual.png": continual_figure(report)}
