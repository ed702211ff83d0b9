"""Wall time of predicted arcs + exact sensitivities, per model, on a 112-arc campaign.

Campaign geometry of the paper's Itokawa descent experiment: 16 orbits (1.2-2.0 R_B,
10-80 deg), 7 arcs of 40 samples at 14 s. Compilation is timed apart (first use of the
compiled variational integrator); propagation is the best of ``--repeat`` runs over all arcs,
on all cores (SIMD batches of arcs over threads), at the tolerance of the fit's propagations
that carry sensitivities (``--tol``, default the fit's); "AtA+Atr" is the
whole normal-equation assembly (propagation included).

    python bench/sensitivities.py [--body itokawa] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import time

import heyoka as hy
import numpy as np

from hamgrav.bodies.catalogue import load_body
from hamgrav.bodies.interiors import build_truth
from hamgrav.core.model import DEFAULT_SENSITIVITY_TOLERANCE, Model, compiled_integrators
from hamgrav.core.problem import ArcProblem
from hamgrav.core.terms import NeuralPotential, PointMass, SphericalHarmonics
from hamgrav.sim.tracking import TrackingConfig, orbit_grid, simulate_orbits


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--body", default="itokawa")
    parser.add_argument("--interior", default="head-tail")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--tol", type=float, default=DEFAULT_SENSITIVITY_TOLERANCE)
    parser.add_argument("--json", action="store_true", help="one JSON object per model")
    args = parser.parse_args()

    t0 = time.perf_counter()
    truth = build_truth(load_body(args.body), args.interior, seed=0)
    arcs = simulate_orbits(
        truth, orbit_grid(16, (1.2, 2.0), (10.0, 80.0)), TrackingConfig(arcs_per_orbit=7), seed=0
    )
    setup_s = time.perf_counter() - t0
    r_b = truth.body.brillouin_radius
    models = {
        "network-721": NeuralPotential((24, 24)),
        "network-353": NeuralPotential((16, 16)),
        **{f"sh{L}": SphericalHarmonics(L, r_b) for L in (4, 8, 12, 16)},
    }
    rows = []
    for name, term in models.items():
        model = Model((PointMass(),), term)
        t = time.perf_counter()
        compiled_integrators(model, variational=True, tol=args.tol)
        compile_s = time.perf_counter() - t
        problem = ArcProblem(model, arcs, sensitivity_tol=args.tol)
        theta = (
            term.initial_params(0) if isinstance(term, NeuralPotential) else np.zeros(term.n_params)
        )
        problem.predict(theta, sensitivities=True)  # warm the thread copies
        best = np.inf
        for _ in range(args.repeat):
            t = time.perf_counter()
            problem.predict(theta, sensitivities=True)
            best = min(best, time.perf_counter() - t)
        t = time.perf_counter()
        problem.normal_equations(theta)
        normal_s = time.perf_counter() - t
        row = {
            "model": name,
            "n_params": term.n_params,
            "compile_s": round(compile_s, 3),
            "propagate_s": round(best, 4),
            "arcs_per_s": round(arcs.n_arcs / best, 1),
            "normal_equations_s": round(normal_s, 3),
            "n_arcs": arcs.n_arcs,
            "tol": args.tol,
            "simd_batch": hy.recommended_simd_size(),
            "threads": os.cpu_count(),
        }
        rows.append(row)
        if args.json:
            print(json.dumps(row), flush=True)
    if not args.json:
        print(
            f"{args.body} ({args.interior}), {arcs.n_arcs} arcs x {arcs.samples_per_arc} "
            f"samples, tol {args.tol:g}, SIMD batch {hy.recommended_simd_size()}, "
            f"{os.cpu_count()} threads; campaign set-up {setup_s:.1f} s"
        )
        print(
            f"{'model':<12} {'params':>7} {'compile [s]':>12} {'all arcs [s]':>13} "
            f"{'arcs/s':>9} {'AtA+Atr [s]':>12}"
        )
        for r in rows:
            print(
                f"{r['model']:<12} {r['n_params']:>7} {r['compile_s']:>12.2f} "
                f"{r['propagate_s']:>13.3f} {r['arcs_per_s']:>9.1f} "
                f"{r['normal_equations_s']:>12.3f}"
            )


if __name__ == "__main__":
    main()
