"""Cost of one network-best LM iteration and peak memory as the arcs grow, in-process and on a
Dask LocalCluster (hamgrav.fit.distributed).

One iteration of a network-best fit is dominated by the normal equations A^T A, A^T r at the
current parameters over the training arcs (propagation with exact sensitivities, then the
sums 64 arcs at a time); this script times exactly that call of the fit's problem, after a
first call that compiles (in-process) or also ships the chunks and builds their problems on
the workers (cluster). Every (arcs, mode) runs in a fresh process so that its peak resident
memory is its own: in-process, the process's; on the cluster, the client's and each worker's.

Arcs: the paper's Itokawa geometry (orbits 1.2-2.0 R_B, 10-80 deg, 7 arcs of 40 samples at
14 s a orbit) under a cheap truth (100 mascons: the truth does not enter the timing); the
network is network-best's member, [24, 24] tanh units (721 parameters).

    python bench/scaling.py [--arcs 112,448,1792,4096] [--workers 2] [--body itokawa] [--json]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def one(arcs_file: str, n_arcs: int, workers: int, repeat: int) -> dict:
    """Time the normal equations on the first ``n_arcs`` arcs of ``arcs_file``."""
    from hamgrav.core.problem import ArcProblem
    from hamgrav.experiments.runner import dask_client
    from hamgrav.fit.distributed import DistributedArcProblem
    from hamgrav.fit.estimator import GravityEstimator
    from hamgrav.io.arcs import load_arcs

    arcs = load_arcs(arcs_file)
    arcs = arcs.subset(np.arange(n_arcs))
    est = GravityEstimator("network", hidden=(24, 24), harmonic=None)
    model, _ = est.build_model(arcs)
    theta = est.initial_params(model, arcs)
    out = {"arcs": n_arcs, "parameters": int(theta.size), "workers": workers}
    with dask_client(workers) if workers else contextlib.nullcontext() as client:
        if client is None:
            problem = ArcProblem(model, arcs)
        else:
            problem = DistributedArcProblem(model, arcs, client=client)
        t0 = time.perf_counter()
        problem.normal_equations(theta)
        out["first_call_s"] = time.perf_counter() - t0
        times = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            problem.normal_equations(theta)
            times.append(time.perf_counter() - t0)
        out["iteration_s"] = min(times)
        out["arcs_per_s"] = n_arcs / out["iteration_s"]
        out["client_peak_mb"] = _peak_mb()
        if client is not None:
            peaks = client.run(_peak_mb)
            out["worker_peak_mb"] = max(peaks.values())
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--arcs", default="112,448,1792,4096")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--body", default="itokawa")
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--one", nargs=3, help=argparse.SUPPRESS)  # ARCS_FILE N WORKERS
    args = parser.parse_args()
    if args.one:
        print(json.dumps(one(args.one[0], int(args.one[1]), int(args.one[2]), args.repeat)))
        return

    from hamgrav.bodies.catalogue import load_body
    from hamgrav.bodies.interiors import build_truth
    from hamgrav.io.arcs import save_arcs
    from hamgrav.sim.tracking import TrackingConfig, orbit_grid, simulate_orbits

    sizes = [int(n) for n in args.arcs.split(",")]
    orbits = -(-max(sizes) // 7)
    t0 = time.perf_counter()
    truth = build_truth(load_body(args.body), "head-tail", n_mascons=100, seed=0)
    arcs = simulate_orbits(
        truth, orbit_grid(orbits, (1.2, 2.0), (10.0, 80.0)), TrackingConfig(), seed=0
    )
    print(f"simulated {arcs.n_arcs} arcs in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        path = save_arcs(arcs, os.path.join(folder, "arcs.h5"))
        for n in sizes:
            for workers in (0, args.workers):
                cmd = [sys.executable, __file__, "--one", str(path), str(n), str(workers)]
                cmd += ["--repeat", str(args.repeat)]
                done = subprocess.run(cmd, capture_output=True, text=True, check=True)
                row = json.loads(done.stdout.strip().splitlines()[-1])
                rows.append(row)
                if args.json:
                    print(json.dumps(row), flush=True)
                else:
                    mode = f"LocalCluster x{workers}" if workers else "in-process"
                    memory = f"client {row['client_peak_mb']:.0f} MB"
                    if "worker_peak_mb" in row:
                        memory += f", worker {row['worker_peak_mb']:.0f} MB"
                    print(
                        f"{n:5d} arcs  {mode:16s}  iteration {row['iteration_s']:7.2f} s  "
                        f"{row['arcs_per_s']:6.0f} arcs/s  per arc {1e3 / row['arcs_per_s']:.2f}"
                        f" ms  peak {memory}",
                        flush=True,
                    )


if __name__ == "__main__":
    main()
