"""The interiors experiment's README and figure, from results.json."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from .tables import format_range

__all__ = ["interiors_readme", "residuals_figure"]


def _ratio_text(values: list[float]) -> str:
    if len(values) == 1:
        return f"{values[0]:.2f}"
    return f"{np.median(values):.2f} ({min(values):.2f}-{max(values):.2f})"


def interiors_readme(report: dict, paper: dict) -> list[str]:
    """README lines: per truth, the field-error table (median and range over repetitions),
    then the paper's statements checked; ``paper``: the paper's numbers
    (:data:`hamgrav.experiments.interiors.PAPER`)."""
    reps = report["repetitions"]
    cfg = report["config"]
    agg = report["aggregate"]["field_error"]
    lines = [
        f"{reps[0]['body']}: {cfg['orbits']} orbits x {cfg['arcs_per_orbit']} arcs of 40 samples "
        f"({cfg['radius_rb'][0]}-{cfg['radius_rb'][1]} R_B, {cfg['inclination_deg'][0]:g}-"
        f"{cfg['inclination_deg'][1]:g} deg) per truth. Relative field error of the whole "
        "model (known part plus learned term) against the perturbing potential "
        "(1 = no correction); `shape` is the constant-density shape prior alone, its error is "
        "the fraction of the perturbing field the shape misses.",
    ]
    for interior in cfg["truths"]:
        names = [k.split("/", 1)[1] for k in agg if k.startswith(interior + "/")]
        sets = list(agg[f"{interior}/shape"])
        lines += ["", f"### Truth: {interior}", "", "| model | " + " | ".join(sets) + " |"]
        lines.append("|---|" + "---|" * len(sets))
        for name in names:
            cells = [format_range(agg[f"{interior}/{name}"][k], "{:.3f}") for k in sets]
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines += ["", "## Against the paper", ""]
    shells = [k for k in reps[0]["truths"][cfg["truths"][0]]["missed_fraction"]]
    for interior in cfg["truths"]:
        fe = [r["truths"][interior]["field_error"] for r in reps]
        missed = (
            [min(f["shape"][k] for k in shells) for f in fe],
            [max(f["shape"][k] for k in shells) for f in fe],
        )
        better_prior = sum(
            all(f["shape+network"][k] < f["shape"][k] for k in f["shape"]) for f in fe
        )
        scratch_ratio = [f["network-scratch"]["r1.05"] / f["shape+network"]["r1.05"] for f in fe]
        prior_ratio = [min(f["shape"][k] / f["shape+network"][k] for k in shells) for f in fe]
        lines.append(
            f"- {interior}: the shape misses {100 * min(missed[0]):.0f}-"
            f"{100 * max(missed[1]):.0f} % of the perturbing field on the shells "
            f"(paper, head/tail: {paper['missed_fraction']}); the residual network beats the "
            f"prior on every set in {better_prior} of {len(fe)}; at 1.05 R_B it is "
            f"{_ratio_text(scratch_ratio)}x better than the network from scratch (paper: "
            f"{paper['residual_over_scratch_r1.05']:g}x) and on the shells at least "
            f"{_ratio_text(prior_ratio)}x better than the prior (paper, void: "
            f"{paper['void_residual_over_prior']})."
        )
    if "head-tail" in cfg["truths"]:
        r105 = [r["truths"]["head-tail"]["field_error"]["shape+network"]["r1.05"] for r in reps]
        scratch = [
            r["truths"]["head-tail"]["field_error"]["network-scratch"]["r1.05"] for r in reps
        ]
        prior = [r["truths"]["head-tail"]["field_error"]["shape"]["r1.05"] for r in reps]
        quoted = {k: v["r1.05"] for k, v in paper["head-tail"].items()}
        lines.append(
            f"- head-tail at 1.05 R_B: residual network {_ratio_text(r105)} (target <= "
            f"{quoted['shape+network']:g}), network from scratch {_ratio_text(scratch)} (paper "
            f"{quoted['network-scratch']:.3f}), prior alone {_ratio_text(prior)} (paper "
            f"{quoted['shape']:.3f})."
        )
    lines += [
        "",
        "Wall time per repetition [s]: " + ", ".join(f"{r['wall_s']:.0f}" for r in reps),
    ]
    return lines


def residuals_figure(report: dict) -> Figure:
    """Field error against shell radius, prior / scratch / residual, one panel per truth
    (first repetition)."""
    first = report["repetitions"][0]
    truths = list(first["truths"])
    fig = Figure(figsize=(4.2 * len(truths), 3.8))
    axes = fig.subplots(1, len(truths), squeeze=False)[0]
    for ax, interior in zip(axes, truths, strict=True):
        fe = first["truths"][interior]["field_error"]
        shells = [k for k in fe["shape"] if k.startswith("r")]
        radii = [float(k[1:]) for k in shells]
        for name, style in (
            ("shape", "s-"),
            ("network-scratch", "o--"),
            ("shape+network", "^-"),
        ):
            ax.plot(radii, [fe[name][k] for k in shells], style, label=name)
        ax.set_yscale("log")
        ax.set_xlabel("shell radius [R_B]")
        ax.set_title(f"truth: {interior}")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("relative field error")
    axes[0].legend()
    fig.tight_layout()
    return fig
