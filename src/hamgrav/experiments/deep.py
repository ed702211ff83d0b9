"""Inside the Brillouin sphere: the 67P deep-region campaign (the paper's section "Inside the
Brillouin Sphere: the 67P Scenario", and its continual-learning figure).

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

The later parts are further stage sequences fed to the same continual fit
(:class:`hamgrav.fit.continual.ContinualFit`) and the same evaluation:

- Descent assimilation (``descents``, default 9; 0: off): deployment descents released at
  1.3 R_B (at rest in inertial space plus a 1-3 cm/s inward manoeuvre,
  :class:`hamgrav.sim.descent.DescentConfig`), flown under the truth to contact and tracked as
  one arc each (the orbital arcs' 40 samples and noise; ``descent_span``: at 14 s ending at
  contact, or spread over the whole fall; :func:`hamgrav.sim.descent.tracked_descents`). They
  arrive as a seventh stage after the fixed order's six: the network and the SH degrees of
  ``descent_degrees`` are warm-refitted on the 126 + 9 arcs from their stage-6 parameters
  (by default the network holds out its usual share of the arriving arcs for validation, here
  one descent; with ``descent_iterations`` every descent is trained, without a validation
  stop; with ``descent_share`` the descent arcs weigh as a set at that share of the cost,
  :func:`hamgrav.fit.weights.share_weights`) and the deep bins are evaluated again.
- Arrival orders (``random_orders``, default 5; 0: off): the same orbits under seeded random
  permutations, split into the same stage sizes, the network alone warm-refitted stage by
  stage; the mean exterior error after each stage.
- The D-optimal campaign (``d_optimal``): before each stage, the orbits still in the pool are
  scored from their plans (initial state and sample times, no measurements) predicted under
  the current network, with the paper's greedy gain and eps
  (:func:`hamgrav.fit.design.choose_from_plans`); the stage's picks are then flown (their
  simulated arcs added) and the network refitted. As in the paper the accumulated
  information starts at zero, so the first stage is chosen too, under the network's seeded
  initialisation (the starting point of its first fit), and it is the running sum of the
  picks' information as predicted when they were picked. The ensemble's members are fitted
  each on its own, so its information is block-diagonal, one block per member (the gain is
  the sum of the members' gains, eps per member).

With ``prior`` "shape" every model sits on the imaged shape at constant density (the known
part, as mascons; the truth's ``interior`` may differ from it) and fits what it leaves; the
prior alone is scored on the same sets (``prior_alone``).

Each part's wall time is reported (``wall_parts_s``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from functools import partial

import numpy as np

from ..bodies.evaluation import (
    deep_bin_errors,
    deep_set,
    equatorial_error_map,
    significant,
)
from ..bodies.interiors import Truth
from ..core.arcs import Arcs, join_arcs, sample_radii
from ..core.fields import acceleration_field_error, member_spread, model_perturbing_potential
from ..errors import InputError
from ..fit.anchor import ANCHOR_QUANTITIES, AnchorSettings
from ..fit.continual import ContinualFit
from ..fit.design import d_optimal_campaign, orbit_plans
from ..fit.estimator import NETWORK_STARTS, NETWORK_WARM_SOLVER, validation_split
from ..fit.weights import share_weights
from ..report.deep import (
    bins_figure,
    deep_readme,
    descents_figure,
    geometry_figure,
    maps_figure,
    orders_figure,
)
from ..sim.descent import DESCENT_SPANS, DescentConfig, tracked_descents
from .base import Experiment, RunContext, RunOutput
from .common import (
    CampaignConfig,
    campaign_artefacts,
    errors_of,
    fit_staged,
    harmonic_option,
    lm_iterations_option,
    min_radius_rb_option,
    n_mascons_option,
    network_best,
    orbits_option,
    radius_rb_option,
    row_estimator,
    sets_for,
    simulate,
    warm_gate_option,
)
from .config import label, option

__all__ = [
    "DeepCampaignConfig",
    "DeepExperimentConfig",
    "DeepExperiment",
    "NETWORK",
    "SAMPLE_FLOOR_RB",
    "arrival_stages",
    "random_orders",
    "evaluate",
    "campaign_descents",
    "PAPER",
    "PRIORS",
]

#: The paper's numbers (67P, 126 arcs, one run): SH 8 exterior error (shells 1.2-1.7 R_B);
#: 300 m above the surface inside the Brillouin sphere, SH 4 / 8 / 12; the network's deepest
#: and worst radial bin; median error over the patches where SH is worse than no correction.
PAPER = {
    "sh8_exterior": 0.012,
    "deep": {"sh4": 0.65, "sh8": 1.34, "sh12": 45.0},
    "network_deepest_bin": 0.29,
    "network_worst_bin": 0.51,
    "patch_median_sh": 2.7,
    "patch_median_network": 0.27,
    # after the nine descents: the network's deepest bin; SH 8 and SH 12 on the deep set
    "after_descents": {"network_deepest_bin": 0.15, "sh8": 1.5, "sh12": 7.6},
    # the network's mean exterior error under five random arrival orders
    "random_after_6": (0.37, 1.06),
    "random_after_18": (0.20, 0.26),
    # the D-optimal campaign after 15 orbits; below every random order from 12 orbits on
    "d_optimal_15": 0.14,
    "d_optimal_below_from": 12,
}


#: Result key of the network row (the ``network-best`` configuration).
NETWORK = "network-best"
#: The paper's lowest tracked sample [R_B]: the sample count below it is reported.
SAMPLE_FLOOR_RB = 0.96
#: The known parts a deep-region model can sit on (the ``prior`` option).
PRIORS = ("none", "shape")
PRIOR_PLACEMENTS = ("centred", "in-place")


@dataclass(frozen=True)
class DeepCampaignConfig(CampaignConfig):
    """What every deep-region experiment of 67P shares: the 18-orbit campaign that keeps its
    samples above 0.96 R_B, the network, the evaluation sets (exterior shells, the
    surface-following set by radial bins) and the tracked descents."""

    body: str = option("67p", "Body: a catalogue name, 'synthetic' or a body TOML file.")
    interior: str = option("uniform", "Truth interior (the paper's 67P truth is homogeneous).")
    n_mascons: int = n_mascons_option(240, "Truth mascons (the paper's 67P truth has 240).")
    orbits: int = orbits_option(
        18,
        "Orbits on a radius x inclination grid: 18 = 3 start radii x 6 inclinations (see "
        "--radius-rb and --inclination-deg).",
    )
    radius_rb: tuple[float, ...] = radius_rb_option(
        (1.1, 2.5),
        "Start radius range of the circular orbits [R_B]: 1.1, 1.8, 2.5 R_B with 18 orbits; "
        "tracked samples then lie at about 1.0-2.6 R_B on 67P.",
    )
    inclination_deg: tuple[float, ...] = option(
        (10.0, 80.0), "Inclination range [deg]: 10, 24, 38, 52, 66, 80 deg with 18 orbits."
    )
    min_radius_rb: float = min_radius_rb_option(
        0.96,
        "Redraw orbits dipping below this radius [R_B]: no sample reaches the deep bins.",
    )
    hidden: tuple[int, ...] = option(
        (24, 24), "Hidden layer sizes of the network.", at_least=1, nonempty=True
    )
    harmonic: float = harmonic_option()
    lm_iterations: int = lm_iterations_option(
        "LM iteration cap of each network member at the first stage."
    )
    altitude_m: float = option(
        300.0, "Altitude of the surface-following evaluation set [m].", above=0
    )
    shells_rb: tuple[float, ...] = option(
        (1.2, 1.3, 1.4, 1.5, 1.6, 1.7),
        "Exterior evaluation shells [R_B] (the orbit radii); the exterior error is their mean.",
        above=1.0,
        nonempty=True,
    )
    deep_bins_rb: tuple[float, ...] = option(
        (0.25, 0.45, 0.55, 0.65, 0.75, 0.85, 0.95),
        "Edges [R_B] of the deep-region radial bins of the surface-following set "
        "(increasing, at most 1).",
    )
    descents: int = option(
        9,
        "Deployment descents tracked as one arc each (see descent_span) and assimilated "
        "after the last stage (0: off).",
        at_least=0,
    )
    descent_span: str = option(
        "end",
        "What a descent's arc covers: 'end', its last 40 samples at 14 s, ending at contact; "
        "'whole', 40 samples spread from release to contact.",
    )
    prior: str = option(
        "none",
        "Known part of every model: 'none' (the central term) or 'shape' (the imaged shape "
        "at constant density as mascons; the network and SH carry the rest, and the prior "
        "alone is scored too).",
    )
    network_start: str = option(
        "random",
        "Where the network's fits from scratch start: 'random' (seeded Glorot weights) or "
        "'zero-output' (the same with the output weights zero: no correction, the known "
        "part alone, at the start).",
    )
    prior_placement: str = option(
        "centred",
        "With prior 'shape': 'centred' (the paper's: the shape's constant-density centre of "
        "mass moved to the frame's origin, so the shape itself moves by the offset between "
        "the two centres of mass) or 'in-place' (the shape where it is, plus the point "
        "dipole that takes that offset out of the known part's exterior).",
    )
    descent_noise: float = option(
        1.0,
        "Scale of the descents' tracking noise, relative to the orbital arcs' (1: the same; "
        "0: noise-free descents, a diagnosis of what the noise costs the assimilation).",
        at_least=0.0,
    )
    envelope_softening_rb: float = option(
        0.0,
        "Softening r_c of the network's envelope [R_B]: R_w^3 / (r^2 + r_c^2)^(3/2) for "
        "(R_w / r)^3, which caps how much a change of the network is amplified near the "
        "centre (0: none).",
        at_least=0.0,
    )

    def check(self) -> None:
        super().check()
        if self.network_start not in NETWORK_STARTS:
            raise InputError(
                f"{label('network_start')} must be one of {', '.join(NETWORK_STARTS)}, "
                f"got {self.network_start!r}"
            )
        if self.prior_placement not in PRIOR_PLACEMENTS:
            raise InputError(
                f"{label('prior_placement')} must be one of {', '.join(PRIOR_PLACEMENTS)}, "
                f"got {self.prior_placement!r}"
            )
        if self.prior_placement != "centred" and self.prior != "shape":
            raise InputError(f"{label('prior_placement')} needs {label('prior')} shape")
        if self.prior not in PRIORS:
            raise InputError(
                f"{label('prior')} must be one of {', '.join(PRIORS)}, got {self.prior!r}"
            )
        if self.descent_span not in DESCENT_SPANS:
            raise InputError(
                f"{label('descent_span')} must be one of {', '.join(DESCENT_SPANS)}, "
                f"got {self.descent_span!r}"
            )
        edges = np.asarray(self.deep_bins_rb, dtype=float)
        if len(edges) < 2 or np.any(np.diff(edges) <= 0) or edges[0] <= 0 or edges[-1] > 1:
            raise InputError(
                f"{label('deep_bins_rb')} must be two or more increasing edges in (0, 1], "
                "e.g. 0.45,0.65,0.95"
            )


def known_of(config: DeepCampaignConfig) -> dict:
    """Every row's known-part settings: the shape prior when there is one, with its placement
    when it is not the default (so the settings of the runs before the option stay)."""
    if config.prior != "shape":
        return {}
    if config.prior_placement == "centred":
        return {"prior": "shape"}
    return {"prior": "shape", "prior_placement": config.prior_placement}


def softening_of(config: DeepCampaignConfig) -> dict:
    """The network rows' envelope-softening setting, given only when there is one (so the
    settings of the runs before the option stay as they were)."""
    if not config.envelope_softening_rb:
        return {}
    return {"envelope_softening_rb": config.envelope_softening_rb}


@dataclass(frozen=True)
class DeepExperimentConfig(DeepCampaignConfig):
    """The deep-region campaign: 67P, 18 orbits in 6 stages, the network and SH 4/8/12."""

    stages: int = option(
        6,
        "Stages the orbits arrive in, in a fixed order: each stage brings one orbit per start "
        "radius, at different inclinations; each stage's fits are warm-started from the "
        "previous stage's.",
        at_least=1,
    )
    sh_degrees: tuple[int, ...] = option(
        (4, 8, 12), "SH degrees fitted (LM).", at_least=2, nonempty=True
    )
    map_degrees: tuple[int, ...] = option(
        (8, 12),
        "SH degrees drawn in the equatorial maps; their error > 1 defines the patches "
        "(must be among --sh-degrees).",
        at_least=2,
        nonempty=True,
    )
    warm_iterations: int = option(
        NETWORK_WARM_SOLVER.max_iter,
        "LM iteration cap of each network member at warm-started stages.",
    )
    warm_gate: bool = warm_gate_option()
    map_extent_rb: float = option(1.3, "Half-width of the equatorial maps [R_B].", above=0)
    map_points: int = option(161, "Grid points along each side of the equatorial maps.", at_least=3)
    descent_iterations: int = option(
        0,
        "0: the descents arrive as a continual stage (one held out for validation, the warm "
        "stage's solver); n > 0: every descent is trained and each model refitted without a "
        "validation stop, the network by n LM iterations per member.",
        at_least=0,
    )
    descent_degrees: tuple[int, ...] = option(
        (8, 12),
        "SH degrees warm-refitted on the descents with the network (among sh_degrees).",
        at_least=2,
    )
    descent_share: float = option(
        0.0,
        "0: every arc of the descent refits weighs 1; s in (0, 1): the descent arcs, as a "
        "set, are weighed at the share s of the refits' cost, measured by what no "
        "correction leaves on them and on the orbital training arcs "
        "(hamgrav.fit.weights.share_weights; the orbital arcs keep weight 1).",
    )
    descent_validation: float = option(
        0.0,
        "With descent_iterations, 0: every descent trains and each refit returns its last "
        "iterate; f in (0, 0.5): that fraction of the descents (seeded by the seed) is held "
        "out of every descent refit and is the network's only validation set: its refit (and "
        "the control) returns the iterate, the stage-6 fit included, with the lowest cost on "
        "them (no validation patience or gate); SH runs its own solver on the rest.",
    )
    descent_control: bool = option(
        False,
        "Also run the network's descent refit from the same stage-6 fit with no descent "
        "arcs (same solver and budget): what the refit alone changes, scored beside the "
        "refit on the descents.",
    )
    descent_anchor: float = option(
        0.0,
        "0: off; w > 0: the network's descent refit (and the control) holds its learned "
        "field near the stage-6 fit's with the weight w (measured like --harmonic) at the "
        "harmonic penalty's collocation points farther than descent_anchor_clearance_rb from "
        "every sample of the arriving arcs (hamgrav.fit.anchor): the descents move the field "
        "where they fly, not where they do not reach.",
        at_least=0,
    )
    descent_anchor_clearance_rb: float = option(
        0.1,
        "With descent_anchor: collocation points within this distance [R_B] of a descent "
        "sample are free of the anchor.",
        at_least=0,
    )
    descent_anchor_on: str = option(
        "acceleration",
        "With descent_anchor: the learned field's quantity held, 'acceleration' (rows "
        "weighted by (r/R_w)^4) or 'potential' (unweighted rows, so a change near the surface "
        "counts as the relative field error counts it).",
    )
    random_orders: int = option(
        5,
        "Random arrival orders of the same orbits, network only, seeded by the seed (0: off).",
        at_least=0,
    )
    d_optimal: bool = option(
        True, "Run the D-optimal campaign (each stage's orbits chosen from the pool)."
    )

    def check(self) -> None:
        super().check()
        degrees = ", ".join(map(str, self.sh_degrees))
        if set(self.map_degrees) - set(self.sh_degrees):
            raise InputError(
                f"{label('map_degrees')} must be among {label('sh_degrees')} ({degrees})"
            )
        if self.descents and set(self.descent_degrees) - set(self.sh_degrees):
            raise InputError(
                f"{label('descent_degrees')} must be among {label('sh_degrees')} ({degrees})"
            )
        if not (self.descent_share == 0 or 0 < self.descent_share < 1):
            raise InputError(
                f"{label('descent_share')} must be 0 (unweighted) or lie in (0, 1), e.g. 0.2; "
                f"got {self.descent_share}"
            )
        if self.descent_anchor_on not in ANCHOR_QUANTITIES:
            raise InputError(
                f"{label('descent_anchor_on')} must be one of {', '.join(ANCHOR_QUANTITIES)}, "
                f"got {self.descent_anchor_on!r}"
            )
        if self.descent_anchor_on != "acceleration" and not self.descent_anchor:
            raise InputError(
                f"{label('descent_anchor_on')} sets the descent refit's anchor: give "
                f"{label('descent_anchor')} above 0 too"
            )
        if self.descent_anchor and not self.descents:
            raise InputError(
                f"{label('descent_anchor')} holds the descent refit near the stage-6 fit: give "
                f"{label('descents')} above 0, or leave it at 0"
            )
        if self.descent_control and not self.descents:
            raise InputError(
                f"{label('descent_control')} refits without the descents: give "
                f"{label('descents')} above 0, or leave it off"
            )
        if self.descent_validation and not (
            self.descent_iterations and 0 < self.descent_validation < 0.5
        ):
            raise InputError(
                f"{label('descent_validation')} holds out a fraction in (0, 0.5) of the "
                f"descents of a fixed-budget refit: give {label('descent_iterations')} above 0 "
                f"and a fraction such as 0.2; got {self.descent_validation}"
            )
        if self.descent_validation and round(self.descent_validation * self.descents) < 1:
            raise InputError(
                f"{label('descent_validation')} {self.descent_validation} of "
                f"{self.descents} descents holds none out: give more descents or a larger "
                "fraction"
            )
        if self.descent_share and not self.descents:
            raise InputError(
                f"{label('descent_share')} weighs the descents: give {label('descents')} "
                "above 0, or leave the share at 0"
            )


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


def random_orders(n_orbits: int, count: int, stages: int, seed: int) -> list[list[np.ndarray]]:
    """``count`` random arrival orders of orbits 0..n_orbits-1, each split into ``stages``
    groups of the fixed order's sizes, seeded by (``seed``, 2): only the permutation of the
    orbits to the stages differs from :func:`arrival_stages`."""
    rng = np.random.default_rng([seed, 2])
    return [
        [np.asarray(g, dtype=int) for g in np.array_split(rng.permutation(n_orbits), stages)]
        for _ in range(count)
    ]


def evaluate(fitted: dict, truth: Truth, config: DeepCampaignConfig, seed: int) -> dict:
    """Errors of fitted models ({name: (model, params)}): ``exterior_error`` (mean over the
    shells), ``deep_error`` (the surface-following set inside R_B), ``deep_bins`` ({model:
    {bin: error}}, None for an empty bin), ``deep_bin_points`` ({bin: points}) and the
    equatorial ``maps`` (pointwise errors, the inside mask and the patch summary)."""
    shells = sets_for(truth, config.shells_rb, (), seed)
    out: dict = {"exterior_error": {}}
    for name, (model, params) in fitted.items():
        out["exterior_error"][name] = significant(
            np.mean(list(errors_of(model, params, truth, shells).values()))
        )
    out.update(deep_bin_errors(fitted, truth, config.altitude_m, config.deep_bins_rb, seed))
    out["maps"] = equatorial_error_map(
        fitted,
        truth,
        config.map_extent_rb,
        config.map_points,
        [f"sh{d}" for d in config.map_degrees],
    )
    return out


def _prior_alone(arcs: Arcs, truth: Truth, shells: dict, config: DeepCampaignConfig, ctx) -> dict:
    """The shape prior's own errors on the exterior ``shells`` and the deep set, no
    correction fitted ({"shape": {exterior, deep, deepest_bin, worst_bin, and each bin's
    error}}): the floor the models start from."""
    model, _ = row_estimator(
        {"term": "none", **known_of(config)}, seed=ctx.seed, body=truth.body
    ).build_model(arcs)
    ev = deep_bin_errors(
        {"shape": (model, np.zeros(0))}, truth, config.altitude_m, config.deep_bins_rb, ctx.seed
    )
    bins = ev["deep_bins"]["shape"]
    deepest, worst = _bin_summary(bins)
    return {
        "shape": {
            "exterior": significant(
                np.mean(list(errors_of(model, np.zeros(0), truth, shells).values()))
            ),
            "deep": ev["deep_error"]["shape"],
            "deepest_bin": deepest,
            "worst_bin": worst,
            **bins,
        }
    }


def _descent_weights(
    est, run, arcs: Arcs, descent_idx: np.ndarray, share: float, held_out=()
) -> np.ndarray:
    """Arc weights (one per arc of ``arcs``) of the descent refit: the descents it trains on
    (``descent_idx`` but ``held_out``) at ``share`` of the cost against the orbital arcs the
    run trains on (:func:`hamgrav.fit.weights.share_weights`, by ``est``'s no-correction
    costs); every descent, held out or not, gets that weight."""
    last = run.records[-1]
    trained = np.setdiff1d(last.arcs, last.validation)
    fitted = np.concatenate([trained, np.setdiff1d(descent_idx, held_out)])
    costs = est.no_correction_costs(arcs.subset(fitted))
    local = share_weights(costs, np.isin(fitted, descent_idx), share)
    weights = np.ones(arcs.n_arcs)
    weights[descent_idx] = local[-1]
    return weights


def _best_iterations(result) -> list[int]:
    """The iteration each member of an ensemble's fit returned (the fit's own, unensembled)."""
    return [m.best_iteration for m in result.members if m is not None] or [result.best_iteration]


def _refit_agreement(before: dict, after: dict, truth: Truth, config, ctx) -> dict:
    """For each ensemble ({name: (model, params)} in both), what the descent refit did to
    the deep set, without the truth: ``deep_change``, the RMS change of the perturbing
    potential, and ``deep_spread_before`` / ``_after``, the RMS of the members' spread
    (:func:`~hamgrav.core.fields.member_spread`), each over the RMS of the perturbing
    potential before the refit. A change the members agree on is one the arcs determine."""
    points = deep_set(truth.body, config.altitude_m, ctx.seed)
    out = {}
    for name, (model, params) in after.items():
        if name not in before or model.learnable is None or model.learnable.members < 2:
            continue
        m0, p0 = before[name]
        v0 = model_perturbing_potential(m0, p0, points)
        v1 = model_perturbing_potential(model, params, points)
        size = np.sqrt(np.mean(v0**2))
        parts = {
            "deep_change": v1 - v0,
            "deep_spread_before": member_spread(m0, p0, points),
            "deep_spread_after": member_spread(model, params, points),
        }
        out[name] = {k: significant(float(np.sqrt(np.mean(v**2)) / size)) for k, v in parts.items()}
    if out:
        ctx.say(
            "the descent refit on the deep set (no truth; relative RMS): "
            + ", ".join(
                f"{n} change {a['deep_change']}, members' spread {a['deep_spread_before']} -> "
                f"{a['deep_spread_after']}"
                for n, a in out.items()
            )
        )
    return out


def _deep_acceleration(before: dict, after: dict, truth: Truth, config, ctx) -> dict:
    """For each refitted model ({name: (model, params)} in both), the truth's relative error
    of the perturbing acceleration on the deep set before and after the descent refit
    (``deep_acceleration_before`` / ``_after``): what the tracked descents observe, beside
    the potential the deep set is scored on."""
    points = deep_set(truth.body, config.altitude_m, ctx.seed)
    return {
        name: {
            f"deep_acceleration_{when}": significant(
                acceleration_field_error(*fitted[name], truth.mascons, points)
            )
            for when, fitted in (("before", before), ("after", after))
        }
        for name in after
        if name in before
    }


def _bin_summary(by_bin: dict) -> tuple[float | None, float | None]:
    """(deepest, worst) of a model's bins: the first bin holding points, and the largest."""
    values = [v for v in by_bin.values() if v is not None]
    return (values[0], max(values)) if values else (None, None)


def campaign_descents(truth: Truth, config: DeepCampaignConfig, seed: int) -> Arcs:
    """The campaign's ``descents`` deployment descents, tracked with its orbital arcs'
    samples and noise (times ``descent_noise``) over ``descent_span``
    (:func:`hamgrav.sim.descent.tracked_descents`)."""
    tracking = config.campaign(seed).tracking
    if config.descent_noise != 1.0:
        tracking = replace(tracking, sigma_r_m=tracking.sigma_r_m * config.descent_noise)
    return tracked_descents(
        truth, config.descents, DescentConfig(), tracking, seed=seed, span=config.descent_span
    )


def _stage_errors(model, records, truth: Truth, shells: dict) -> list[float | None]:
    """The mean exterior error (over ``shells``) of every stage's parameters."""
    return [
        significant(np.mean(list(errors_of(model, r.result.params, truth, shells).values())))
        for r in records
    ]


def _fit_record(record) -> dict:
    """Plain-data summary of a stage's fit (``relative_cost``: see
    :class:`~hamgrav.fit.continual.StageRecord`)."""
    return {
        "iterations": record.result.iterations,
        "wall_s": round(record.result.wall_s, 2),
        "outcome": record.result.outcome.value,
        "warm_started": record.warm_started,
        "relative_cost": significant(record.relative_cost)
        if record.relative_cost is not None
        else None,
        "checked_on": record.checked_on,
    }


def _descent_record(descents: Arcs, truth: Truth) -> dict:
    """Plain-data summary of the tracked descents: count, duration [s], the radii [R_B] their
    arcs span, where they touch down [R_B]."""
    r_b = truth.body.brillouin_radius
    r = np.linalg.norm(descents.true_states[..., :3], axis=-1) / r_b
    info = descents.trajectory_info

    def span(values) -> dict:
        values = np.asarray(values, dtype=float)
        return {"min": round(float(values.min()), 3), "max": round(float(values.max()), 3)}

    return {
        "n": descents.n_arcs,
        "duration_s": span(info["duration_s"]),
        "arc_radius_rb": span(r),
        "arc_start_radius_rb": [round(float(v), 3) for v in r[:, 0]],
        "contact_radius_rb": [round(float(v), 3) for v in r[:, -1]],
        "dv_m_s": [round(float(v), 4) for v in info["dv_m_s"]],
    }


def _order_unit(
    unit, *, arcs, truth, settings, sizes, shells, seed, escape_factor, client=None
) -> dict:
    """One arrival order of the network (a work unit of plain data, but for ``client``, the
    Dask client of a distributed fit when the units run in this process): ``unit`` is
    ("random", stage groups of orbit indices) or ("d-optimal", None). Returns the orbits by
    stage, the mean exterior error after each stage, the D-optimal choices and the wall time
    [s]."""
    kind, groups = unit
    start = time.perf_counter()
    est = row_estimator(settings, seed=seed, body=truth.body, client=client)
    choices = None
    if kind == "random":
        run = ContinualFit(est, arcs)
        for g in groups:
            run.add(arcs.arcs_of(g))
        orbits = [[int(k) for k in g] for g in groups]
    else:
        run, choices = d_optimal_campaign(
            est,
            arcs,
            orbit_plans(arcs),
            sizes,
            brillouin_radius=truth.body.brillouin_radius,
            escape_factor=escape_factor,
        )
        orbits = [c["picked"] for c in choices]
    return {
        "kind": kind,
        "orbits": orbits,
        "errors": _stage_errors(est.model_, run.records, truth, shells),
        "choices": choices,
        "fit_wall_s": round(sum(r.result.wall_s for r in run.records), 1),
        "wall_s": round(time.perf_counter() - start, 1),
    }


class DeepExperiment(Experiment):
    """See the module docstring."""

    name = "deep"
    title = "Inside the Brillouin sphere: the deep region of 67P"
    config_type = DeepExperimentConfig
    aggregate_keys = (
        "summary",
        "deep_bins",
        "deep_bins_after_descents",
        "deep_bins_descent_control",
        "descents_summary",
        "orders_summary",
        "prior_alone",
    )
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
        "descents.png": "(a) the descent arcs over the shape's vertices, x-y projection (first "
        "repetition; x: contact); (b) error by radial bin of the models refitted on the "
        "descents, before (dashed) and after (solid), the median over the repetitions "
        "(min-max shaded after)",
        "orders.png": "the network's mean exterior error against the number of orbits tracked "
        "(first repetition): random arrival orders (grey, min-max band), the D-optimal "
        "campaign (bold) and the fixed order (dashed)",
    }

    def run(self, config: DeepExperimentConfig, ctx: RunContext) -> RunOutput:
        wall: dict[str, float] = {}
        clock = [time.perf_counter()]

        def lap(part: str) -> None:
            now = time.perf_counter()
            wall[part] = round(wall.get(part, 0.0) + now - clock[0], 1)
            clock[0] = now

        truth, arcs = simulate(config, ctx)
        r_b = truth.body.brillouin_radius
        radii = sample_radii(arcs, r_b, SAMPLE_FLOOR_RB)
        ctx.say(
            f"sample radii [R_B]: {radii['min']:.3f}-{radii['max']:.3f} (median "
            f"{radii['median']:.3f}), {radii['below_floor']} of {radii['n_samples']} below "
            f"{radii['floor_rb']:g}"
        )
        info = arcs.trajectory_info
        groups = arrival_stages(info["radius_rb"], info["inclination_deg"], config.stages)
        sizes = [len(g) for g in groups]
        tracking = config.campaign(ctx.seed).tracking
        lap("simulate")
        all_arcs, descent_idx, descents = arcs, None, None
        voting = np.zeros(0, dtype=int)  # descents held out to choose the refits' iterates
        if config.descents:
            desc = campaign_descents(truth, config, ctx.seed)
            all_arcs = join_arcs(arcs, desc)
            descent_idx = np.arange(arcs.n_arcs, all_arcs.n_arcs)
            if config.descent_validation:
                _, held = validation_split(len(descent_idx), config.descent_validation, ctx.seed)
                voting = descent_idx[held]
            descents = _descent_record(desc, truth)
            ctx.say(
                f"{config.descents} descents, {descents['duration_s']['min']:.0f}-"
                f"{descents['duration_s']['max']:.0f} s; their arcs span "
                f"{descents['arc_radius_rb']['min']:.2f}-{descents['arc_radius_rb']['max']:.2f} R_B"
            )
            lap("descents_simulate")
        arriving = [all_arcs.arcs_of(g) for g in groups]
        known = known_of(config)
        best = network_best(
            config.hidden,
            config.lm_iterations,
            harmonic=config.harmonic,
            network_start=config.network_start,
            **softening_of(config),
            **known,
        )
        best["warm_solver"] = replace(
            best["warm_solver"], max_iter=config.warm_iterations, validation_gate=config.warm_gate
        )
        rows = {f"sh{d}": {"term": "sh", "degree": d, **known} for d in config.sh_degrees}
        rows[NETWORK] = best
        refit = (
            {NETWORK, *(f"sh{d}" for d in config.descent_degrees)}
            if descent_idx is not None
            else set()
        )
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
        finals, after, descent_fits, fits, controls = {}, {}, {}, {}, {}
        for name, settings in rows.items():
            est, run = fit_staged(settings, all_arcs, arriving, truth, ctx)
            records = list(run.records)
            errors = _stage_errors(est.model_, records, truth, shells)
            for stage, record, err in zip(stages, records, errors, strict=True):
                stage["exterior_error"][name] = err
                stage["fits"][name] = _fit_record(record)
            finals[name] = (est.model_, records[-1].result.params)
            ctx.say(
                f"{name}: exterior error by stage "
                + ", ".join(f"{e}" for e in errors)
                + f"; {sum(r.result.wall_s for r in records):.0f} s in all"
            )
            fixed_fit = est.fitted_.solver
            lap("fixed_order")
            if name in refit:
                weights = (
                    _descent_weights(est, run, all_arcs, descent_idx, config.descent_share, voting)
                    if config.descent_share
                    else None
                )
                # with descent_iterations the network runs a fixed budget, SH its own solver
                # to convergence; all descents train (no validation stop), or the held-out
                # ones (descent_validation) alone choose the iterate
                stage = (
                    {
                        "validate": bool(len(voting)),
                        "solver": replace(
                            settings["warm_solver"],
                            max_iter=config.descent_iterations,
                            patience=None,
                            validation_gate=settings["warm_solver"].validation_gate
                            and not len(voting),
                        )
                        if name == NETWORK
                        else None,
                    }
                    if config.descent_iterations
                    else {}
                )
                held = {"validation_arcs": voting} if len(voting) else {}
                if config.descent_anchor and name == NETWORK:
                    # the control is anchored at the refit's points: clear of the descents
                    held["anchor"] = AnchorSettings(
                        config.descent_anchor,
                        config.descent_anchor_clearance_rb * truth.body.brillouin_radius,
                        clear_of=all_arcs.states[descent_idx][..., :3],
                        quantity=config.descent_anchor_on,
                    )
                # the same refit with no new arcs, from the same fit (descent_control); with
                # held-out descents they still choose its iterate, and none trains
                control = run.fork() if config.descent_control and name == NETWORK else None
                record = run.add(descent_idx, arc_weights=weights, **held, **stage)
                after[name] = (est.model_, record.result.params)
                descent_fits[name] = {"n_arcs": record.n_arcs, **_fit_record(record)}
                if "anchor" in held:
                    # None: the stage restarted cold, without it
                    descent_fits[name]["anchor"] = est.fitted_.solver.get("anchor")
                if len(voting):
                    descent_fits[name]["n_validation_descents"] = len(voting)
                if len(voting) and name == NETWORK:
                    descent_fits[name]["best_iterations"] = _best_iterations(record.result)
                if control is not None:
                    lap("descent_refits")
                    control_record = control.add(voting, **held, **stage)
                    controls[name] = (control.estimator.model_, control.params)
                    descent_fits[name]["control"] = {
                        "n_arcs": control_record.n_arcs,
                        **_fit_record(control_record),
                    }
                    if "anchor" in held:
                        anchor_record = control.estimator.fitted_.solver.get("anchor")
                        descent_fits[name]["control"]["anchor"] = anchor_record
                    if len(voting):
                        descent_fits[name]["control"]["best_iterations"] = _best_iterations(
                            control_record.result
                        )
                    lap("descent_control")
                if weights is not None:
                    # the weights the fit ran with, as its solver recorded them
                    descent_fits[name]["descent_weight"] = significant(weights[descent_idx[0]])
                    record_w = est.fitted_.solver["arc_weights"]
                    descent_fits[name]["arc_weights"] = {
                        k: v for k, v in record_w.items() if k != "values"
                    }
                lap("descent_refits")
            fits[name] = fixed_fit
        ev = evaluate(finals, truth, config, ctx.seed)
        maps = ev.pop("maps")
        summary = {}
        for name in finals:
            deepest, worst = _bin_summary(ev["deep_bins"][name])
            summary[name] = {
                "exterior": ev["exterior_error"][name],
                "deep": ev["deep_error"][name],
                "deepest_bin": deepest,
                "worst_bin": worst,
                "patch_median": maps["patch_median"][name],
            }
        ctx.say(
            "deep region: "
            + ", ".join(f"{n} {s['deep']}" for n, s in summary.items())
            + f"; patches: {maps['patch_points']} map points"
        )
        lap("evaluate")
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
            "fits": fits,
        }
        if known:
            result["prior_alone"] = _prior_alone(all_arcs, truth, shells, config, ctx)
            ctx.say(
                f"the shape prior alone: {result['prior_alone']['shape']['exterior']} exterior, "
                f"{result['prior_alone']['shape']['deep']} deep"
            )
        if after:
            result.update(
                self._after_descents(after, summary, truth, shells, config, ctx, controls)
            )
            for name, agreement in _refit_agreement(finals, after, truth, config, ctx).items():
                result["descents_summary"][name].update(agreement)
            for name, errors in _deep_acceleration(finals, after, truth, config, ctx).items():
                result["descents_summary"][name].update(errors)
            result["descents"] = {**descents, "fits": descent_fits}
            lap("evaluate_descents")
        result.update(self._orders(arcs, truth, best, sizes, stages, shells, tracking, ctx, config))
        wall["random_orders"] = result.pop("_random_wall_s")
        wall["d_optimal"] = result.pop("_d_optimal_wall_s")
        lap("orders_elapsed")
        result["wall_parts_s"] = wall
        ctx.say("wall time by part [s]: " + ", ".join(f"{k} {v:.0f}" for k, v in wall.items()))
        artefacts = campaign_artefacts(truth, arcs)
        artefacts["maps"] = {k: maps[k] for k in ("errors", "inside", "patch", "axis_m")}
        if descent_idx is not None:
            length = truth.body.units.length_m
            artefacts["descent_positions_m"] = all_arcs.true_states[descent_idx, :, :3] * length
        return RunOutput(result, artefacts)

    @staticmethod
    def _after_descents(after, summary, truth, shells, config, ctx, controls) -> dict:
        """The deep bins, deep set and exterior error of the models refitted on the
        descents, beside their values before, and of the ``controls`` (the same refits
        with no descent arcs; {name: (model, params)}) as ``*_control``."""
        ev = deep_bin_errors(after, truth, config.altitude_m, config.deep_bins_rb, ctx.seed)
        out = {"deep_bins_after_descents": ev["deep_bins"], "descents_summary": {}}
        if controls:
            ev_control = deep_bin_errors(
                controls, truth, config.altitude_m, config.deep_bins_rb, ctx.seed
            )
            out["deep_bins_descent_control"] = ev_control["deep_bins"]
        for name, (model, params) in after.items():
            deepest, worst = _bin_summary(ev["deep_bins"][name])
            exterior = np.mean(list(errors_of(model, params, truth, shells).values()))
            out["descents_summary"][name] = {
                "deepest_bin_before": summary[name]["deepest_bin"],
                "deepest_bin_after": deepest,
                "worst_bin_after": worst,
                "deep_before": summary[name]["deep"],
                "deep_after": ev["deep_error"][name],
                "exterior_before": summary[name]["exterior"],
                "exterior_after": significant(exterior),
            }
            if name in controls:
                c_model, c_params = controls[name]
                c_exterior = np.mean(list(errors_of(c_model, c_params, truth, shells).values()))
                out["descents_summary"][name].update(
                    deepest_bin_control=_bin_summary(ev_control["deep_bins"][name])[0],
                    deep_control=ev_control["deep_error"][name],
                    exterior_control=significant(c_exterior),
                )
        ctx.say(
            "after the descents, deepest bin: "
            + ", ".join(
                f"{n} {s['deepest_bin_before']} -> {s['deepest_bin_after']}"
                for n, s in out["descents_summary"].items()
            )
        )
        return out

    @staticmethod
    def _orders(arcs, truth, best, sizes, stages, shells, tracking, ctx, config) -> dict:
        """The random arrival orders and the D-optimal campaign of the network, as work units
        over ``ctx.mapper``; the fixed order's curve is taken from ``stages``."""
        n_orbits = [int(n) for n in np.cumsum(sizes)]
        units = [
            ("random", g)
            for g in random_orders(arcs.n_trajectories, config.random_orders, len(sizes), ctx.seed)
        ]
        if config.d_optimal:
            units.append(("d-optimal", None))
        work = partial(
            _order_unit,
            arcs=arcs,
            truth=truth,
            settings=best,
            sizes=sizes,
            shells=shells,
            seed=ctx.seed,
            escape_factor=tracking.escape_factor,
            # units mapped over the cluster are its tasks already: their fits run there
            client=ctx.fit_client if ctx.mapper is map else None,
        )
        done = []
        for unit in ctx.mapper(work, units):  # builtin map: one by one, as each finishes
            done.append(unit)
            ctx.say(
                f"order {len(done)}/{len(units)} ({unit['kind']}): exterior error by stage "
                + ", ".join(f"{e}" for e in unit["errors"])
                + f"; {unit['wall_s']:.0f} s"
            )
        fixed = [s["exterior_error"][NETWORK] for s in stages]
        orders: dict = {"n_orbits": n_orbits, "fixed": fixed}
        random = [d for d in done if d["kind"] == "random"]
        dopt = next((d for d in done if d["kind"] == "d-optimal"), None)
        out: dict = {"_random_wall_s": round(sum(d["wall_s"] for d in random), 1)}
        out["_d_optimal_wall_s"] = dopt["wall_s"] if dopt else 0.0
        orders["random"] = [d["errors"] for d in random]
        orders["random_orbits"] = [d["orbits"] for d in random]
        curves = {"fixed": fixed}
        if random:
            table = np.array([[np.inf if e is None else e for e in d["errors"]] for d in random])
            curves["random-best"] = [significant(v) for v in table.min(axis=0)]
            curves["random-worst"] = [significant(v) for v in table.max(axis=0)]
            ctx.say(
                f"{len(random)} random orders, exterior error after each stage: "
                + "; ".join(", ".join(f"{e}" for e in d["errors"]) for d in random)
            )
        if dopt is not None:
            orders["d-optimal"] = dopt["errors"]
            orders["d_optimal_orbits"] = dopt["orbits"]
            curves["d-optimal"] = dopt["errors"]
            info = arcs.trajectory_info
            out["d_optimal_picks"] = [
                [
                    {
                        "orbit": k,
                        "radius_rb": float(info["radius_rb"][k]),
                        "inclination_deg": float(info["inclination_deg"][k]),
                        "gain": round(g, 2),
                    }
                    for k, g in zip(c["picked"], c["gains"], strict=True)
                ]
                for c in dopt["choices"]
            ]
            out["d_optimal_first_picks"] = [
                [p["radius_rb"], p["inclination_deg"]] for p in out["d_optimal_picks"][0]
            ]
            ctx.say(
                "D-optimal: exterior error after each stage "
                + ", ".join(f"{e}" for e in dopt["errors"])
                + "; first picks (R_B, deg) "
                + ", ".join(f"({r:g}, {i:g})" for r, i in out["d_optimal_first_picks"])
            )
        out["orders"] = orders
        out["orders_summary"] = {
            name: {f"{n} orbits": e for n, e in zip(n_orbits, curve, strict=False)}
            for name, curve in curves.items()
        }
        return out

    def readme(self, report: dict) -> list[str]:
        return deep_readme(report, PAPER)

    def figures(self, report: dict, artefacts: dict) -> dict:
        figures = {
            "geometry.png": geometry_figure(report, artefacts),
            "deep_bins.png": bins_figure(report),
            "maps.png": maps_figure(report, artefacts),
        }
        if report["aggregate"].get("deep_bins_after_descents"):
            figures["descents.png"] = descents_figure(report, artefacts)
        if any(
            len(r.get("orders", {}).get("random", [])) or "d-optimal" in r.get("orders", {})
            for r in report["repetitions"]
        ):
            figures["orders.png"] = orders_figure(report)
        return figures
