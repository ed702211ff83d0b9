"""Buried anomalies under a nearly spherical body (the paper's anomaly table and maps).

Truth: the Bennu shape with dense point-mass anomalies buried below the surface, background
rescaled; by default in the frame of the shape's constant-density centroid, not recentred on
the anomalies' centre of mass (the paper centres only its interior and residual-descent
truths), so the residual keeps a degree-1 part. Every model is a residual on the
constant-density shape prior: SH of several degrees, SH with Kaula regularisation (alpha
scanned, chosen two ways: by the truth's field error on the 1.05 R_B shell, the paper's
protocol and the baseline at its strongest, and by the cost on held-out arcs, what a mission
can do), and the network-best network. Field errors of the whole model against the perturbing
potential (1 = no correction) on shells close to the surface.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.fields import MAX_SHELL_RB, perturbing_potential
from ..core.model import evaluate_field
from ..fit.estimator import truth_shell_metric
from ..report.anomalies import anomalies_readme, maps_figure
from .base import Experiment, RunContext, RunOutput
from .common import (
    CampaignConfig,
    cv_sh_option,
    cv_sh_row,
    fit_rows,
    harmonic_option,
    lm_iterations_option,
    network_best,
    radius_rb_option,
    sets_for,
    simulate,
)
from .config import option

__all__ = [
    "AnomaliesExperimentConfig",
    "AnomaliesExperiment",
    "PAPER_ANOMALIES",
    "PAPER_STATEMENTS",
]

#: The paper's table (relative field error on shells 1.03, 1.05, 1.1, 1.2 R_B).
PAPER_ANOMALIES = {
    "shape": (0.758, 0.767, 0.792, 0.844),
    "shape+sh4": (0.629, 0.639, 0.667, 0.725),
    "shape+sh8": (1.177, 1.141, 1.071, 0.996),
    "shape+sh8-kaula": (1.060, 1.033, 0.983, 0.936),
    "shape+sh12": (3.846, 3.490, 2.801, 1.985),
    "shape+sh16": (51.82, 44.90, 32.19, 18.27),
    "shape+sh16-kaula": (0.953, 0.929, 0.886, 0.855),
    "shape+network": (0.189, 0.181, 0.170, 0.174),
}
#: The paper's statements: the network residual's error on every shell (0.17-0.19: "0.18"),
#: and the best SH option of any degree and regularisation over the network (the paper's
#: 3.5x, checked against a bound of 3x).
PAPER_STATEMENTS = {"network_every_shell": 0.18, "best_sh_over_network": 3}


@dataclass(frozen=True)
class AnomaliesExperimentConfig(CampaignConfig):
    """The buried-anomaly campaign (Bennu, 16 orbits 1.08-1.7 R_B by default)."""

    body: str = option("bennu", "Body: a catalogue name, 'synthetic' or a body TOML file.")
    interior: str = option("anomalies", "Truth interior (see hamgrav.bodies.interiors).")
    frame: str = option(
        "shape",
        "Origin of the body frame: 'shape' (the constant-density centroid of the imaged shape; "
        "the anomalies' offset of the centre of mass stays in the residual, which the paper's "
        "numbers imply) or 'centre-of-mass' of the truth.",
    )
    radius_rb: tuple[float, ...] = radius_rb_option((1.08, 1.7))
    sh_degrees: tuple[int, ...] = option(
        (4, 8, 12, 16), "SH residual degrees (LM).", at_least=2, nonempty=True
    )
    kaula_degrees: tuple[int, ...] = option(
        (8, 16), "SH degrees also fitted with Kaula scans.", at_least=2
    )
    hidden: tuple[int, ...] = option(
        (24, 24), "Hidden layer sizes of the network.", at_least=1, nonempty=True
    )
    harmonic: float = harmonic_option("shape+network")
    cv_sh: bool = cv_sh_option()
    lm_iterations: int = lm_iterations_option("LM iteration cap of each network member.")
    shells_rb: tuple[float, ...] = option(
        (1.03, 1.05, 1.1, 1.2),
        "Evaluation shells [R_B].",
        at_least=1.0,
        at_most=MAX_SHELL_RB,
        nonempty=True,
    )


class AnomaliesExperiment(Experiment):
    """See the module docstring."""

    name = "anomalies"
    title = "Buried anomalies: residuals on the shape prior"
    config_type = AnomaliesExperimentConfig
    aggregate_keys = ("field_error",)
    default_output = "results/anomalies-bennu"
    figure_captions = {
        "maps.png": "on the 1.05 R_B shell, common colour scale: the true residual of the "
        "perturbing potential over the shape prior, the network's recovery and the best SH "
        "recovery (latitude against longitude)",
    }

    def run(self, config: AnomaliesExperimentConfig, ctx: RunContext) -> RunOutput:
        truth, arcs = simulate(config, ctx)
        best = network_best(
            config.hidden, config.lm_iterations, harmonic=config.harmonic, prior="shape"
        )
        rows = {"shape": {"term": "none", "prior": "shape"}}
        for d in config.sh_degrees:
            rows[f"shape+sh{d}"] = {"term": "sh", "degree": d, "prior": "shape"}
        metric = truth_shell_metric(arcs, truth.body, 1.05)
        for d in config.kaula_degrees:
            sh = {"term": "sh", "degree": d, "prior": "shape"}
            rows[f"shape+sh{d}-kaula"] = {**sh, "kaula": "truth-scan", "kaula_metric": metric}
            rows[f"shape+sh{d}-kaula-holdout"] = {
                **sh,
                "kaula": "holdout-scan",
                "validation_fraction": 0.12,
            }
            if config.cv_sh:  # k folds of all the arcs, as the other rows fit them all
                rows[f"shape+sh{d}-kaula-cv"] = {**sh, "kaula": "cv", "validation_fraction": 0.0}
        if config.cv_sh:
            rows["shape+sh-cv"] = cv_sh_row(config.sh_degrees, prior="shape")
        rows["shape+network"] = best
        sets = sets_for(truth, config.shells_rb, (), ctx.seed)
        fits, field_error = fit_rows(rows, arcs, truth, ctx, sets)
        kaula = {
            n: e.fitted_.solver["kaula_alpha"]
            for n, e in fits.items()
            if "kaula" in n or n.endswith("-cv")
        }
        sh_rows = [n for n in fits if "+sh" in n]
        best_sh = min(sh_rows, key=lambda n: field_error[n]["r1.05"])
        ctx.say(
            "r1.05: "
            + ", ".join(f"{n} {field_error[n]['r1.05']:.3f}" for n in fits)
            + f"; best SH {best_sh}"
        )
        result = {
            "body": config.body,
            "n_arcs": arcs.n_arcs,
            "anomalies": truth.parameters,
            **_cv_degrees(fits),
            "field_error": field_error,
            "kaula_alpha": kaula,
            "best_sh": best_sh,
            "fits": {n: e.fitted_.solver for n, e in fits.items()},
        }
        artefacts = {"maps": _maps(truth, fits, best_sh)}
        return RunOutput(result, artefacts)

    def readme(self, report: dict) -> list[str]:
        return anomalies_readme(report, PAPER_ANOMALIES, PAPER_STATEMENTS)

    def figures(self, report: dict, artefacts: dict) -> dict:
        return {"maps.png": maps_figure(artefacts["maps"])}


def _cv_degrees(fits: dict) -> dict:
    """{"cv_degree": {row: chosen degree}} of the rows whose degree was chosen (else {})."""
    chosen = {
        n: s["chosen"]
        for n, e in fits.items()
        for s in e.fitted_.solver.get("selection", ())
        if s["name"] == "degree"
    }
    return {"cv_degree": chosen} if chosen else {}


def _maps(truth, fits, best_sh: str, shell_rb: float = 1.05, n_lon: int = 72, n_lat: int = 36):
    """The residual over the prior on a lat-lon grid of the shell: truth, network, best SH."""
    lon = np.linspace(-np.pi, np.pi, n_lon)
    lat = np.linspace(-np.pi / 2, np.pi / 2, n_lat)
    glon, glat = np.meshgrid(lon, lat)
    r = shell_rb * truth.body.brillouin_radius
    pts = r * np.stack(
        [np.cos(glat) * np.cos(glon), np.cos(glat) * np.sin(glon), np.sin(glat)], axis=-1
    ).reshape(-1, 3)
    net = fits["shape+network"]
    prior = evaluate_field(net.model_, net.params_, pts, "known")[0]
    centre = 1.0 / np.linalg.norm(pts, axis=1)
    true_residual = perturbing_potential(truth.mascons, pts) - (prior - centre)
    out = {"lon_deg": np.degrees(lon), "lat_deg": np.degrees(lat), "truth": true_residual}
    for label, name in (("network", "shape+network"), (best_sh, best_sh)):
        est = fits[name]
        out[label] = evaluate_field(est.model_, est.params_, pts, "learnable")[0]
    return {k: (v.reshape(n_lat, n_lon) if v.size == n_lat * n_lon else v) for k, v in out.items()}
