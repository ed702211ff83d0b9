"""Throughput of the cost gradient A^T r (what first-order training needs): the adjoint
(the costate from the state transition matrix, core.propagation.adjoint_gradient) against
the forward sensitivities (the design matrix contracted with the residuals), and the full normal
equations, on the 112 Itokawa arcs of the paper's descent geometry (16 orbits 1.2-2.0 R_B,
10-80 deg, 7 arcs of 40 samples at 14 s; a cheap 100-mascon truth). Each figure is the best
of ``--repeat`` calls after a first call that compiles; the two gradients are compared.

    python bench/gradient.py [--hidden 24,24 16,16] [--adjoint-tol 1e-8] [--repeat 3] [--json]
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
from hamgrav.core import propagation
from hamgrav.core.model import Model
from hamgrav.core.problem import ArcProblem
from hamgrav.core.terms import NeuralPotential, PointMass
from hamgrav.sim.tracking import TrackingConfig, orbit_grid, simulate_orbits


def _best(call, repeat: int) -> float:
    call()  # compiles, and warms the thread copies
    best = np.inf
    for _ in range(repeat):
        start = time.perf_counter()
        call()
        best = min(best, time.perf_counter() - start)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hidden", nargs="+", default=["24,24", "16,16"])
    parser.add_argument("--adjoint-tol", type=float, default=propagation.ADJOINT_TOLERANCE)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--json", action="store_true", help="one JSON object per network")
    args = parser.parse_args()
    propagation.ADJOINT_TOLERANCE = args.adjoint_tol
    truth = build_truth(load_body("itokawa"), "head-tail", n_mascons=100, seed=0)
    arcs = simulate_orbits(
        truth, orbit_grid(16, (1.2, 2.0), (10.0, 80.0)), TrackingConfig(arcs_per_orbit=7), seed=0
    )
    rows = []
    for hidden in args.hidden:
        term = NeuralPotential(tuple(int(h) for h in hidden.split(",")))
        model = Model((PointMass(),), term)
        theta = term.initial_params(0)
        adjoint = ArcProblem(model, arcs, gradient_method="adjoint")
        forward = ArcProblem(model, arcs, gradient_method="forward")
        g_adj = adjoint.gradient(theta)[1]
        g_fwd = forward.gradient(theta)[1]
        times = {
            "adjoint": _best(lambda p=adjoint, t=theta: p.gradient(t), args.repeat),
            "forward": _best(lambda p=forward, t=theta: p.gradient(t), args.repeat),
            "normal_equations": _best(
                lambda p=forward, t=theta: p.normal_equations(t), args.repeat
            ),
        }
        row = {
            "hidden": hidden,
            "n_params": term.n_params,
            "n_arcs": arcs.n_arcs,
            "adjoint_tol": args.adjoint_tol,
            **{f"{k}_arcs_per_s": round(arcs.n_arcs / v, 1) for k, v in times.items()},
            "gradient_relative_difference": float(
                np.abs(g_adj - g_fwd).max() / np.abs(g_fwd).max()
            ),
            "simd_batch": hy.recommended_simd_size(),
            "threads": os.cpu_count(),
        }
        rows.append(row)
        if args.json:
            print(json.dumps(row), flush=True)
    if not args.json:
        print(
            f"{arcs.n_arcs} Itokawa arcs x {arcs.samples_per_arc} samples, SIMD batch "
            f"{hy.recommended_simd_size()}, {os.cpu_count()} threads, adjoint tolerance "
            f"{args.adjoint_tol:g}; arcs/s (best of {args.repeat})"
        )
        print(
            f"{'network':<9} {'params':>7} {'adjoint':>9} {'forward':>9} {'A^T A':>9} "
            f"{'adj/fwd':>8} {'|g_adj - g_fwd|':>16}"
        )
        for r in rows:
            print(
                f"{r['hidden']:<9} {r['n_params']:>7} {r['adjoint_arcs_per_s']:>9.0f} "
                f"{r['forward_arcs_per_s']:>9.0f} {r['normal_equations_arcs_per_s']:>9.0f} "
                f"{r['adjoint_arcs_per_s'] / r['forward_arcs_per_s']:>8.2f} "
                f"{r['gradient_relative_difference']:>16.1e}"
            )


if __name__ == "__main__":
    main()
