"""Inside the Brillouin sphere: the 67P deep-region campaign (the paper's section "Inside the
Brillouin Sphere: the 67P Scenario", first part).

Truth: 67P at constant density, 240 mascons. Tracking: 18 orbits, a grid of 3 start radii
(1.1, 1.8, 2.5 R_B) x 6 inclinations (10-80 deg, 14 deg apart), 7 arcs each (126 arcs);
orbits dipping below 0.96 R_B are redrawn, so no tracked sample reaches the deep-region bins.
The orbits arrive in 6 stages of 3 in a fixed order (:func:`arrival_stages`); the network
(the ``network-best`` configuration) and SH 4/8/12 are fitted continually, every stage
warm-started from the previous one, all models on the identical arcs (the machinery of the
continual experiment, :func:`hamgrav.fit.continual.fit_continual`).

Evaluation of the final models, relative error of the perturbing potential (1 = no
correction): the mean over exterior shells 1.2-1.7 R_B (also after every stage), the 300 m
surface-following set inside the Brillouin sphere as a whole and by r / R_B bins below
0.95 R_B, and pointwise errors on an equatorial-plane grid with the body's cross-section
masked, summarised over the patches where an SH map model is worse than no correction.

The design leaves room for the later parts of the campaign (descent assimilation, random
arrival orders, D-optimal selection): they are further stage sequences fed to the same
continual fit and the same evaluation (:func:`evaluate`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..bodies.evaluation import equatorial_grid, radial_bins
from ..bodies.interiors import Truth
from ..core.arcs import Arcs
from ..core.fields import pointwise_field_errors
from ..errors import InputError
from ..fit.continual import fit_continual
from ..fit.estimator import NETWORK_WARM_SOLVER, GravityEstimator
from .common import (
    CampaignConfig,
    campaign_artefacts,
    errors_of,
    harmonic_option,
    network_best,
    sets_for,
    simulate,
)
from .config import option
from .deep_report import bins_figure, deep_readme, geometry_figure, maps_figure
from .runner import Experiment, RunContext, RunOutput, register

__all__ = [
    "DeepExperimentConfig",
    "DeepExperiment",
    "NETWORK",
    "SAMPLE_FLOOR_RB",
    "arrival_stages",
    "sample_radii",
    "evaluate",
]

#: Result key of the network row (the ``network-best`` configuration).
NETWORK = "network-best"
#: The paper's lowest tracked sample [R_B]: the sample count below it is reported.
SAMPLE_FLOOR_RB = 0.96


@dataclass(frozen=True)
class DeepExperimentConfig(CampaignConfig):
    """The deep-region campaign: 67P, 18 orbits in 6 stages, the network and SH 4/8/12."""

    body: str = option("67p", "Body: a catalogue name or 'synthetic'.")
    interior: str = option("uniform", "Truth interior (the paper's 67P truth is homogeneous).")
    n_mascons: int = option(240, "Truth mascons (the paper's 67P truth has 240).")
    orbits: int = option(
        18,
        "Orbits on a radius x inclination grid: 18 = 3 start radii x 6 inclinations (see "
        "--radius-rb and --inclination-deg).",
    )
    radius_rb: tuple[float, ...] = option(
        (1.1, 2.5),
        "Start radius range of the circular orbits [R_B]: 1.1, 1.8, 2.5 R_B with 18 orbits; "
        "tracked samples then lie at about 1.0-2.6 R_B on 67P.",
    )
    inclination_deg: tuple[float, ...] = option(
        (10.0, 80.0), "Inclination range [deg]: 10, 24, 38, 52, 66, 80 deg with 18 orbits."
    )
    min_radius_rb: float = option(
        0.96,
        "Redraw orbits dipping below this radius [R_B]: no sample reaches the deep bins.",
    )
    stages: int = option(
        6,
        "Stages the orbits arrive in, in a fixed order: each stage brings one orbit per start "
        "radius, at different inclinations; each stage's fits are warm-started from the "
        "previous stage's.",
    )
    sh_degrees: tuple[int, ...] = option((4, 8, 12), "SH degrees fitted (LM).")
    map_degrees: tuple[int, ...] = option(
        (8, 12),
        "SH degrees drawn in the equatorial maps; their error > 1 defines the patches "
        "(must be among --sh-degrees).",
    )
    hidden: tuple[int, ...] = option((24, 24), "Hidden layer sizes of the network.")
    harmonic: float = harmonic_option()
    lm_iterations: int = option(30, "LM iteration cap of each network member at the first stage.")
    warm_iterations: int = option(
        NETWORK_WARM_SOLVER.max_iter,
        "LM iteration cap of each network member at warm-started stages.",
    )
    altitude_m: float = option(300.0, "Altitude of the surface-following evaluation set [m].")
    shells_rb: tuple[float, ...] = option(
        (1.2, 1.3, 1.4, 1.5, 1.6, 1.7),
        "Exterior evaluation shells [R_B] (the orbit radii); the exterior error is their mean.",
    )
    deep_bins_rb: tuple[float, ...] = option(
        (0.25, 0.45, 0.55, 0.65, 0.75, 0.85, 0.95),
        "Edges [R_B] of the deep-region radial bins of the surface-following set "
        "(increasing, at most 1).",
    )
    map_extent_rb: float = option(1.3, "Half-width of the equatorial maps [R_B].")
    map_points: int = option(161, "Grid points along each side of the equatorial maps.")

    def check(self) -> None:
        super().check()
        if not 1 <= self.stages <= self.orbits:
            raise InputError(
                f"stages must lie between 1 and --orbits ({self.orbits}), got {self.stages}"
            )
        if not self.sh_degrees or any(d < 2 for d in self.sh_degrees):
            raise InputError("sh_degrees must be one or more degrees of at least 2")
        missing = sorted(set(self.map_degrees) - set(self.sh_degrees))
        if not self.map_degrees or missing:
            raise InputError(
                f"map_degrees must be among sh_degrees ({', '.join(map(str, self.sh_degrees))})"
            )
        if not self.hidden or any(h < 1 for h in self.hidden):
            raise InputError("hidden must be one or more positive layer sizes, e.g. 24,24")
        if self.lm_iterations < 1 or self.warm_iterations < 1:
            raise InputError("lm_iterations and warm_iterations must be at least 1")
        if not self.altitude_m > 0:
            raise InputError(f"altitude_m must be positive, got {self.altitude_m}")
        if not self.shells_rb or any(s <= 1.0 for s in self.shells_rb):
            raise InputError("shells_rb must be one or more radii above 1 R_B (exterior)")
        edges = np.asarray(self.deep_bins_rb, dtype=float)
        if len(edges) < 2 or np.any(np.diff(edges) <= 0) or edges[0] <= 0 or edges[-1] > 1:
            raise InputError(
                "deep_bins_rb must be two or more increasing edges in (0, 1], e.g. 0.45,0.65,0.95"
            )
        if not self.map_extent_rb > 0 or self.map_points < 3:
            raise InputError("map_extent_rb must be positive and map_points at least 3")


def arrival_stages(radius_rb, inclination_deg, stages: int) -> list[np.ndarray]:
    """Orbits of a radius x inclination grid (start radius [R_B] and inclination [deg] of
    each orbit) split into ``stages`` groups of orbit indices, in a fixed diagonal order:
    stage k brings, at the start radius of rank i, the inclination of rank k + s i (modulo the
    inclinations; s = inclinations per radius), so that every stage spans the radius range at
    different inclinations (18 orbits in 6 stages: one orbit per radius, inclinations two
    grid steps apart). Later parts of the campaign (random arrival orders, D-optimal
    selection) replace this order."""
    radii, r_idx = np.unique(np.asarray(radius_rb), return_inverse=True)
    incl, i_idx = np.unique(np.asarray(inclination_deg), return_inverse=True)
    r_idx, i_idx = r_idx.ravel(), i_idx.ravel()
    step = max(1, len(incl) // len(radii))
    order = np.lexsort((r_idx, (i_idx - step * r_idx) % len(incl)))
    return [np.asarray(g, dtype=int) for g in np.array_split(order, stages)]


def sample_radii(arcs: Arcs, brillouin_radius: float, floor_rb: float = SAMPLE_FLOOR_RB) -> dict:
    """Radial distribution of the tracked samples [R_B]: min, quartiles, max, the sample
    count and how many lie below ``floor_rb``."""
    r = np.linalg.norm(arcs.states[..., :3], axis=-1).ravel() / brillouin_radius
    q = np.percentile(r, [0, 25, 50, 75, 100])
    keys = ("min", "q1", "median", "q3", "max")
    return {
        **{k: round(float(v), 3) for k, v in zip(keys, q, strict=True)},
        "n_samples": int(r.size),
        "floor_rb": floor_rb,
        "below_floor": int(np.sum(r < floor_rb)),
    }


def _value(x: float) -> float | None:
    """A finite error rounded to 4 significant digits, or None (empty set, overflow)."""
    return float(f"{x:.4g}") if np.isfinite(x) else None


def evaluate(estimators: dict, truth: Truth, config: DeepExperimentConfig, seed: int) -> dict:
    """The final models' errors: ``exterior_error`` (mean over the shells), ``deep_error``
    (the surface-following set inside R_B), ``deep_bins`` ({model: {bin: error}}, None for an
    empty bin), ``deep_bin_points`` ({bin: points}) and the equatorial ``maps`` (pointwise
    errors, the inside mask and the patch summary)."""
    body = truth.body
    shells = sets_for(truth, config.shells_rb, (), seed)
    surface = sets_for(truth, (), (config.altitude_m,), seed)[f"h{config.altitude_m:g}m"]
    inside_rb = surface[np.linalg.norm(surface, axis=1) < body.brillouin_radius]
    bins = radial_bins(surface, body.brillouin_radius, config.deep_bins_rb)
    filled = {k: v for k, v in bins.items() if len(v)}
    out: dict = {
        "exterior_error": {},
        "deep_error": {},
        "deep_bins": {},
        "deep_bin_points": {k: int(len(v)) for k, v in bins.items()},
    }
    for name, est in estimators.items():
        out["exterior_error"][name] = _value(
            np.mean(list(errors_of(est.model_, est.params_, truth, shells).values()))
        )
        deep = errors_of(est.model_, est.params_, truth, {"deep": inside_rb, **filled})
        out["deep_error"][name] = _value(deep.pop("deep"))
        out["deep_bins"][name] = {k: _value(deep[k]) if k in deep else None for k in bins}
    out["maps"] = _maps(estimators, truth, config)
    return out


def _maps(estimators: dict, truth: Truth, config: DeepExperimentConfig) -> dict:
    """Pointwise errors of every model on the equatorial grid (NaN inside the body), and
    the patches: outside points where an SH map model's error exceeds 1."""
    body = truth.body
    points, inside = equatorial_grid(body, config.map_extent_rb, config.map_points)
    outside = points[~inside]
    errors = {}
    for name, est in estimators.items():
        err = np.full(len(points), np.nan)
        err[~inside] = pointwise_field_errors(est.model_, est.params_, truth.mascons, outside)
        errors[name] = err
    patch = np.zeros(len(points), bool)
    for d in config.map_degrees:
        patch |= errors[f"sh{d}"] > 1.0  # NaN (inside) compares False
    r = np.linalg.norm(points, axis=1) / body.brillouin_radius
    return {
        "errors": errors,
        "inside": inside,
        "patch": patch,
        "axis_m": np.unique(points[:, 0]) * body.units.length_m,
        "patch_points": int(patch.sum()),
        "patch_inside_brillouin": _value(np.mean(r[patch] < 1.0)) if patch.any() else None,
        "patch_median": {
            n: _value(np.median(e[patch])) if patch.any() else None for n, e in errors.items()
        },
    }


class DeepExperiment(Experiment):
    """See the module docstring."""

    name = "deep"
    title = "Inside the Brillouin sphere: the deep region of 67P"
    config_type = DeepExperimentConfig
    aggregate_keys = ("summary", "deep_bins")
    default_output = "results/deep-67p"
    figure_captions = {
        "geometry.png": "the tracked arcs over the shape in the body frame, and the radii of "
        "the tracked samples in R_B (dashed: the Brillouin radius; shaded: the deep-region "
        "bins, which no sample reaches)",
        "deep_bins.png": "relative field error of each final model on the surface-following "
        "set inside the Brillouin sphere, by radial bin (log scale; 1 = no correction)",
        "maps.png": "pointwise relative error of the perturbing potential in the equatorial "
        "plane, common logarithmic colour scale, the body's z = 0 cross-section masked "
        "(grey); dashed: the Brillouin sphere; contours: error 1 (worse than no correction)",
    }

    def run(self, config: DeepExperimentConfig, ctx: RunContext) -> RunOutput:
        truth, arcs = simulate(config, ctx)
        r_b = truth.body.brillouin_radius
        radii = sample_radii(arcs, r_b)
        ctx.say(
            f"sample radii [R_B]: {radii['min']:.3f}-{radii['max']:.3f} (median "
            f"{radii['median']:.3f}), {radii['below_floor']} of {radii['n_samples']} below "
            f"{radii['floor_rb']:g}"
        )
        info = arcs.trajectory_info
        groups = arrival_stages(info["radius_rb"], info["inclination_deg"], config.stages)
        arriving = [arcs.arcs_of(g) for g in groups]
        best = network_best(config.hidden, config.lm_iterations, harmonic=config.harmonic)
        best["warm_solver"] = replace(best["warm_solver"], max_iter=config.warm_iterations)
        rows = {f"sh{d}": {"term": "sh", "degree": d} for d in config.sh_degrees}
        rows[NETWORK] = best
        shells = sets_for(truth, config.shells_rb, (), ctx.seed)
        counts = np.cumsum([len(a) for a in arriving])
        stages = [
            {
                "orbits": [int(k) for k in g],
                "n_arcs": int(n),
                "exterior_error": {},
                "fits": {},
            }
            for g, n in zip(groups, counts, strict=True)
        ]
        estimators = {}
        for name, settings in rows.items():
            est = GravityEstimator(body=truth.body, seed=ctx.seed, mapper=ctx.mapper, **settings)
            records = fit_continual(est, arcs, arriving, warm_start=True)
            for stage, record in zip(stages, records, strict=True):
                errs = errors_of(est.model_, record.result.params, truth, shells)
                stage["exterior_error"][name] = _value(np.mean(list(errs.values())))
                stage["fits"][name] = {
                    "iterations": record.result.iterations,
                    "wall_s": round(record.result.wall_s, 2),
                    "outcome": record.result.outcome.value,
                    "warm_started": record.warm_started,
                }
            estimators[name] = est
            ctx.say(
                f"{name}: exterior error by stage "
                + ", ".join(f"{s['exterior_error'][name]}" for s in stages)
                + f"; {sum(r.result.wall_s for r in records):.0f} s in all"
            )
        ev = evaluate(estimators, truth, config, ctx.seed)
        maps = ev.pop("maps")
        summary = {}
        for name in estimators:
            by_bin = [v for v in ev["deep_bins"][name].values() if v is not None]
            summary[name] = {
                "exterior": ev["exterior_error"][name],
                "deep": ev["deep_error"][name],
                "deepest_bin": by_bin[0] if by_bin else None,
                "worst_bin": max(by_bin) if by_bin else None,
                "patch_median": maps["patch_median"][name],
            }
        ctx.say(
            "deep region: "
            + ", ".join(f"{n} {s['deep']}" for n, s in summary.items())
            + f"; patches: {maps['patch_points']} map points"
        )
        result = {
            "body": config.body,
            "n_arcs": arcs.n_arcs,
            "radius_rb": radii,
            **ev,
            "patch_median": maps["patch_median"],
            "patch_points": maps["patch_points"],
            "patch_inside_brillouin": maps["patch_inside_brillouin"],
            "summary": summary,
            "stages": stages,
            "fits": {n: e.fitted_.solver for n, e in estimators.items()},
        }
        artefacts = campaign_artefacts(truth, arcs)
        artefacts["maps"] = {k: maps[k] for k in ("errors", "inside", "patch", "axis_m")}
        return RunOutput(result, artefacts)

    def readme(self, report: dict) -> list[str]:
        return deep_readme(report)

    def figures(self, report: dict, artefacts: dict) -> dict:
        return {
            "geometry.png": geometry_figure(report, artefacts),
            "deep_bins.png": bins_figure(report),
            "maps.png": maps_figure(report, artefacts),
        }


register(DeepExperiment())
