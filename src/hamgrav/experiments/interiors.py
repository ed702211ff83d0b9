"""The imaged shape as a prior: how much of the field the constant-density shape misses, and
what a learned residual on it recovers (the paper's residual-architecture experiment).

For each truth interior (default: Itokawa with the head lobe twice as dense, and Itokawa with an
off-centre void), the 112-arc campaign is simulated and fitted through the estimator, all
models to the identical arcs: the shape prior alone (``shape``), the network-best network from
scratch without the prior (``network-scratch``), the same network as a residual on the prior
(``shape+network``) and SH residuals on the prior (``shape+shL``). Field errors are those of
the whole model against the perturbing potential (1 = no correction), on shells and on the
surface-following set; the shape alone's error is the fraction of the perturbing field the
constant-density shape misses.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from ..bodies.interiors import INTERIORS
from ..core.fields import MAX_SHELL_RB
from ..errors import InputError
from ..report.interiors import interiors_readme, residuals_figure
from .base import Experiment, RunContext, RunOutput
from .common import (
    CampaignConfig,
    fit_rows,
    harmonic_option,
    lm_iterations_option,
    network_best,
    sets_for,
    simulate,
)
from .config import label, option

__all__ = ["InteriorsExperimentConfig", "InteriorsExperiment", "PAPER"]

#: The paper's statements (Itokawa, head lobe denser; a hollow body with an off-centre void):
#: the share of the perturbing field the constant-density shape misses (head/tail), the
#: 1.05 R_B errors of the head-tail fits (the residual network's is the target), how much
#: better the residual network is than the network from scratch (head/tail) and than the
#: prior alone (void).
PAPER = {
    "missed_fraction": "15-21 %",
    "head-tail": {
        "shape+network": {"r1.05": 0.11},
        "network-scratch": {"r1.05": 0.489},
        "shape": {"r1.05": 0.160},
    },
    "residual_over_scratch_r1.05": 4.4,
    "void_residual_over_prior": "more than 2x",
}


@dataclass(frozen=True)
class InteriorsExperimentConfig(CampaignConfig):
    """Truth interiors and the models fitted to each."""

    truths: tuple[str, ...] = option(("head-tail", "void"), "Truth interiors, each a campaign.")
    sh_degrees: tuple[int, ...] = option(
        (4, 8, 12), "SH residual degrees (LM).", at_least=2, nonempty=True
    )
    hidden: tuple[int, ...] = option(
        (24, 24), "Hidden layer sizes of the network.", at_least=1, nonempty=True
    )
    harmonic: float = harmonic_option("network-scratch and shape+network")
    lm_iterations: int = lm_iterations_option("LM iteration cap of each network member.")
    altitude_m: float = option(
        30.0, "Altitude of the surface-following evaluation set [m].", above=0
    )
    shells_rb: tuple[float, ...] = option(
        (1.05, 1.1, 1.2, 1.5),
        "Evaluation shells [R_B].",
        at_least=1.0,
        at_most=MAX_SHELL_RB,
        nonempty=True,
    )

    def check(self) -> None:
        super().check()
        unknown = [t for t in self.truths if t not in INTERIORS]
        if unknown or not self.truths:
            raise InputError(
                f"{label('truths')} must be among {', '.join(INTERIORS)}, "
                f"got {', '.join(self.truths)}"
            )


class InteriorsExperiment(Experiment):
    """See the module docstring."""

    name = "interiors"
    title = "The imaged shape as a prior: interior residuals"
    config_type = InteriorsExperimentConfig
    aggregate_keys = ("field_error",)
    default_output = "results/interiors-itokawa"
    figure_captions = {
        "residuals.png": "field error against radius for the shape prior alone, the network "
        "from scratch and the network as a residual on the prior, one panel per truth",
    }

    def run(self, config: InteriorsExperimentConfig, ctx: RunContext) -> RunOutput:
        best = network_best(config.hidden, config.lm_iterations, harmonic=config.harmonic)
        rows = {
            "shape": {"term": "none", "prior": "shape"},
            "network-scratch": best,
            "shape+network": {**best, "prior": "shape"},
        }
        rows |= {
            f"shape+sh{d}": {"term": "sh", "degree": d, "prior": "shape"} for d in config.sh_degrees
        }
        truths, flat, fits = {}, {}, {}
        for interior in config.truths:
            truth, arcs = simulate(replace(config, interior=interior), ctx)
            sets = sets_for(truth, config.shells_rb, (config.altitude_m,), ctx.seed)
            estimators, errors = fit_rows(rows, arcs, truth, ctx, sets, prefix=f"{interior} ")
            fitted = {name: est.fitted_.solver for name, est in estimators.items()}
            flat |= {f"{interior}/{name}": e for name, e in errors.items()}
            shells = [k for k in errors["shape"] if k.startswith("r")]
            truths[interior] = {
                "missed_fraction": {k: errors["shape"][k] for k in shells},
                "field_error": errors,
            }
            fits[interior] = fitted
            ctx.say(
                f"{interior}: the shape misses "
                + ", ".join(f"{errors['shape'][k]:.3f}" for k in shells)
                + f" ({', '.join(shells)}); shape+network "
                + ", ".join(f"{errors['shape+network'][k]:.3f}" for k in shells)
            )
        result = {
            "body": config.body,
            "truths": truths,
            "field_error": flat,
            "fits": fits,
        }
        return RunOutput(result)

    def readme(self, report: dict) -> list[str]:
        return interiors_readme(report, PAPER)

    def figures(self, report: dict, artefacts: dict) -> dict:
        return {"residuals.png": residuals_figure(report)}
