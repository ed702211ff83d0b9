"""Pieces every campaign experiment shares: its campaign options, the simulated campaign,
fits through the estimator, evaluation sets and plain-data artefacts for figures."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from ..bodies.evaluation import evaluation_sets
from ..bodies.interiors import INTERIORS, TRUTH_FRAMES, Truth
from ..core.arcs import Arcs
from ..core.fields import field_errors
from ..errors import InputError
from ..fit.continual import ContinualFit
from ..fit.estimator import (
    NETWORK_BEST_HARMONIC,
    NETWORK_BEST_SOLVER,
    NETWORK_WARM_SOLVER,
    GravityEstimator,
    preset,
)
from ..sim.campaign import MAX_TRUTH_MASCONS, Campaign, run_campaign
from ..sim.tracking import MAX_ORBIT_RADIUS_RB, TrackingConfig, orbit_grid
from ..sizing import fit_bytes
from .base import RunContext
from .config import ExperimentConfig, label, largest_parameters, option

__all__ = [
    "CampaignConfig",
    "committed_holdout",
    "cv_sh_option",
    "cv_sh_row",
    "simulate",
    "fit",
    "network_best",
    "harmonic_option",
    "errors_of",
    "sets_for",
    "campaign_artefacts",
]


def n_mascons_option(default: int = 600, help: str = "Truth mascons."):
    """The ``n_mascons`` option: the truth's mascon count, within a campaign file's bounds."""
    return option(default, help, at_least=10, at_most=MAX_TRUTH_MASCONS)


def orbits_option(default: int = 16, help: str = "Orbits, on a radius x inclination grid."):
    """The ``orbits`` option: the orbit count, within a campaign file's bounds."""
    return option(default, help, at_least=1, at_most=1000)


def radius_rb_option(default=(1.2, 2.0), help: str = "Orbit radius range [R_B]."):
    """The ``radius_rb`` option: start radii [R_B] outside the Brillouin sphere."""
    return option(default, help, above=1, at_most=MAX_ORBIT_RADIUS_RB)


def min_radius_rb_option(
    default: float = 0.0, help: str = "Redraw orbits dipping below this radius [R_B] (0: off)."
):
    """The ``min_radius_rb`` option [R_B] (0: off)."""
    return option(default, help, at_least=0, at_most=MAX_ORBIT_RADIUS_RB)


@dataclass(frozen=True)
class CampaignConfig(ExperimentConfig):
    """The tracking campaign of an experiment (the paper's 112-arc campaign by default)."""

    body: str = option("itokawa", "Body: a catalogue name, 'synthetic' or a body TOML file.")
    interior: str = option("head-tail", f"Truth interior: {' | '.join(INTERIORS)}.")
    n_mascons: int = n_mascons_option()
    orbits: int = orbits_option()
    radius_rb: tuple[float, ...] = radius_rb_option()
    inclination_deg: tuple[float, ...] = option(
        (10.0, 80.0), "Inclination range [deg].", at_least=0, at_most=180
    )
    arcs_per_orbit: int = option(
        7, "Arcs per orbit (40 samples at 14 s each).", at_least=1, at_most=10_000
    )
    window_spin_periods: float = option(
        1.0, "Tracking window of each orbit [spin periods].", above=0, at_most=100
    )
    min_radius_rb: float = min_radius_rb_option()
    frame: str = option(
        "centre-of-mass",
        "Origin of the body frame (arcs, central term, SH, evaluation shells): 'centre-of-mass' "
        "of the truth, or 'shape', the constant-density centroid of the imaged shape (the "
        "truth's offset from it stays in the perturbing potential as a degree-1 part).",
    )

    contrast: float = option(
        2.0,
        "Head-tail interior: density of the head lobe over the rest's, total mass fixed (the "
        "shared reference file mascons_head_tail_2x uses 1.63 on the same head).",
    )

    def check(self) -> None:
        if not self.contrast > 0:
            raise InputError(f"{label('contrast')} must be positive, got {self.contrast}")
        if self.interior not in INTERIORS:
            raise InputError(
                f"{label('interior')} must be one of {', '.join(INTERIORS)}, got {self.interior!r}"
            )
        if self.frame not in TRUTH_FRAMES:
            raise InputError(
                f"{label('frame')} must be one of {', '.join(TRUTH_FRAMES)}, got {self.frame!r}"
            )
        for name in ("radius_rb", "inclination_deg"):
            low_high = getattr(self, name)
            if len(low_high) != 2 or low_high[0] > low_high[1]:
                raise InputError(
                    f"{label(name)} must be a range of two numbers (low, high), got "
                    f"{','.join(map(str, low_high))}"
                )
        # the option of harmonic_option(), in the experiments that have a network-best row
        if getattr(self, "harmonic", 0.0) < 0:
            raise InputError(f"{label('harmonic')} must be >= 0 (0: off), got {self.harmonic}")
        # the stages of the experiments that bring the orbits in stages, each at least one orbit
        stages = getattr(self, "stages", 1)
        if not 1 <= stages <= self.orbits:
            raise InputError(
                f"{label('stages')} must lie between 1 and {label('orbits')} ({self.orbits}), "
                f"got {stages}"
            )
        # the options of lm_iterations_option() and warm-stage caps, where an experiment has them
        for name in ("lm_iterations", "warm_iterations", "warm_patience"):
            if getattr(self, name, 1) < 1:
                raise InputError(f"{label(name)} must be at least 1, got {getattr(self, name)}")
        # the campaign file's checks (orbit radii and count, tracking, truth mascons) apply
        # to an experiment's campaign too, before anything runs
        Campaign.from_dict(self.campaign(0).as_dict(), source="campaign")

    memory_fix = "lower --orbits, --arcs-per-orbit, --hidden or the SH degrees"

    def memory_parts(self) -> dict[str, float]:
        """Its campaign's simulation and its largest fit's arrays [bytes] (the campaign's arcs
        are the fit's: counted once)."""
        campaign = self.campaign(0)
        n_arcs = self.orbits * self.arcs_per_orbit
        fit = fit_bytes(n_arcs, campaign.tracking.samples_per_arc, largest_parameters(self))
        del fit["the arcs"]
        return campaign.memory_parts() | fit

    def campaign(self, seed: int) -> Campaign:
        """The campaign this config describes, seeded."""
        families = orbit_grid(self.orbits, tuple(self.radius_rb), tuple(self.inclination_deg))
        tracking = TrackingConfig(
            arcs_per_orbit=self.arcs_per_orbit,
            window_spin_periods=self.window_spin_periods,
            min_radius_rb=self.min_radius_rb,
        )
        return Campaign(
            self.body,
            self.interior,
            self.n_mascons,
            seed,
            tuple(families),
            tracking,
            frame=self.frame,
            contrast=self.contrast,
        )


def simulate(config: CampaignConfig, ctx: RunContext) -> tuple[Truth, Arcs]:
    """The truth and its simulated arcs for ``config`` at the context's seed."""
    start = time.perf_counter()
    truth, arcs = run_campaign(config.campaign(ctx.seed), folder=ctx.bodies_folder)
    ctx.say(f"truth and {arcs.n_arcs} arcs in {time.perf_counter() - start:.1f} s")
    return truth, arcs


def committed_holdout(settings: dict) -> dict:
    """``settings`` with the validation fraction the experiments' committed results were
    fitted with when they give none: 12 % of the arcs (rounded) for the network, none for SH
    and the known part alone (the estimator's defaults until every fit held arcs out, see
    :func:`hamgrav.fit.estimator.default_holdout`), so that their numbers do not move."""
    if "validation_fraction" in settings:
        return settings
    network = settings.get("term", "network") == "network"
    return {**settings, "validation_fraction": 0.12 if network else 0.0}


def row_estimator(
    settings: dict, *, seed: int, body=None, mapper=map, client=None, committed: bool = True
) -> GravityEstimator:
    """The estimator of one experiment row (the only place an experiment builds one):
    ``settings`` are its keywords as a row spells them (``{"term": "sh", "degree": 8}``),
    ``body`` the truth's body (None: the one the arcs record), ``mapper`` the map for its
    independent work and ``client`` the Dask client of a distributed fit (None: in this
    process; see :attr:`RunContext.fit_client`). With ``committed`` the row keeps the
    hold-out its committed results were fitted with (:func:`committed_holdout`); without,
    the estimator's own default."""
    keywords = committed_holdout(settings) if committed else settings
    return GravityEstimator(body=body, seed=seed, mapper=mapper, client=client, **keywords)


def fit(name: str, arcs: Arcs, truth: Truth, ctx: RunContext, **settings) -> GravityEstimator:
    """Fit one row of an experiment through the estimator (the one fit path), reporting
    progress about every 20 s."""
    last = [time.perf_counter()]

    def progress(iteration: int, record: dict) -> None:
        if time.perf_counter() - last[0] > 20.0:
            last[0] = time.perf_counter()
            costs = ", ".join(
                f"{k} {v:.3g}" for k, v in record.items() if k in ("train", "validation", "cost")
            )
            ctx.say(f"{name}: iteration {iteration} ({costs}, canonical units)")

    estimator = row_estimator(
        settings, seed=ctx.seed, body=truth.body, mapper=ctx.mapper, client=ctx.fit_client
    )
    estimator.fit(arcs, callback=progress)
    r = estimator.result_
    ctx.say(f"{name}: {r.outcome.value}, {r.iterations} iterations in {r.wall_s:.1f} s")
    return estimator


def fit_rows(
    rows: dict[str, dict], arcs: Arcs, truth: Truth, ctx: RunContext, sets: dict, prefix: str = ""
) -> tuple[dict[str, GravityEstimator], dict[str, dict[str, float]]]:
    """The campaign's fits: every row (name -> estimator settings) fitted to ``arcs`` in
    order (:func:`fit`; progress names it ``prefix`` + name), and each row's field errors on
    the named evaluation ``sets`` (:func:`errors_of`). Returns (estimators, errors) by row."""
    fits = {name: fit(f"{prefix}{name}", arcs, truth, ctx, **s) for name, s in rows.items()}
    errors = {name: errors_of(e.model_, e.params_, truth, sets) for name, e in fits.items()}
    return fits, errors


def fit_staged(
    settings: dict, arcs: Arcs, arriving, truth: Truth, ctx: RunContext, *, warm_start=True
) -> tuple[GravityEstimator, ContinualFit]:
    """One row of a campaign whose arcs arrive in stages: the estimator of ``settings`` fitted
    stage by stage (``arriving``: the arc indices of ``arcs`` that arrive at each stage),
    warm-started from the previous stage's fit unless ``warm_start`` is false. Returns the
    estimator and its :class:`~hamgrav.fit.continual.ContinualFit` (its ``records``, one per
    stage; more stages can be added to it)."""
    estimator = row_estimator(
        settings, seed=ctx.seed, body=truth.body, mapper=ctx.mapper, client=ctx.fit_client
    )
    run = ContinualFit(estimator, arcs, warm_start=warm_start)
    for new in arriving:
        run.add(new)
    return estimator, run


def network_best(hidden, lm_iterations: int, *, harmonic: float, **overrides) -> dict:
    """The network-best estimator settings of an experiment row: ``hidden`` layers, each
    member's LM iteration cap, the harmonic penalty's weight (0: off) and other overrides."""
    best = preset("network-best", hidden=hidden, harmonic=harmonic or None, **overrides)
    best["solver"] = replace(best["solver"], max_iter=lm_iterations)
    return best


def lm_iterations_option(help: str = "LM iteration cap of each network-best member."):
    """The ``lm_iterations`` option of an experiment config: network-best's own cap by default."""
    return option(NETWORK_BEST_SOLVER.max_iter, help)


def warm_gate_option():
    """The ``warm_gate`` option of an experiment config with warm-started network stages:
    the validation gate of network-best's warm solver (on by default)."""
    return option(
        NETWORK_WARM_SOLVER.validation_gate,
        "Warm stages: after a member's first validation gain, accept only steps that lower "
        "the validation cost too (the LM solver's validation_gate).",
    )


def harmonic_option(row: str = "network-best"):
    """The ``harmonic`` option of an experiment config: the weight of the harmonic penalty
    of its ``row`` (network-best's own by default)."""
    return option(
        NETWORK_BEST_HARMONIC,
        f"Weight of the harmonic penalty of the '{row}' row (its Laplacian, scaled by "
        "(r / R_w)^5, pushed to zero at 1500 points outside the body out to the farthest "
        "sample; 0: off).",
    )


def cv_sh_option():
    """The ``cv_sh`` option of an experiment config with SH rows (off: the committed results
    have no such row)."""
    return option(
        False,
        "Also fit SH chosen from the arcs alone (no truth) by 5-fold cross-validation over "
        "whole arcs, one-standard-error rule: row 'sh-cv' (its degree among 2 to the largest "
        "of --sh-degrees, then its Kaula alpha among 1e-4..1e-8 and 0 at that degree) and, "
        "where Kaula rows are fitted, '-kaula-cv' rows (alpha chosen at their degree).",
    )


def cv_sh_row(degrees, **settings) -> dict:
    """The settings of the 'sh-cv' row: SH of degree chosen among 2..max(``degrees``) and
    Kaula alpha chosen at it, by cross-validation on all the arcs (none held out besides the
    folds, as the other SH rows), with the other ``settings``."""
    return {
        "term": "sh",
        "degree": tuple(range(2, max(degrees) + 1)),
        "kaula": "cv",
        "validation_fraction": 0.0,
        **settings,
    }


def errors_of(model, params, truth: Truth, sets: dict) -> dict[str, float]:
    """Field errors of ``model`` at ``params`` on the named sets, rounded to 4 digits."""
    errs = field_errors(model, params, truth.mascons, sets)
    return {k: round(v, 4) for k, v in errs.items()}


def sets_for(truth: Truth, shells_rb, altitudes_m, seed: int) -> dict:
    """Evaluation sets of the truth's body (see :func:`hamgrav.bodies.evaluation_sets`)."""
    return evaluation_sets(truth.body, tuple(shells_rb), tuple(altitudes_m), seed=seed)


def campaign_artefacts(truth: Truth, arcs: Arcs) -> dict:
    """Plain arrays for the campaign figure: mesh [m], Brillouin radius [m], arcs [m]."""
    length = truth.body.units.length_m
    return {
        "vertices_m": np.asarray(truth.body.mesh.vertices) * length,
        "faces": np.asarray(truth.body.mesh.faces),
        "brillouin_radius_m": truth.body.brillouin_radius_m,
        "arc_positions_m": arcs.true_states[..., :3] * length,
        "arc_trajectory": np.asarray(arcs.trajectory),
        "arcs": arcs,
        "interior": truth.interior,
        "body": truth.body.name,
    }
