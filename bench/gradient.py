"""Throughput of the cost gradient A^T r (what first-order training needs): the adjoint
(the costate from the state transition matrix, core.propagation.adjoint_gradient) against
the forward sensitivities (the design matrix contracted with the residuals), and the full normal
equations, on the 112 Itokawa arcs of the paper's descent geometry (16 orbits 1.2-2.0 R_B,
10-80 deg, 7 arcs of 40 samples at 14 s; a cheap 100-mascon truth). Each figure is the best
of ``--repeat`` calls after a first call that compiles; the two gradients are compared.
``--tol`` is the tolerance of the states' propagation, which gives the costs (the fit's
1e-12 by default; the JAX peer's figures are at 1e-10).
``--workers N`` also times the adjoint on a LocalCluster of N single-threaded worker processes
(``hamgrav.fit.distributed``: the arcs split into chunks held by the workers; threads of one
process share the GIL between heyoka's calls, processes do not), and ``--copies K`` repeats
the 112 arcs K times. ``--sh 16`` adds SH models (parameters 1e-4), ``--threads 1`` times one
thread, and ``--orbits``, ``--arcs-per-orbit`` and ``--cadence`` change the tracking (longer
arcs take several Taylor steps).

    python bench/gradient.py [--hidden 24,24 16,16] [--tol 1e-10] [--adjoint-tol 1e-8] [--repeat 3]
                             [--workers 2] [--copies 4] [--json] [--export-peer arcs.npz]
                             [--sh 16] [--threads 1] [--orbits 8 --arcs-per-orbit 2 --cadence 300]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import time

import heyoka as hy
import numpy as np

from hamgrav.bodies.catalogue import load_body
from hamgrav.bodies.interiors import build_truth
from hamgrav.core import propagation
from hamgrav.core.model import DEFAULT_FIT_TOLERANCE, Model
from hamgrav.core.problem import ArcProblem
from hamgrav.core.terms import NeuralPotential, PointMass, SphericalHarmonics
from hamgrav.experiments.runner import dask_client
from hamgrav.fit.distributed import DistributedArcProblem
from hamgrav.sim.tracking import TrackingConfig, orbit_grid, simulate_orbits


def _best(call, repeat: int) -> float:
    call()  # compiles, and warms the thread copies
    best = np.inf
    for _ in range(repeat):
        start = time.perf_counter()
        call()
        best = min(best, time.perf_counter() - start)
    return best


def _row(arcs, name: str, term, theta, args, client) -> dict:
    """The figures of one learnable term (a network "24,24", or "sh16")."""
    model = Model((PointMass(),), term)
    threads = args.threads or None
    adjoint = ArcProblem(model, arcs, gradient_method="adjoint", tol=args.tol, threads=threads)
    forward = ArcProblem(model, arcs, gradient_method="forward", tol=args.tol, threads=threads)
    g_adj = adjoint.gradient(theta)[1]
    g_fwd = forward.gradient(theta)[1]
    times = {
        "adjoint": _best(lambda: adjoint.gradient(theta), args.repeat),
        "forward": _best(lambda: forward.gradient(theta), args.repeat),
        "normal_equations": _best(lambda: forward.normal_equations(theta), args.repeat),
    }
    row = {
        "hidden": name,
        "n_params": term.n_params,
        "n_arcs": arcs.n_arcs,
        "tol": args.tol,
        "adjoint_tol": args.adjoint_tol,
        "gradient_relative_difference": float(np.abs(g_adj - g_fwd).max() / np.abs(g_fwd).max()),
        "simd_batch": hy.recommended_simd_size(),
        "threads": args.threads or os.cpu_count(),
    }
    if client is not None:
        cluster = DistributedArcProblem(
            model, arcs, client=client, gradient_method="adjoint", tol=args.tol
        )
        g_cluster = cluster.gradient(theta)[1]
        times["cluster_adjoint"] = _best(lambda: cluster.gradient(theta), args.repeat)
        row["workers"] = args.workers
        row["cluster_relative_difference"] = float(
            np.abs(g_cluster - g_adj).max() / np.abs(g_adj).max()
        )
    row.update({f"{k}_arcs_per_s": round(arcs.n_arcs / v, 1) for k, v in times.items()})
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hidden", nargs="*", default=["24,24", "16,16"])
    parser.add_argument(
        "--tol",
        type=float,
        default=DEFAULT_FIT_TOLERANCE,
        help="tolerance of the states' propagation (the costs): the fit's by default; the "
        "issue's comparison with the peer is at 1e-10",
    )
    parser.add_argument("--adjoint-tol", type=float, default=propagation.ADJOINT_TOLERANCE)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--json", action="store_true", help="one JSON object per network")
    parser.add_argument("--workers", type=int, default=0, help="LocalCluster worker processes")
    parser.add_argument("--copies", type=int, default=1, help="the 112 arcs, repeated")
    parser.add_argument(
        "--sh", type=int, nargs="*", default=[], help="also SH models of these degrees"
    )
    parser.add_argument("--threads", type=int, default=0, help="threads (0: all cores)")
    parser.add_argument("--orbits", type=int, default=16)
    parser.add_argument("--arcs-per-orbit", type=int, default=7)
    parser.add_argument("--cadence", type=float, default=14.0, help="sample spacing [s]")
    parser.add_argument(
        "--export-peer",
        metavar="NPZ",
        help="also write the arcs' initial states and sample times (canonical) for "
        "bench/peer_gradient.py, which times the JAX peer on the same arcs",
    )
    args = parser.parse_args()
    if args.workers and args.adjoint_tol != propagation.ADJOINT_TOLERANCE:
        parser.error("--adjoint-tol applies in this process only, not with --workers")
    propagation.ADJOINT_TOLERANCE = args.adjoint_tol
    truth = build_truth(load_body("itokawa"), "head-tail", n_mascons=100, seed=0)
    arcs = simulate_orbits(
        truth,
        orbit_grid(args.orbits, (1.2, 2.0), (10.0, 80.0)),
        TrackingConfig(arcs_per_orbit=args.arcs_per_orbit, cadence_s=args.cadence),
        seed=0,
    )
    arcs = arcs.subset(np.tile(np.arange(arcs.n_arcs), args.copies))
    if args.export_peer:
        np.savez(args.export_peer, states0=arcs.states[:, 0], times=arcs.times)
    with dask_client(args.workers) if args.workers else contextlib.nullcontext() as client:
        rows = []
        for hidden in args.hidden:
            term = NeuralPotential(tuple(int(h) for h in hidden.split(",")))
            rows.append(_row(arcs, hidden, term, term.initial_params(0), args, client))
        for degree in args.sh:
            term = SphericalHarmonics(degree, 1.0)
            theta = np.full(term.n_params, 1e-4)
            rows.append(_row(arcs, f"sh{degree}", term, theta, args, client))
    if args.json:
        for row in rows:
            print(json.dumps(row), flush=True)
    if not args.json:
        print(
            f"{arcs.n_arcs} Itokawa arcs x {arcs.samples_per_arc} samples, SIMD batch "
            f"{hy.recommended_simd_size()}, {args.threads or os.cpu_count()} threads, tolerance "
            f"{args.tol:g} "
            f"(adjoint's transition matrix {args.adjoint_tol:g}); arcs/s (best of {args.repeat})"
        )
        cluster = f"adjoint x{args.workers}" if args.workers else ""
        print(
            f"{'network':<9} {'params':>7} {'adjoint':>9} {cluster:>11} {'forward':>9} "
            f"{'A^T A':>9} {'adj/fwd':>8} {'|g_adj - g_fwd|':>16}"
        )
        for r in rows:
            on_cluster = f"{r['cluster_adjoint_arcs_per_s']:>11.0f}" if args.workers else " " * 11
            print(
                f"{r['hidden']:<9} {r['n_params']:>7} {r['adjoint_arcs_per_s']:>9.0f} "
                f"{on_cluster} {r['forward_arcs_per_s']:>9.0f} "
                f"{r['normal_equations_arcs_per_s']:>9.0f} "
                f"{r['adjoint_arcs_per_s'] / r['forward_arcs_per_s']:>8.2f} "
                f"{r['gradient_relative_difference']:>16.1e}"
            )
        if args.workers:
            worst = max(r["cluster_relative_difference"] for r in rows)
            print(f"the cluster's gradient against the in-process one: {worst:.1e} (relative)")


if __name__ == "__main__":
    main()
