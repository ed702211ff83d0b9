"""README and figure of the continual-learning experiment."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from .tables import format_range

__all__ = ["continual_readme", "continual_figure"]

#: The issue's targets for continual fits of the network.
TARGETS = (
    ("worst_stage_step", "warm stage k r1.2 / stage k-1 (never more than 5 % worse)", 1.05),
    ("final_warm_over_scratch", "final r1.2, warm / scratch (within 10 %)", 1.10),
    ("wall_ratio", "total wall time, warm / scratch", 0.5),
)


def continual_readme(report: dict) -> list[str]:
    """README lines of a continual report."""
    reps = report["repetitions"]
    first = reps[0]
    models = list(first["summary"])
    lines = [
        f"{first['n_arcs']} arcs of {first['body']} arriving in {len(first['stages'])} stages "
        "of whole orbits. At each stage every model is fitted to all arcs so far, warm-started "
        "from the previous stage (warm) or from its initialisation (scratch). Validation arcs "
        "are drawn once per arriving stage and never trained on. Field errors are relative "
        "errors of the perturbing potential (1 = no correction).",
        "",
        "First repetition, stage by stage:",
        "",
        "| model | stage | arcs | r1.2 warm | r1.2 scratch | h30m warm | h30m scratch | "
        "iterations warm / scratch | wall warm / scratch [s] | outcome warm |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name in models:
        for k, st in enumerate(first["stages"]):
            w, s = st["warm"][name], st["scratch"][name]
            lines.append(
                f"| {name} | {k + 1} | {st['n_arcs']} | {w['r1.2']:.3f} | {s['r1.2']:.3f} | "
                f"{w['h30m']:.3f} | {s['h30m']:.3f} | {w['iterations']} / {s['iterations']} | "
                f"{w['wall_s']:.1f} / {s['wall_s']:.1f} | {w['outcome']} |"
            )
    agg = report["aggregate"]["summary"]
    lines += ["", "## Against the targets", ""]
    lines += ["| model | measure | ours | target | met |", "|---|---|---|---|---|"]
    for name in models:
        for key, text, bound in TARGETS:
            met = sum(r["summary"][name][key] <= bound for r in reps)
            lines.append(
                f"| {name} | {text} | {format_range(agg[name][key], '{:.2f}')} | <= {bound} | "
                f"{met} of {len(reps)} |"
            )
    lines += [
        "",
        "The paper states that continual refits are warm-started from the previous stage and",
        "sets no numbers for this comparison; the targets above are ours.",
    ]
    return lines


def continual_figure(report: dict) -> Figure:
    """r1.2 against arcs received, warm and scratch, per model: the median over the
    repetitions, with the min-max band of the warm fits when there are several."""
    reps = report["repetitions"]
    fig = Figure(figsize=(6.5, 4.2))
    ax = fig.add_subplot()
    n = [s["n_arcs"] for s in reps[0]["stages"]]
    for i, name in enumerate(reps[0]["summary"]):
        for mode, style in (("warm", "-o"), ("scratch", "--s")):
            values = np.array([[s[mode][name]["r1.2"] for s in rep["stages"]] for rep in reps])
            ax.plot(
                n,
                np.median(values, axis=0),
                style,
                color=f"C{i}",
                label=f"{name}, {mode}",
            )
            if mode == "warm" and len(reps) > 1:
                ax.fill_between(
                    n, values.min(axis=0), values.max(axis=0), color=f"C{i}", alpha=0.15, lw=0
                )
    ax.set_yscale("log")
    ax.set_xlabel("arcs received")
    ax.set_ylabel("relative field error at 1.2 R_B")
    ax.set_xticks(np.asarray(n))
    if len(reps) > 1:
        ax.set_title(
            f"median over {len(reps)} repetitions (band: min-max of the warm fits)", fontsize=9
        )
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig
