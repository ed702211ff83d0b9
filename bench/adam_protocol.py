"""The paper-protocol network (Adam) over learning rates and step counts, per campaign draw.

For each seed: the descent experiment's 112-arc Itokawa campaign, then the preset "network"
(Adam, unweighted canonical residuals, 24-arc batches, cosine schedule, 12 % hold-out) for
every (peak learning rate, steps) pair; prints the r1.2 and h30m field errors, the descent
miss statistics [m], the step of the best validation cost and the wall time [s]. This is the
measurement behind the preset's learning rate and step count.

    python bench/adam_protocol.py --seeds 2,4,7 --learning-rates 3e-3,1e-2,3e-2 --steps 1500
"""

from __future__ import annotations

import argparse
import itertools
import json
import time

import numpy as np

from hamgrav.core.model import TRUTH_TOLERANCE
from hamgrav.experiments.common import errors_of, sets_for, simulate
from hamgrav.experiments.descent import DescentExperimentConfig
from hamgrav.experiments.runner import RunContext
from hamgrav.fit.estimator import GravityEstimator, preset
from hamgrav.sim.descent import DescentConfig, descend, miss_statistics, release_states


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="2,4,7")
    parser.add_argument("--learning-rates", default="3e-3,1e-2,3e-2")
    parser.add_argument("--steps", default="1500")
    parser.add_argument("--json", action="store_true", help="one JSON object per row")
    args = parser.parse_args()
    seeds = [int(v) for v in args.seeds.split(",")]
    rates = [float(v) for v in args.learning_rates.split(",")]
    steps = [int(v) for v in args.steps.split(",")]
    config = DescentExperimentConfig()
    start = time.perf_counter()
    rows = []
    for seed in seeds:
        truth, arcs = simulate(config, RunContext(seed=seed))
        sets = sets_for(truth, (1.2,), (config.altitude_m,), seed)
        descents = DescentConfig(count=config.descents)
        release, _ = release_states(truth.body, descents, seed=seed)
        truth_td = descend(truth.model, [], release, truth.body, descents, tol=TRUTH_TOLERANCE)
        for rate, n in itertools.product(rates, steps):
            settings = preset("network", learning_rate=rate, adam_steps=n)
            est = GravityEstimator(body=truth.body, seed=seed, **settings).fit(arcs)
            tds = descend(est.model_, est.params_, release, truth.body, descents)
            stats = miss_statistics(truth_td, tds, truth.body.units.length_m)
            row = {
                "seed": seed,
                "learning_rate": rate,
                "steps": n,
                **errors_of(est.model_, est.params_, truth, sets),
                "median_m": stats["median_m"],
                "worst_m": stats["worst_m"],
                "landed": stats["landed"],
                "best_step": est.result_.best_iteration,
                "wall_s": round(est.result_.wall_s, 1),
            }
            rows.append(row)
            if args.json:
                print(json.dumps(row), flush=True)
            else:
                print(
                    f"seed {seed} lr {rate:g} steps {n}: r1.2 {row['r1.2']:.3f} "
                    f"h30m {row['h30m']:.3f} median {row['median_m']:.2f} m worst "
                    f"{row['worst_m']:.1f} m landed {row['landed']} best step "
                    f"{row['best_step']} ({row['wall_s']} s)",
                    flush=True,
                )
    if not args.json:
        print("\nacross seeds: median [worst] of r1.2 and of the median miss [m]")
        for rate, n in itertools.product(rates, steps):
            sel = [r for r in rows if r["learning_rate"] == rate and r["steps"] == n]
            r12 = np.array([r["r1.2"] for r in sel])
            miss = np.array([r["median_m"] for r in sel])
            print(
                f"  lr {rate:g} steps {n}: r1.2 {np.median(r12):.3f} [{r12.max():.3f}], "
                f"median miss {np.median(miss):.2f} [{miss.max():.2f}]"
            )
        print(f"({time.perf_counter() - start:.0f} s)")


if __name__ == "__main__":
    main()
