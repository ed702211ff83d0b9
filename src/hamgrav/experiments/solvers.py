"""Solver comparison: the paper's choices next to ours, on one campaign, same sensitivities.

- Network: Adam (the paper) vs Levenberg-Marquardt, each on the unweighted canonical cost (the
  paper) and on the noise-weighted cost (each sample's residual whitened by the tracking noise,
  :func:`hamgrav.fit.estimator.noise_whitening`); same hold-out, same initialisation.
- SH degree 4 and 8 by Levenberg-Marquardt (reference rows).
- Continual learning: the campaign in stages; each stage warm-started vs from scratch.
- D-optimal selection: greedy picks from the campaign's orbits (predicted sensitivities at the
  degree-4 model fitted on the first stage) against seeded random orders.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ..fit.continual import fit_continual
from ..fit.design import greedy_d_optimal, random_order_logdet, trajectory_informations
from ..fit.lm import LevenbergMarquardt
from ..report.figures import logdet_figure
from ..report.solvers import solvers_readme
from .base import Experiment, RunContext, RunOutput
from .common import (
    CampaignConfig,
    errors_of,
    fit,
    fit_rows,
    row_estimator,
    sets_for,
    simulate,
)
from .config import option

__all__ = ["SolverExperimentConfig", "SolverExperiment"]


@dataclass(frozen=True)
class SolverExperimentConfig(CampaignConfig):
    """The solver comparison: the campaign, the network, the solvers' budgets, the stages."""

    hidden: tuple[int, ...] = option(
        (24, 24), "Hidden layer sizes of the network.", at_least=1, nonempty=True
    )
    adam_steps: int = option(1500, "Adam steps.", at_least=1)
    learning_rate: float = option(1e-2, "Adam peak learning rate.", above=0)
    lm_iterations: int = option(20, "LM iterations of the network.")
    stages: int = option(4, "Stages of the continual fits (orbits split evenly).", at_least=1)
    picks: int = option(8, "D-optimal picks.", at_least=1)


class SolverExperiment(Experiment):
    """See the module docstring."""

    name = "solvers"
    title = "Solver comparison: Adam vs LM, weighting, continual warm starts, D-optimal"
    config_type = SolverExperimentConfig
    aggregate_keys = ("field_error",)
    default_output = "results/solvers-itokawa"
    figure_captions = {
        "d_optimal.png": "log det of the information of the orbits selected so far: greedy "
        "D-optimal selection against random orders (higher is more informative)",
    }

    def run(self, config: SolverExperimentConfig, ctx: RunContext) -> RunOutput:
        seed, say = ctx.seed, ctx.say
        truth, arcs = simulate(config, ctx)
        sets = sets_for(truth, (1.05, 1.2, 1.5), (30.0,), seed)
        rows = {f"sh{d}-lm": {"term": "sh", "degree": d} for d in (4, 8)}
        lm = LevenbergMarquardt(max_iter=config.lm_iterations, rtol=1e-9)
        for weighted in (False, True):
            tag = "weighted" if weighted else "unweighted"
            common = {"term": "network", "hidden": config.hidden, "weighted": weighted}
            rows[f"network-adam-{tag}"] = {
                **common,
                "solver": "adam",
                "adam_steps": config.adam_steps,
                "learning_rate": config.learning_rate,
            }
            rows[f"network-lm-{tag}"] = {**common, "solver": lm}
        fits, field_error = fit_rows(rows, arcs, truth, ctx, sets)
        summary = {name: est.fitted_.solver for name, est in fits.items()}

        per_stage = np.array_split(np.arange(config.orbits), config.stages)
        stage_arcs = [arcs.arcs_of(o) for o in per_stage]
        continual = {}
        r12 = {"r1.2": sets["r1.2"]}
        for label, settings in (
            ("sh8-lm", {"term": "sh", "degree": 8}),
            (
                "network-lm",
                {
                    "term": "network",
                    "hidden": config.hidden,
                    "solver": LevenbergMarquardt(max_iter=config.lm_iterations, rtol=1e-4),
                },
            ),
        ):
            out = {}
            for warm in (True, False):
                est = row_estimator(settings, seed=seed, body=truth.body, client=ctx.fit_client)
                records = fit_continual(est, arcs, stage_arcs, warm_start=warm)
                out["warm" if warm else "scratch"] = [
                    {**r.summary(), **errors_of(est.model_, r.result.params, truth, r12)}
                    for r in records
                ]
            continual[label] = out
            say(
                f"continual {label}: iterations warm "
                f"{[s['iterations'] for s in out['warm']]}, scratch "
                f"{[s['iterations'] for s in out['scratch']]}"
            )

        first = fit("sh4 (stage 1)", arcs.subset(stage_arcs[0]), truth, ctx, term="sh", degree=4)
        infos = trajectory_informations(first.model_, first.params_, arcs, mapper=ctx.mapper)
        n_pick = min(config.picks, config.orbits)
        picked, greedy_logdet, gains = greedy_d_optimal(infos, n_pick)
        randoms = [random_order_logdet(infos, n_pick, seed=s) for s in range(5)]
        families = config.campaign(seed).families
        design = {
            "model": "sh4 fitted on stage 1",
            "greedy_picks": [int(p) for p in picked],
            "greedy_families": [asdict(families[int(p)]) for p in picked],
            "greedy_logdet": [round(float(v), 3) for v in greedy_logdet],
            "greedy_gain": [round(float(v), 3) for v in gains],
            "random_picks": [[int(p) for p in r[0]] for r in randoms],
            "random_logdet": [[round(float(v), 3) for v in r[1]] for r in randoms],
        }
        say(f"D-optimal picks {design['greedy_picks']}")
        result = {
            "body": config.body,
            "interior": config.interior,
            "n_arcs": arcs.n_arcs,
            "fits": summary,
            "field_error": field_error,
            "continual": continual,
            "d_optimal": design,
        }
        return RunOutput(result)

    def readme(self, report: dict) -> list[str]:
        return solvers_readme(report)

    def figures(self, report: dict, artefacts: dict) -> dict:
        d = report["repetitions"][0]["d_optimal"]
        return {"d_optimal.png": logdet_figure(d["greedy_logdet"], d["random_logdet"])}
