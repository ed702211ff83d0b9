"""Wall time of one network-best fit of the descent campaign's 112 Itokawa arcs, per draw.

The measurement behind the target "one network-best fit of 112 arcs, 2 cores <= 30 s": each
draw's arcs (the descent experiment's campaign, seeded) fitted by ``GravityEstimator`` with
the ``network-best`` preset, as ``hamgrav fit`` does. The first fit of the process includes
the compilation of the integrators, as a first ``hamgrav fit`` would; later draws reuse them.
Run it on an otherwise idle machine: the figure is a wall time on all cores.

    python bench/network_best_fit.py [--seeds 0-3] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import time

from hamgrav.experiments.common import simulate
from hamgrav.experiments.descent import DescentExperimentConfig
from hamgrav.experiments.runner import RunContext
from hamgrav.fit.estimator import GravityEstimator, preset
from network_members import parse_seeds  # this folder's sibling script


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0-3", help="campaign draws, e.g. 0-3 or 0,4")
    parser.add_argument("--json", action="store_true", help="one JSON object per draw")
    args = parser.parse_args()
    config = DescentExperimentConfig()
    for k, seed in enumerate(parse_seeds(args.seeds)):
        truth, arcs = simulate(config, RunContext(seed=seed))
        estimator = GravityEstimator(body=truth.body, seed=seed, **preset("network-best"))
        t = time.perf_counter()
        estimator.fit(arcs)
        wall = time.perf_counter() - t
        result = estimator.result_
        row = {
            "seed": seed,
            "n_arcs": arcs.n_arcs,
            "wall_s": round(wall, 2),
            "compiled_in_this_fit": k == 0,
            "iterations": result.iterations,
            "outcome": result.outcome.value,
            "threads": os.cpu_count(),
        }
        if args.json:
            print(json.dumps(row), flush=True)
        else:
            note = " (compilation included)" if k == 0 else ""
            print(
                f"seed {seed}: network-best fit of {arcs.n_arcs} arcs on {os.cpu_count()} "
                f"cores: {wall:.1f} s{note}, {result.iterations} LM iterations, "
                f"{result.outcome.value}",
                flush=True,
            )


if __name__ == "__main__":
    main()
