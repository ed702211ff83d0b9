"""Where a continual fit's time goes: warm-started stages against fits from scratch.

Fits network-best stage by stage on the continual campaign (the experiment's own config:
`hamgrav experiment continual`), warm and from scratch, in this process, and prints per
stage the iterations, the wall time and how much of it went to forming normal equations
(variational propagation and A^T A) and to plain propagations (trial and validation
costs); then the total wall time warm / scratch. Timings are of this process alone: run it
on an idle machine.

    python bench/continual_stages.py --body itokawa --seed 0
"""

from __future__ import annotations

import argparse
import collections
import time

import numpy as np

from hamgrav.core.problem import ArcProblem
from hamgrav.experiments.common import network_best
from hamgrav.experiments.continual import ContinualExperimentConfig
from hamgrav.fit.continual import fit_continual
from hamgrav.fit.estimator import NETWORK_WARM_SOLVER, GravityEstimator
from hamgrav.sim.campaign import run_campaign

TIMED = ("normal_equations", "cost")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--body", default="itokawa")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    spent: dict[str, float] = collections.defaultdict(float)
    calls: collections.Counter = collections.Counter()
    for name in TIMED:
        method = getattr(ArcProblem, name)

        def timed(self, *a, _method=method, _name=name, **k):
            start = time.perf_counter()
            try:
                return _method(self, *a, **k)
            finally:
                spent[_name] += time.perf_counter() - start
                calls[_name] += 1

        setattr(ArcProblem, name, timed)

    config = ContinualExperimentConfig(body=args.body)
    truth, arcs = run_campaign(config.campaign(args.seed))
    groups = np.array_split(np.arange(config.orbits), config.stages)
    arriving = [arcs.arcs_of(g) for g in groups]
    totals = {}
    print("mode     stage  arcs  iterations  wall [s]  normal eq. [s] (calls)  plain [s] (calls)")
    for mode in ("warm", "scratch"):
        settings = network_best(
            config.hidden,
            config.lm_iterations,
            harmonic=config.harmonic,
            warm_solver=NETWORK_WARM_SOLVER,
        )
        estimator = GravityEstimator(body=truth.body, seed=args.seed, **settings)
        spent.clear()
        calls.clear()

        def on_stage(record, mode=mode):
            print(
                f"{mode:8s} {record.stage + 1:5d} {record.n_arcs:5d} "
                f"{record.result.iterations:11d} {record.result.wall_s:9.1f} "
                f"{spent['normal_equations']:15.1f} ({calls['normal_equations']:3d})  "
                f"{spent['cost']:9.1f} ({calls['cost']:3d})"
            )
            spent.clear()
            calls.clear()

        records = fit_continual(
            estimator, arcs, arriving, warm_start=mode == "warm", on_stage=on_stage
        )
        totals[mode] = sum(r.result.wall_s for r in records)
    print(
        f"total wall: warm {totals['warm']:.1f} s, scratch {totals['scratch']:.1f} s, "
        f"warm / scratch {totals['warm'] / totals['scratch']:.3f}"
    )


if __name__ == "__main__":
    main()
