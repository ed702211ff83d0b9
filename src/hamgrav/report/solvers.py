"""The README of the solver comparison (tables of fits, continual stages, D-optimal picks)."""

from __future__ import annotations

from .tables import range_row

__all__ = ["solvers_readme"]


def solvers_readme(report: dict) -> list[str]:
    """README lines of a solver-comparison report."""
    first = report["repetitions"][0]
    agg = report["aggregate"]["field_error"]
    sets = list(next(iter(agg.values())))
    lines = [
        f"{first['n_arcs']} arcs of {first['body']} ({first['interior']}). Every fit uses the",
        "same arcs and the same exact sensitivities; network fits share the initialisation and",
        "the 12 % validation hold-out. Field errors are relative errors of the perturbing",
        "potential (1 = no correction).",
        "",
        "| fit | solver | cost | params | outcome | iterations | wall [s] | "
        + " | ".join(sets)
        + " |",
        "|---|---|---|---|---|---|---|" + "---|" * len(sets),
    ]
    for key, f in first["fits"].items():
        n_params = f.get("n_params", "")
        weighting = "weighted" if f["weighted"] else "unweighted"
        cells = [key, f["solver"], weighting, n_params, f["outcome"], f["iterations"]]
        lines.append(range_row([*cells, f"{f['wall_s']:.1f}"], agg[key], sets))
    lines += [
        "",
        "## Continual learning: warm start vs scratch (first repetition)",
        "",
        "Validation arcs are drawn once per arriving stage and never trained on later.",
        "",
        "| model | stage | arcs | iterations warm | iterations scratch | wall warm [s] | "
        "wall scratch [s] | outcome warm | outcome scratch | r1.2 warm | r1.2 scratch |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for label, out in first["continual"].items():
        for w, s in zip(out["warm"], out["scratch"], strict=True):
            lines.append(
                f"| {label} | {w['stage'] + 1} | {w['n_arcs']} | {w['iterations']} | "
                f"{s['iterations']} | {w['wall_s']:.2f} | {s['wall_s']:.2f} | {w['outcome']} | "
                f"{s['outcome']} | {w['r1.2']:.3f} | {s['r1.2']:.3f} |"
            )
    d = first["d_optimal"]
    lines += [
        "",
        "## D-optimal selection vs random orders (first repetition)",
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
    ]
    return lines
