"""Joint estimation of gravity and solar radiation pressure on a particle swarm (the paper's
"particle swarm" row: Bennu, 28 particles, 263 arcs at 39 s cadence).

Truth: the body's shape at constant density (mascons) with SRP acting on every particle
(:mod:`hamgrav.sim.particles`: per-particle A/m, Sun fixed inertially, constant flux). The
particles are the tracking data. Fits, all through the estimator and the same variational
equations:

- joint: SH of each degree in ``sh_degrees`` (LM) and the network-best configuration with one
  member (an ensemble cannot estimate per-trajectory parameters), each with the particles' A/m
  as per-trajectory parameters estimated together with gravity (SRP in the model, only its
  coefficients unknown);
- gravity-only: the same SRP-active arcs with no SRP term in the model: SH of degree
  ``gravity_only_degree`` and the same network;
- with ``harmonic_scan`` (the default), each network-best fit (joint and gravity-only, each
  on its own) is made once per harmonic-penalty weight, and the fit kept is chosen from the
  costs on its held-out arcs by ``harmonic_scan_rule`` (:func:`choose_weight`): a choice a
  mission can make, with no truth;
- with ``paper_network``, also the paper's protocol network (preset ``network``: Adam, no
  harmonic penalty, the same hidden layers) both ways, as rows ``network-adam``.

Reported: per-particle A/m relative errors (median), field errors on the ``altitude_m``
surface-following set and on shells, the draws rejected by the simulation, and the wall time
of every stage.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..bodies.catalogue import load_body
from ..bodies.interiors import INTERIORS, build_truth
from ..core.fields import MAX_SHELL_RB
from ..errors import InputError, PropagationError
from ..fit.estimator import PRESETS, preset
from ..fit.selection import RULES, choose
from ..report.swarm import swarm_figure, swarm_readme
from ..report.tables import summarise
from ..sim.particles import SwarmConfig, simulate_swarm, solar_radiation_pressure
from ..sizing import fit_bytes
from .base import Experiment, RunContext, RunOutput
from .common import (
    errors_of,
    fit,
    harmonic_option,
    lm_iterations_option,
    n_mascons_option,
    network_best,
    sets_for,
)
from .config import ExperimentConfig, label, largest_parameters, option

__all__ = [
    "SwarmExperimentConfig",
    "SwarmExperiment",
    "PAPER_SWARM",
    "SCAN_RULES",
    "choose_weight",
]

#: The paper's numbers: A/m median relative error of the joint fits (fraction) and the field
#: error at 30 m altitude (1 = no correction).
PAPER_SWARM = {
    "a/m sh8 joint": 0.006,
    "a/m network joint": 0.035,
    "h30m sh8 gravity-only": 3.5,
    "h30m network joint": 0.33,
    "h30m network gravity-only": 0.48,
}


#: Row name of the paper's protocol network (``--paper-network``).
PAPER_NETWORK = "network-adam"


@dataclass(frozen=True)
class SwarmExperimentConfig(ExperimentConfig):
    """The particle-swarm experiment (the paper's Bennu campaign by default)."""

    body: str = option("bennu", "Body: a catalogue name, 'synthetic' or a body TOML file.")
    interior: str = option("uniform", f"Truth interior: {' | '.join(INTERIORS)}.")
    n_mascons: int = n_mascons_option()
    particles: int = option(28, "Particles ejected and tracked.", at_least=1)
    arcs: int = option(263, "Arcs in all, shared out over the particles.", at_least=1)
    samples_per_arc: int = option(40, "Samples per arc.", at_least=2)
    cadence_s: float = option(39.0, "Time between samples [s].", above=0)
    window_s: float = option(16_200.0, "Tracking span of each particle from ejection [s].", above=0)
    area_to_mass_m2_kg: tuple[float, ...] = option(
        (0.055, 0.825),
        "A/m range [m^2/kg] (log-uniform, stratified over the particles): 0.055-0.825 are "
        "spheres of 1.4-0.09 cm diameter at 2 g/cm^3, the SRP strength at which the paper's "
        "swarm statements come closest to holding together (0.02-0.3: 3.8-0.25 cm, the "
        "sizes reported for Bennu's particles, gives too little SRP for them).",
        above=0,
    )
    speed_escape_fraction: tuple[float, ...] = option(
        (0.6, 1.0), "Ejection speed range relative to the surface, in local escape speeds.", above=0
    )
    cone_deg: float = option(
        45.0, "Half-angle of the ejection cone about the normal [deg].", at_least=0, at_most=90
    )
    escape_radius_rb: float = option(
        4.0, "Beyond this radius [R_B] a particle has escaped.", above=1
    )
    distance_au: float = option(
        0.9, "Heliocentric distance [AU] (flux 1361 W/m^2 at 1 AU).", above=0
    )
    reflectivity: float = option(
        1.044, "1 + rho of the cannonball SRP model (1: black body).", at_least=1, at_most=2
    )
    sun_latitude_deg: float = option(
        0.0, "Latitude of the inertially fixed Sun [deg].", at_least=-90, at_most=90
    )
    sh_degrees: tuple[int, ...] = option(
        (4, 8, 12), "SH degrees of the joint fits (LM).", at_least=2, nonempty=True
    )
    gravity_only_degree: int = option(8, "SH degree of the gravity-only fit.", at_least=2)
    hidden: tuple[int, ...] = option(
        (16, 16), "Hidden layer sizes of the network.", at_least=1, nonempty=True
    )
    harmonic: float = harmonic_option("network")
    harmonic_scan: tuple[float, ...] = option(
        (1e-5, 1e-4, 1e-3, 1e-2, 1e-1),
        "Weights of the harmonic penalty to scan for each 'network' fit (joint and "
        "gravity-only, each on its own): every weight is fitted and the fit that "
        "--harmonic-scan-rule chooses from the costs on its held-out arcs is kept (no truth). "
        'Empty (""): no scan, the single weight --harmonic (which a scan replaces).',
        at_least=0,
    )
    harmonic_scan_rule: str = option(
        "one-standard-error",
        "How the scan chooses: 'lowest' keeps the weight of lowest held-out cost; "
        "'one-standard-error' the strongest weight whose held-out cost is within one standard "
        "error (paired over the held-out arcs) of the lowest, so that the more harmonic field "
        "is kept when the held-out arcs cannot tell the fits apart.",
    )
    harmonic_scan_folds: int = option(
        0,
        "0: --harmonic-scan chooses on each fit's own held-out arcs (one split; the committed "
        "results); k >= 2: by k-fold cross-validation over whole arcs of the training arcs "
        "(the estimator's harmonic choice, same rule), then only the kept weight is fitted "
        "on all of them (no field errors of the other weights).",
        at_least=0,
    )
    lm_iterations: int = lm_iterations_option("LM iteration cap of the network fits.")
    paper_network: bool = option(
        False,
        f"Also fit the paper's protocol network (preset 'network': Adam, "
        f"{PRESETS['network']['adam_steps']} steps) jointly and gravity-only, as rows "
        f"'{PAPER_NETWORK}'.",
    )
    altitude_m: float = option(
        30.0, "Altitude of the surface-following evaluation set [m].", above=0
    )
    shells_rb: tuple[float, ...] = option(
        (1.05, 1.2), "Evaluation shells [R_B].", at_least=1.0, at_most=MAX_SHELL_RB, nonempty=True
    )

    def check(self) -> None:
        if self.interior not in INTERIORS:
            raise InputError(
                f"{label('interior')} must be one of {', '.join(INTERIORS)}, got {self.interior!r}"
            )
        for name in ("area_to_mass_m2_kg", "speed_escape_fraction"):
            if len(getattr(self, name)) != 2:
                raise InputError(f"{label(name)} must be two numbers: low,high")
        if self.harmonic < 0:
            raise InputError(f"{label('harmonic')} must be >= 0 (0: off), got {self.harmonic}")
        if self.harmonic_scan_rule not in SCAN_RULES:
            raise InputError(
                f"{label('harmonic_scan_rule')} must be one of {', '.join(SCAN_RULES)}, got "
                f"{self.harmonic_scan_rule!r}"
            )
        if self.harmonic_scan_folds == 1:
            raise InputError(
                f"{label('harmonic_scan_folds')} must be 0 (one held-out split) or 2 or more"
            )
        if len(self.harmonic_scan) == 1:
            raise InputError(
                f"{label('harmonic_scan')} needs two or more weights to choose from; for one "
                f"weight give {label('harmonic')}"
            )
        try:
            self.swarm()
        except InputError as exc:
            # name the command-line option: SwarmConfig's fields are this config's options
            raise InputError(f"swarm option: {exc}") from None

    memory_fix = "lower --arcs, --samples-per-arc, --hidden or the SH degrees"

    def memory_parts(self) -> dict[str, float]:
        """Its arcs and its largest fit's arrays [bytes]: the network or SH expansion and one
        A/m per particle."""
        n_params = largest_parameters(self) + self.particles
        return fit_bytes(self.arcs, self.samples_per_arc, n_params)

    def swarm(self) -> SwarmConfig:
        """The particle campaign of this config."""
        return SwarmConfig(
            particles=self.particles,
            arcs=self.arcs,
            samples_per_arc=self.samples_per_arc,
            cadence_s=self.cadence_s,
            window_s=self.window_s,
            area_to_mass_m2_kg=tuple(self.area_to_mass_m2_kg),
            speed_escape_fraction=tuple(self.speed_escape_fraction),
            cone_deg=self.cone_deg,
            escape_radius_rb=self.escape_radius_rb,
            distance_au=self.distance_au,
            reflectivity=self.reflectivity,
            sun_latitude_deg=self.sun_latitude_deg,
        )


#: How a harmonic-weight scan chooses among its fits (see :func:`choose_weight`).
SCAN_RULES = RULES


def choose_weight(weights, arc_costs, rule: str) -> int:
    """Index of the weight ``rule`` keeps, given each fit's costs on the same held-out arcs
    (``arc_costs``: one row per weight, one column per arc, in any common unit; absolute
    costs, so arcs with larger residuals weigh more, as in the total cost). A fit whose total
    is not finite is never kept.

    The rule is :func:`hamgrav.fit.selection.choose` with the weights ranked strongest
    (simplest) first, on a single held-out set: the one-fold case of the estimator's
    cross-validation (``harmonic="cv"``). ``lowest``: the fit of lowest total cost.
    ``one-standard-error``: the largest weight whose mean cost over the arcs exceeds the
    lowest fit's by at most one standard error of the paired per-arc differences."""
    costs = np.asarray(arc_costs, dtype=float)
    order = sorted(range(len(weights)), key=lambda k: -weights[k])
    try:
        return order[choose(costs[order], rule)]
    except PropagationError:
        raise ValueError("no fit of the scan has a finite held-out cost") from None


def _fit_harmonic_scan(label, arcs, truth, ctx, settings: dict, weights, rule: str, sets) -> tuple:
    """Fit a network row once per harmonic-penalty weight and keep the fit ``rule`` chooses
    from the costs on its held-out arcs (:func:`choose_weight`). Every fit has the same seed,
    so the same held-out arcs and starting network. Returns the kept estimator and
    {"weights": [...], "held_out_cost": [...] (relative to no correction), "rule": rule,
    "chosen": weight, "field_error": [{set: error} per weight]}. The field errors (truth)
    play no part in the choice: they record how far the rule is from the best weight."""
    fitted, costs, per_arc = [], [], []
    for w in weights:
        est = fit(
            f"{label} (harmonic {w:g})", arcs, truth, ctx, **{**settings, "harmonic": w or None}
        )
        if est.diagnostics_.get("checked_on") != "validation arcs":
            raise InputError(
                "--harmonic-scan chooses by the cost on held-out arcs, and this fit holds none "
                "out: give the network a validation fraction > 0"
            )
        fitted.append(est)
        costs.append(float(est.diagnostics_["relative_cost"]))
        per_arc.append(est.checked_arc_costs_.fitted)
    k = choose_weight(weights, per_arc, rule)
    ctx.say(
        f"{label}: harmonic weight {weights[k]:g} kept by the {rule} rule (held-out cost "
        "relative to no correction: "
        + ", ".join(f"{w:g} {c:.4f}" for w, c in zip(weights, costs, strict=True))
        + ")"
    )
    scan = {
        "weights": [float(w) for w in weights],
        "held_out_cost": [round(c, 6) for c in costs],
        "rule": rule,
        "chosen": float(weights[k]),
        "field_error": [errors_of(e.model_, e.params_, truth, sets) for e in fitted],
    }
    return fitted[k], scan


def _fit_harmonic_cv(label, arcs, truth, ctx, settings: dict, weights, rule, folds) -> tuple:
    """Fit a network row with its harmonic weight chosen among ``weights`` by ``folds``-fold
    cross-validation over whole arcs of its training arcs (the estimator's ``harmonic``
    choice, :mod:`hamgrav.fit.selection`; arcs, not particles, since the particles' A/m are
    estimated from their own arcs). Returns the estimator and {"weights", "rule", "folds",
    "chosen", "selection": the cross-validation table}."""
    cv = {"harmonic": tuple(weights), "folds": folds, "cv_rule": rule, "cv_group": "arc"}
    est = fit(
        f"{label} (harmonic by {folds}-fold cross-validation)",
        arcs,
        truth,
        ctx,
        **{
            **settings,
            **cv,
        },
    )
    (selection,) = est.selection_
    for line in selection.lines(f"{label}: harmonic weight"):
        ctx.say(line)
    scan = {
        "weights": [float(w) for w in weights],
        "rule": rule,
        "folds": folds,
        "chosen": float(selection.chosen),
        "selection": selection.describe(),
    }
    return est, scan


def _median_relative_error(estimated, true) -> float:
    return float(np.median(np.abs(np.asarray(estimated) - true) / true))


class SwarmExperiment(Experiment):
    """See the module docstring."""

    name = "swarm"
    title = "Particle swarm: joint estimation of gravity and solar radiation pressure"
    config_type = SwarmExperimentConfig
    aggregate_keys = ("area_to_mass_median_error", "field_error")
    default_output = "results/swarm-bennu"
    figure_captions = {
        "swarm.png": "(a) the tracked arcs of every particle over the shape in the body frame, "
        "coloured by the particle's true A/m; (b) estimated against true A/m for the joint "
        "SH and network fits (the diagonal is a perfect estimate)",
    }

    def run(self, config: SwarmExperimentConfig, ctx: RunContext) -> RunOutput:
        seed, say = ctx.seed, ctx.say
        stages: dict[str, float] = {}
        start = time.perf_counter()
        body = load_body(config.body, folder=ctx.bodies_folder)
        truth = build_truth(body, config.interior, n_mascons=config.n_mascons, seed=seed)
        swarm = config.swarm()
        arcs = simulate_swarm(truth, swarm, seed=seed)
        stages["simulation"] = round(time.perf_counter() - start, 1)
        info = arcs.trajectory_info
        true_am = np.asarray(info["area_to_mass_m2_kg"], dtype=float)
        draws = int(config.particles + info["redraws"].sum())
        say(
            f"truth and {config.particles} particles ({arcs.n_arcs} arcs) in "
            f"{stages['simulation']:.1f} s; {int(info['redraws'].sum())} of {draws} draws "
            f"rejected ({int(info['impacted'].sum())} impacts, {int(info['escaped'].sum())} "
            "escapes)"
        )
        srp = solar_radiation_pressure(truth.body.units, swarm)
        joint = {"per_trajectory": (srp,), "estimate_trajectory_params": True}
        best = network_best(
            config.hidden, config.lm_iterations, harmonic=config.harmonic, members=1
        )
        best["warm_solver"] = None
        rows = {
            ("joint", f"sh{d}"): {"term": "sh", "degree": d, **joint} for d in config.sh_degrees
        }
        rows[("joint", "network")] = {**best, **joint}
        rows[("gravity-only", f"sh{config.gravity_only_degree}")] = {
            "term": "sh",
            "degree": config.gravity_only_degree,
        }
        rows[("gravity-only", "network")] = best
        if config.paper_network:
            paper = preset("network", hidden=config.hidden)
            rows[("joint", PAPER_NETWORK)] = {**paper, **joint}
            rows[("gravity-only", PAPER_NETWORK)] = paper
        sets = sets_for(truth, config.shells_rb, (config.altitude_m,), seed)
        field_error: dict = {"joint": {}, "gravity-only": {}}
        estimated: dict[str, list[float]] = {}
        fits: dict = {"joint": {}, "gravity-only": {}}
        scans: dict = {}
        for (kind, model), settings in rows.items():
            label = f"{kind}/{model}"
            start = time.perf_counter()
            if model == "network" and config.harmonic_scan and config.harmonic_scan_folds:
                est, scans[kind] = _fit_harmonic_cv(
                    label,
                    arcs,
                    truth,
                    ctx,
                    settings,
                    config.harmonic_scan,
                    config.harmonic_scan_rule,
                    config.harmonic_scan_folds,
                )
            elif model == "network" and config.harmonic_scan:  # check(): two weights or more
                est, scans[kind] = _fit_harmonic_scan(
                    label,
                    arcs,
                    truth,
                    ctx,
                    settings,
                    config.harmonic_scan,
                    config.harmonic_scan_rule,
                    sets,
                )
            else:
                est = fit(label, arcs, truth, ctx, **settings)
            stages[label] = round(time.perf_counter() - start, 1)
            if model == "network" and "field_error" in scans.get(kind, {}):
                # the scan has the kept fit's errors
                scan = scans[kind]
                field_error[kind][model] = scan["field_error"][
                    scan["weights"].index(scan["chosen"])
                ]
            else:
                field_error[kind][model] = errors_of(est.model_, est.params_, truth, sets)
            fits[kind][model] = est.fitted_.solver
            if kind == "joint":
                estimated[model] = [float(v) for v in est.params_[est.model_.n_learn :]]
        am_error = {m: round(_median_relative_error(v, true_am), 5) for m, v in estimated.items()}
        say(
            "A/m median error: "
            + ", ".join(f"{m} {100 * v:.2f} %" for m, v in am_error.items())
            + f"; {config.altitude_m:g} m field error: "
            + ", ".join(
                f"{k}/{m} {e[f'h{config.altitude_m:g}m']:.3f}"
                for k, row in field_error.items()
                for m, e in row.items()
            )
        )
        speeds = np.asarray(info["speed_m_s"])
        r_b = truth.body.brillouin_radius
        radius = np.linalg.norm(arcs.true_states[..., :3], axis=-1) / r_b
        result = {
            "body": config.body,
            "n_arcs": arcs.n_arcs,
            "n_particles": config.particles,
            "srp": {**srp.describe(), "acceleration_per_area_to_mass_m_s2": _per_am(srp, truth)},
            "draws": {
                "total": draws,
                "rejected": int(info["redraws"].sum()),
                "impacted": int(info["impacted"].sum()),
                "escaped": int(info["escaped"].sum()),
            },
            "speed_m_s": [round(float(speeds.min()), 4), round(float(speeds.max()), 4)],
            "radius_rb": [round(float(f(radius)), 3) for f in (np.min, np.median, np.max)],
            "area_to_mass_span": round(float(true_am.max() / true_am.min()), 2),
            "area_to_mass_median_error": am_error,
            "area_to_mass": {"true": [float(v) for v in true_am], **estimated},
            "field_error": field_error,
            "wall_s_stages": stages,
            "fits": fits,
        }
        if scans:
            result["harmonic_scan"] = scans
        length = truth.body.units.length_m
        artefacts = {
            "vertices_m": np.asarray(truth.body.mesh.vertices) * length,
            "faces": np.asarray(truth.body.mesh.faces),
            "arc_positions_m": arcs.true_states[..., :3] * length,
            "arc_area_to_mass": true_am[arcs.trajectory],
        }
        return RunOutput(result, artefacts)

    def aggregate(self, repetitions: list[dict]) -> dict:
        """Median, min, max and count over the repetitions of every number in
        ``area_to_mass_median_error`` ({model: value}) and ``field_error`` ({fit: {model:
        {set: value}}}), in the same nesting."""
        return {key: _nested_summary([r[key] for r in repetitions]) for key in self.aggregate_keys}

    def readme(self, report: dict) -> list[str]:
        return swarm_readme(report, PAPER_NETWORK, PAPER_SWARM)

    def figures(self, report: dict, artefacts: dict) -> dict:
        return {"swarm.png": swarm_figure(report["repetitions"][0], artefacts)}


def _per_am(srp, truth) -> float:
    """SRP acceleration [m/s^2] per unit A/m [m^2/kg]."""
    return float(truth.body.units.from_acceleration(srp.pressure_canonical))


def _nested_summary(values: list):
    """The statistics of :func:`hamgrav.experiments.runner.aggregate` at every leaf of a list of
    identically nested dicts of numbers."""
    if isinstance(values[0], dict):
        keys = [k for k in values[0] if all(isinstance(v, dict) and k in v for v in values)]
        return {k: _nested_summary([v[k] for v in values]) for k in keys}
    return summarise([v if isinstance(v, int | float) else None for v in values])
