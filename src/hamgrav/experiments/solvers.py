"""Solver comparison: the paper's choices next to ours, on one campaign, same sensitivities.

- Network: Adam (the paper) vs Levenberg-Marquardt, each on the unweighted canonical cost (the
  paper) and on the noise-weighted cost; same validation hold-out, same initialisation.
- SH degree 4 and 8 by Levenberg-Marquardt (reference rows).
- Continual learning: the campaign in stages; each stage warm-started vs from scratch
  (iterations and wall time of both).
- D-optimal selection: greedy picks from the campaign's orbits (predicted sensitivities at the
  degree-4 model fitted on the first stage) against seeded random orders: log det of the accumulated
  information after each pick.
"""

from __future__ import annotations

import time
from dataclasses import asdict

import numpy as np

from ..bodies import load_body
from ..continual import fit_continual
from ..design import greedy_d_optimal, random_order_logdet, trajectory_informations
from ..estimator import noise_sigmas
from ..evaluate import evaluation_sets, field_errors
from ..interiors import build_truth
from ..model import Model
from ..sensitivity import ArcProblem
from ..solvers import Adam, LevenbergMarquardt, split_validation
from ..terms import NeuralPotential, PointMass, SphericalHarmonics
from ..tracking import TrackingConfig, orbit_grid, simulate_orbits

__all__ = ["run_solver_comparison"]


def _rounded(d: dict, digits: int = 4) -> dict:
    return {k: round(float(v), digits) for k, v in d.items()}


def run_solver_comparison(
    *,
    body: str = "itokawa",
    interior: str = "head-tail",
    orbits: int = 16,
    arcs_per_orbit: int = 7,
    hidden=(24, 24),
    adam_steps: int = 1500,
    lm_iterations: int = 20,
    learning_rate: float = 1e-2,
    stages: int = 4,
    seed: int = 0,
    progress=None,
) -> dict:
    """Run the comparison; returns a JSON-able dict. ``progress(text)`` reports each stage."""
    say = progress or (lambda text: None)
    wall = {}
    t = time.perf_counter()
    truth = build_truth(load_body(body), interior, seed=seed)
    families = orbit_grid(orbits, (1.2, 2.0), (10.0, 80.0))
    arcs = simulate_orbits(
        truth, families, TrackingConfig(arcs_per_orbit=arcs_per_orbit), seed=seed
    )
    wall["truth_and_simulation_s"] = time.perf_counter() - t
    say(f"simulated {arcs.n_arcs} arcs")
    sets = evaluation_sets(truth.body, (1.05, 1.2, 1.5), (30.0,), seed=seed)
    r_b = truth.body.brillouin_radius
    train, validation = split_validation(arcs.n_arcs, 0.12, seed)

    rows = {}
    for degree in (4, 8):
        model = Model((PointMass(),), SphericalHarmonics(degree, r_b))
        res = LevenbergMarquardt().solve(ArcProblem(model, arcs))
        rows[f"sh{degree}-lm"] = {
            "solver": "lm",
            "weighted": False,
            "n_params": model.n_learn,
            "iterations": res.iterations,
            "wall_s": res.wall_s,
            "field_error": _rounded(field_errors(model, res.params, truth.mascons, sets)),
        }
        say(f"sh{degree}: {rows[f'sh{degree}-lm']['field_error']}")

    net = NeuralPotential(tuple(hidden))
    model = Model((PointMass(),), net)
    theta0 = net.initial_params(seed)
    sigmas = noise_sigmas(arcs)
    for weighted in (False, True):
        problem = ArcProblem(model, arcs, sigmas=sigmas if weighted else None)
        for name, solver in (
            ("adam", Adam(steps=adam_steps, learning_rate=learning_rate, seed=seed)),
            ("lm", LevenbergMarquardt(max_iter=lm_iterations, rtol=1e-9)),
        ):
            res = solver.solve(problem, theta0, train=train, validation=validation)
            key = f"network-{name}-{'weighted' if weighted else 'unweighted'}"
            rows[key] = {
                "solver": name,
                "weighted": weighted,
                "n_params": net.n_params,
                "iterations": res.iterations,
                "best_iteration": res.best_iteration,
                "wall_s": res.wall_s,
                "field_error": _rounded(field_errors(model, res.params, truth.mascons, sets)),
            }
            say(f"{key}: {rows[key]['field_error']} in {res.wall_s:.1f} s")

    # Continual learning with the best network solver found here (LM, unweighted) and SH 8.
    per_stage = np.array_split(np.arange(orbits), stages)
    stage_arcs = [np.flatnonzero(np.isin(arcs.trajectory, o)) for o in per_stage]
    continual = {}
    for label, c_model, solver, c_theta0, frac in (
        (
            "sh8-lm",
            Model((PointMass(),), SphericalHarmonics(8, r_b)),
            LevenbergMarquardt(),
            None,
            0.0,
        ),
        ("network-lm", model, LevenbergMarquardt(max_iter=lm_iterations, rtol=1e-4), theta0, 0.12),
    ):
        out = {}
        for warm in (True, False):
            records = fit_continual(
                c_model,
                arcs,
                stage_arcs,
                solver,
                c_theta0,
                warm_start=warm,
                validation_fraction=frac,
                seed=seed,
            )
            out["warm" if warm else "scratch"] = [
                {
                    "stage": r.stage,
                    "n_arcs": r.n_arcs,
                    "iterations": r.iterations,
                    "warm_started": r.warm_started,
                    "wall_s": round(r.wall_s, 3),
                    "field_error_r1.2": round(
                        field_errors(c_model, r.result.params, truth.mascons, sets)["r1.2"], 4
                    ),
                }
                for r in records
            ]
        continual[label] = out
        say(
            f"continual {label}: warm {[s['iterations'] for s in out['warm']]}, scratch "
            f"{[s['iterations'] for s in out['scratch']]}"
        )

    # D-optimal picks among the campaign's orbits, at the SH-4 model of the first stage
    # (well determined from one stage of data, unlike degree 8).
    sh4 = Model((PointMass(),), SphericalHarmonics(4, r_b))
    first = LevenbergMarquardt().solve(ArcProblem(sh4, arcs.subset(stage_arcs[0]))).params
    infos = trajectory_informations(sh4, first, arcs)
    n_pick = min(8, orbits)
    picked, greedy_logdet, gains = greedy_d_optimal(infos, n_pick)
    randoms = [random_order_logdet(infos, n_pick, seed=s) for s in range(5)]
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
    return {
        "experiment": "solvers",
        "body": body,
        "interior": interior,
        "seed": seed,
        "n_arcs": arcs.n_arcs,
        "orbits": orbits,
        "arcs_per_orbit": arcs_per_orbit,
        "network_hidden": list(hidden),
        "adam_steps": adam_steps,
        "adam_learning_rate": learning_rate,
        "lm_iterations": lm_iterations,
        "fits": {k: {**v, "wall_s": round(v["wall_s"], 3)} for k, v in rows.items()},
        "continual": continual,
        "d_optimal": design,
        "wall_s": {k: round(v, 2) for k, v in wall.items()},
    }


def write_solver_report(results: dict, folder, command: str) -> None:
    """results.json, README.md (tables) and figure.png into ``folder`` (atomically each)."""
    import matplotlib.pyplot as plt

    from ._report import save_figure, start_report, write_text

    results, folder = start_report(results, folder, command)

    sets = list(next(iter(results["fits"].values()))["field_error"])
    lines = [
        f"# Solver comparison: {results['body']} ({results['interior']}), {results['n_arcs']} arcs",
        "",
        "Regenerate with:",
        "",
        f"    {command}",
        "",
        "Every fit uses the same arcs and the same exact sensitivities (variational equations);",
        "network fits share the initialisation and the 12 % validation hold-out. Field errors",
        "are relative errors of the perturbing potential (1 = no correction).",
        "",
        "| model | solver | cost | params | iterations | wall [s] | " + " | ".join(sets) + " |",
        "|---|---|---|---|---|---|" + "---|" * len(sets),
    ]
    for key, row in results["fits"].items():
        lines.append(
            f"| {key} | {row['solver']} | {'weighted' if row['weighted'] else 'unweighted'} | "
            f"{row['n_params']} | {row['iterations']} | {row['wall_s']:.1f} | "
            + " | ".join(f"{row['field_error'][s]:.3f}" for s in sets)
            + " |"
        )
    lines += [
        "",
        "## Continual learning: warm start vs scratch",
        "",
        "| model | stage | arcs | iterations warm | iterations scratch | "
        "wall warm [s] | wall scratch [s] | r1.2 warm | r1.2 scratch |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for label, out in results["continual"].items():
        for w, s in zip(out["warm"], out["scratch"], strict=True):
            lines.append(
                f"| {label} | {w['stage'] + 1} | {w['n_arcs']} | {w['iterations']} | "
                f"{s['iterations']} | {w['wall_s']:.2f} | {s['wall_s']:.2f} | "
                f"{w['field_error_r1.2']:.3f} | {s['field_error_r1.2']:.3f} |"
            )
    d = results["d_optimal"]
    lines += [
        "",
        "## D-optimal selection vs random orders",
        "",
        f"Information at {d['model']}; log det(Lambda_acc + eps I) after each pick.",
        "",
        "| picks | greedy | "
        + " | ".join(f"random {i}" for i in range(len(d["random_logdet"])))
        + " |",
        "|---|---|" + "---|" * len(d["random_logdet"]),
    ]
    for k, g in enumerate(d["greedy_logdet"]):
        lines.append(
            f"| {k + 1} | {g:.1f} | " + " | ".join(f"{r[k]:.1f}" for r in d["random_logdet"]) + " |"
        )
    lines += [
        "",
        "Greedy picks (orbit index: radius R_B, inclination deg): "
        + ", ".join(
            f"{p} ({f['radius_rb']:.2f}, {f['inclination_deg']:.0f})"
            for p, f in zip(d["greedy_picks"], d["greedy_families"], strict=True)
        ),
        "",
    ]
    write_text(folder / "README.md", lines)

    fig, ax = plt.subplots(figsize=(6, 4))
    picks = np.arange(1, len(d["greedy_logdet"]) + 1)
    for r in d["random_logdet"]:
        ax.plot(picks, r, color="0.6", lw=1)
    ax.plot(picks, d["greedy_logdet"], color="C3", lw=2.5, label="D-optimal (greedy)")
    ax.plot([], [], color="0.6", label="random orders")
    ax.set_xlabel("orbits selected")
    ax.set_ylabel("log det of accumulated information")
    ax.legend()
    fig.tight_layout()
    save_figure(fig, folder / "d_optimal.png")
