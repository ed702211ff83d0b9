"""Single networks from different initialisations against their ensemble, per campaign draw.

For each seed: the descent experiment's 112-arc Itokawa campaign; ``--members`` networks fitted
one by one with the network-best LM settings from initialisation seeds seed, seed + 1, ...
(the same held-out arcs); then the ensembles of the first 2, 3, ... of them (the mean of the
members, :class:`hamgrav.core.terms.NeuralPotential` with ``members``). Prints, per model, the
lowest validation cost (single networks), the r1.2 and h30m field errors and the descent misses
[m] against the truth; and which single network the validation cost would have picked. This
is the measurement behind network-best being an ensemble rather than the best-validation
restart.

    python bench/network_members.py --seeds 0-7 [--members 3] [--max-iter 30]
                                    [--harmonic W] [--json]

``--max-iter`` caps each single fit's LM iterations (network-best's own cap by default): the
measurement behind the cost-quality trade of the ensemble (fit time scales with members x
iterations). ``--harmonic`` sets the weight of the harmonic penalty of every single fit
(network-best's own by default; 0 turns it off).
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace

import numpy as np

from hamgrav.core.model import TRUTH_TOLERANCE, Model
from hamgrav.core.terms import NeuralPotential
from hamgrav.experiments.common import errors_of, sets_for, simulate
from hamgrav.experiments.descent import DescentExperimentConfig
from hamgrav.experiments.runner import RunContext
from hamgrav.fit.estimator import GravityEstimator, preset
from hamgrav.sim.descent import DescentConfig, descend, miss_statistics, release_states


def parse_seeds(text: str) -> list[int]:
    """Seeds from "0-7" (a range, both ends included) or "2,7" (a list)."""
    if "-" in text:
        lo, hi = (int(v) for v in text.split("-"))
        return list(range(lo, hi + 1))
    return [int(v) for v in text.split(",")]


def one_draw(
    seed: int, members: int, max_iter: int | None = None, harmonic: float | None = None
) -> list[dict]:
    """Rows (plain data) for one campaign draw."""
    config = DescentExperimentConfig()
    truth, arcs = simulate(config, RunContext(seed=seed))
    sets = sets_for(truth, (1.2,), (config.altitude_m,), seed)
    descents = DescentConfig(count=config.descents)
    release, _ = release_states(truth.body, descents, seed=seed)
    truth_td = descend(truth.model, [], release, truth.body, descents, tol=TRUTH_TOLERANCE)
    length_m = truth.body.units.length_m

    def evaluate(model, params) -> dict:
        stats = miss_statistics(
            truth_td, descend(model, params, release, truth.body, descents), length_m
        )
        return {
            **errors_of(model, params, truth, sets),
            "median_m": stats["median_m"],
            "p90_m": stats["p90_m"],
            "worst_m": stats["worst_m"],
            "landed": stats["landed"],
        }

    settings = preset("network-best", members=1)
    if harmonic is not None:
        settings["harmonic"] = harmonic or None
    if max_iter is not None:
        settings["solver"] = replace(settings["solver"], max_iter=max_iter)
    rows, blocks = [], []
    for k in range(members):
        est = GravityEstimator(body=truth.body, seed=seed, **settings)
        model, _ = est.build_model(arcs)
        # the solver is passed explicitly: an ``init`` alone would select the warm-start
        # solver (10 iterations) instead of network-best's own
        init = est.initial_params(model, arcs, seed=seed + k)
        est.fit(arcs, init=init, solver=settings["solver"])
        blocks.append(est.params_)
        rows.append(
            {
                "seed": seed,
                "model": f"single {k}",
                "validation_cost": float(min(est.result_.history["validation"])),
                "wall_s": round(est.result_.wall_s, 1),
                **evaluate(est.model_, est.params_),
            }
        )
    picked = int(np.argmin([r["validation_cost"] for r in rows]))
    rows.append({**rows[picked], "model": "best validation", "picked": picked})
    single = est.model_.learnable
    for n in range(2, members + 1):
        term = NeuralPotential(single.hidden, single.scale, single.envelope_radius, members=n)
        model = Model(est.model_.known, term)
        rows.append(
            {
                "seed": seed,
                "model": f"ensemble {n}",
                "wall_s": round(sum(r["wall_s"] for r in rows[:n]), 1),
                **evaluate(model, np.concatenate(blocks[:n])),
            }
        )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0-7", help="campaign seeds: 0-7 or 2,7")
    parser.add_argument("--members", type=int, default=3)
    parser.add_argument("--max-iter", type=int, default=None, help="LM iterations per network")
    parser.add_argument(
        "--harmonic", type=float, default=None, help="harmonic penalty weight (0: off)"
    )
    parser.add_argument("--json", action="store_true", help="one JSON object per row")
    args = parser.parse_args()
    start = time.perf_counter()
    every = []
    for seed in parse_seeds(args.seeds):
        rows = one_draw(seed, args.members, args.max_iter, args.harmonic)
        every += rows
        for r in rows:
            if args.json:
                print(json.dumps(r))
            else:
                print(
                    f"seed {seed} {r['model']:<16} r1.2 {r['r1.2']:.3f} h30m {r['h30m']:.3f} "
                    f"median {r['median_m']:5.2f} m  p90 {r['p90_m']:5.1f} m  "
                    f"worst {r['worst_m']:6.1f} m  landed {r['landed']}  fit {r['wall_s']:.0f} s",
                    flush=True,
                )
    if not args.json:
        print("\nacross seeds: median [min - max]")
        for name in dict.fromkeys(r["model"] for r in every):
            sel = [r for r in every if r["model"] == name]
            for key in ("r1.2", "median_m", "wall_s"):
                v = np.array([r[key] for r in sel], float)
                print(f"  {name:<16} {key:<8} {np.median(v):.3f} [{v.min():.3f} - {v.max():.3f}]")
        print(f"({time.perf_counter() - start:.0f} s)")


if __name__ == "__main__":
    main()
