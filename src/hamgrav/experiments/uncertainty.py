"""How sure: is the formal sigma of the learned potential honest?

Truth (Itokawa, head lobe twice as dense, centred) -> the 112-arc campaign -> SH 4, SH 8 (LM)
and network-best (the mean of three LM-fitted networks with the harmonic penalty) fitted to
the identical arcs -> each fit's formal parameter covariance
(:mod:`hamgrav.fit.covariance`: the noise of every sample and of each arc's anchor through
the normal equations, the pseudo-inverse over the directions the arcs constrain, scaled by
the a posteriori variance factor) -> sigma_V(q) = sqrt(g^T C g) on the shells and the 30 m
surface-following set -> against the true error of the perturbing potential at every point:
the fractions within 1 and 2 sigma (0.68 and 0.95 when honest) and the median |error| /
sigma (0.67 when honest).

Also recorded: the same with the a priori covariance (the stated noise, no variance factor);
the refits' spread under noise redraws of the same arcs (the noise response that the formal
sigma predicts, without the truth); the rank threshold's effect; for the network, the row
``network-best+penalty``: the same fit with the harmonic penalty's Gauss-Newton rows in each
member's normal matrix (the noise response of the penalised fit rather than what the arcs
alone constrain), the sigma the members' block-diagonal covariance would give (as if each
member had its own noise draw), and the members' spread (their standard deviation /
sqrt(members), what the initialisations alone leave uncertain), alone and added in
quadrature to the formal sigma.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..core.fields import (
    MAX_SHELL_RB,
    member_spread,
    model_perturbing_potential,
    perturbing_potential,
)
from ..core.uncertainty import potential_gradient
from ..fit.covariance import RANK_THRESHOLD, calibration, normal_system
from ..fit.estimator import fitted_harmonic_penalty, noise_sigmas
from ..report.uncertainty import calibration_figure, maps_figure, uncertainty_readme
from ..sim.tracking import observe
from .base import Experiment, RunContext, RunOutput
from .common import (
    CampaignConfig,
    errors_of,
    fit,
    harmonic_option,
    lm_iterations_option,
    network_best,
    sets_for,
    simulate,
)
from .config import option

__all__ = ["UncertaintyExperimentConfig", "UncertaintyExperiment"]


@dataclass(frozen=True)
class UncertaintyExperimentConfig(CampaignConfig):
    """The uncertainty experiment: the campaign, the fitted rows and the evaluation sets."""

    sh_degrees: tuple[int, ...] = option(
        (4, 8), "SH degrees fitted (LM).", at_least=2, nonempty=True
    )
    hidden: tuple[int, ...] = option(
        (24, 24), "Hidden layer sizes of the network.", at_least=1, nonempty=True
    )
    lm_iterations: int = lm_iterations_option("LM iteration cap of each network member.")
    harmonic: float = harmonic_option()
    shells_rb: tuple[float, ...] = option(
        (1.05, 1.2, 1.5),
        "Evaluation shells [R_B].",
        at_least=1.0,
        at_most=MAX_SHELL_RB,
        nonempty=True,
    )
    altitude_m: float = option(
        30.0, "Altitude of the surface-following evaluation set [m].", above=0
    )
    redraws: int = option(
        2,
        "Noise redraws of the same arcs (same truth, orbits and initialisations), each "
        "fitted again: the refits' spread is the noise response the formal sigma predicts.",
        at_least=0,
    )
    thresholds: tuple[float, ...] = option(
        (RANK_THRESHOLD, 1e-9, 1e-6),
        "Relative eigenvalue thresholds of the pseudo-inverse: the first gives the headline "
        "table, the others its sensitivity.",
        above=0,
        at_most=1,
        nonempty=True,
    )


def _sigma(g: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """sqrt(g^T C g) per row of g (k, n)."""
    return np.sqrt(np.clip(np.einsum("ki,ki->k", g @ cov, g), 0.0, None))


def _row(error: np.ndarray, sigma: np.ndarray, scale: float) -> dict:
    """Calibration of one (model, set) plus the RMS error and sigma [m^2/s^2]."""
    return {
        **{k: round(v, 4) for k, v in calibration(error, sigma).items()},
        "rms_error_m2_s2": scale * float(np.sqrt(np.mean(error**2))),
        "rms_sigma_m2_s2": scale * float(np.sqrt(np.mean(sigma**2))),
    }


class UncertaintyExperiment(Experiment):
    """See the module docstring."""

    name = "uncertainty"
    title = "How sure: calibration of the formal sigma of the learned potential"
    config_type = UncertaintyExperimentConfig
    aggregate_keys = ("calibration", "calibration_a_priori", "redraws", "field_error")
    default_output = "results/uncertainty-itokawa"
    figure_captions = {
        "maps.png": "the true error of each model's perturbing potential (left) and its "
        "formal sigma (right) on the 1.2 R_B shell, longitude x latitude, one colour scale "
        "per model",
        "calibration.png": "|true error| against the formal sigma at every evaluation point, "
        "per model, coloured by set; below the solid line the error is within 1 sigma, below "
        "the dashed within 2",
    }

    def run(self, config: UncertaintyExperimentConfig, ctx: RunContext) -> RunOutput:
        truth, arcs = simulate(config, ctx)
        rows = {f"sh{d}": {"term": "sh", "degree": d} for d in config.sh_degrees}
        rows["network-best"] = network_best(
            config.hidden, config.lm_iterations, harmonic=config.harmonic
        )
        fits = {name: fit(name, arcs, truth, ctx, **s) for name, s in rows.items()}
        sets = sets_for(truth, config.shells_rb, (config.altitude_m,), ctx.seed)
        refit_spread = _refit_spread(config, ctx, truth, arcs, rows, fits, sets)
        scale = float(truth.body.units.from_potential(1.0))  # canonical potential [m^2/s^2]
        result = {
            "body": config.body,
            "interior": config.interior,
            "n_arcs": arcs.n_arcs,
            "calibration": {},
            "calibration_a_priori": {},
            "thresholds": {},
            "covariance": {},
            "network": {},
            "redraws": {},
            "field_error": {
                n: errors_of(e.model_, e.params_, truth, sets) for n, e in fits.items()
            },
            "fits": {n: e.fitted_.solver for n, e in fits.items()},
        }
        figure = {"sets": {}, "r_b": truth.body.brillouin_radius}
        variants = []  # (row, estimator, normal system)
        for name, est in fits.items():
            system = normal_system(est.fitted_, arcs, train=est.train_)
            variants.append((name, est, system))
            penalty = fitted_harmonic_penalty(est.fitted_, arcs, truth.body)
            if penalty is not None:
                # the same fit with the harmonic penalty's rows in each member's normal matrix
                # (what evaluate --uncertainty reports for such a fit)
                variants.append((f"{name}+penalty", est, system.with_penalty(penalty, est.fitted_)))
        for name, est, system in variants:
            model, params = est.model_, est.params_
            covs = {t: system.covariance(t) for t in config.thresholds}
            head = covs[config.thresholds[0]]
            result["covariance"][name] = head.describe()
            ctx.say(
                f"{name}: rank {'/'.join(map(str, head.ranks))} of "
                f"{head.describe()['parameters_per_member']} per member, variance factor "
                + "/".join(f"{f:.3g}" for f in head.variance_factors)
            )
            scan = {}
            network = name == "network-best"
            extra = {"block_diagonal_sigma_ratio": {}, "spread": {}, "formal_plus_spread": {}}
            scaled = head.scaled()
            for set_name, pts in sets.items():
                g = potential_gradient(model, params, pts)
                err = model_perturbing_potential(model, params, pts)
                err = err - perturbing_potential(truth.mascons, pts)
                sigma = _sigma(g, scaled)
                key = f"{name} {set_name}"
                result["calibration"][key] = _row(err, sigma, scale)
                result["calibration_a_priori"][key] = _row(err, _sigma(g, head.matrix), scale)
                if refit_spread:
                    refits = refit_spread[name.removesuffix("+penalty")][set_name]
                    rms_spread = float(np.sqrt(np.mean(refits**2)))
                    rms_sigma = float(np.sqrt(np.mean(sigma**2)))
                    result["redraws"][key] = {
                        "rms_spread_m2_s2": scale * rms_spread,
                        "rms_sigma_m2_s2": scale * rms_sigma,
                        "sigma_over_spread": round(rms_sigma / rms_spread, 4),
                    }
                for t, c in covs.items():
                    scan.setdefault(f"{t:g}", {"ranks": list(c.ranks)})[set_name] = {
                        k: round(v, 4)
                        for k, v in calibration(err, _sigma(g, c.scaled())).items()
                        if k != "rms_z"
                    }
                if not name.endswith("+penalty"):
                    figure["sets"].setdefault(set_name, {"points": pts})[name] = (err, sigma)
                if network:
                    block = _sigma(g, head.block_diagonal(scaled))
                    extra["block_diagonal_sigma_ratio"][set_name] = round(
                        float(np.sqrt(np.mean(block**2) / np.mean(sigma**2))), 4
                    )
                    members = member_spread(model, params, pts)
                    extra["spread"][set_name] = _row(err, members, scale)
                    extra["formal_plus_spread"][set_name] = _row(
                        err, np.hypot(sigma, members), scale
                    )
            result["thresholds"][name] = scan
            if network:
                result["network"] = extra
            ctx.say(
                f"{name}: within 1 / 2 sigma "
                + ", ".join(
                    f"{s} {result['calibration'][f'{name} {s}']['within_1_sigma']:.2f}/"
                    f"{result['calibration'][f'{name} {s}']['within_2_sigma']:.2f}"
                    for s in sets
                )
            )
        return RunOutput(result, {"figure": figure, "potential_m2_s2": scale})

    def readme(self, report: dict) -> list[str]:
        return uncertainty_readme(report)

    def figures(self, report: dict, artefacts: dict) -> dict:
        data, scale = artefacts["figure"], artefacts["potential_m2_s2"]
        first = report["repetitions"][0]
        title = f"{first['body']}, {first['n_arcs']} arcs (seed {first['seed']})"
        return {
            "maps.png": maps_figure(data, scale, title),
            "calibration.png": calibration_figure(data, scale, title),
        }


def _refit_spread(config, ctx, truth, arcs, rows, fits, sets) -> dict:
    """{row: {set: (k,) standard deviation of the perturbing potential over the fit and its
    refits to ``config.redraws`` noise redraws of the same true arcs}} (canonical; empty
    without redraws). Each refit starts from the same seeded initialisations and holds out
    the same arcs: only the noise differs."""
    if config.redraws < 1:
        return {}
    values = {
        n: {s: [model_perturbing_potential(e.model_, e.params_, p)] for s, p in sets.items()}
        for n, e in fits.items()
    }
    sigmas = noise_sigmas(arcs)
    for k in range(config.redraws):
        rng = np.random.default_rng([ctx.seed, 1000 + k])
        noisy = replace(arcs, states=observe(arcs.true_states, sigmas[0], sigmas[3], rng))
        for name, settings in rows.items():
            est = fit(f"{name} (redraw {k + 1})", noisy, truth, ctx, **settings)
            for s, p in sets.items():
                values[name][s].append(model_perturbing_potential(est.model_, est.params_, p))
    return {
        n: {s: np.std(v, axis=0, ddof=1) for s, v in per_set.items()}
        for n, per_set in values.items()
    }
