"""The anomalies experiment's README and its maps figure, from results.json and the first
repetition's maps."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from .paper import met, with_paper
from .tables import format_range

__all__ = ["maps_figure", "anomalies_readme"]


def maps_figure(maps: dict) -> Figure:
    """Three maps with one colour scale: true residual, network, best SH."""
    panels = [k for k in maps if k not in ("lon_deg", "lat_deg")]
    fig = Figure(figsize=(4.0 * len(panels), 3.2))
    axes = fig.subplots(1, len(panels), squeeze=False)[0]
    lim = float(np.max(np.abs(maps["truth"])))
    extent = (maps["lon_deg"][0], maps["lon_deg"][-1], maps["lat_deg"][0], maps["lat_deg"][-1])
    for ax, name in zip(axes, panels, strict=True):
        image = ax.imshow(
            maps[name], origin="lower", extent=extent, cmap="RdBu_r", vmin=-lim, vmax=lim
        )
        ax.set_title(f"{name}: residual over the prior" if name == "truth" else name)
        ax.set_xlabel("longitude [deg]")
    axes[0].set_ylabel("latitude [deg]")
    fig.colorbar(image, ax=list(axes), shrink=0.8, label="potential [canonical]")
    return fig


_FRAME_SENTENCE = {
    "shape": "Body frame: origin at the shape's constant-density centroid (what imaging "
    "gives), so the anomalies' pull on the centre of mass stays in the residual as a degree-1 "
    "part that SH, which start at degree 2, cannot represent.",
    "centre-of-mass": "Body frame: origin at the truth's centre of mass, so the residual has "
    "no degree-1 part.",
}


def anomalies_readme(report: dict, paper: dict[str, tuple], statements: dict) -> list[str]:
    """README lines: the field-error table next to the paper's (``paper``: row -> errors on
    the shells), the Kaula choices, and the paper's ``statements`` checked (the network's
    bound on every shell; the best SH option's error over the network's)."""
    reps = report["repetitions"]
    agg = report["aggregate"]["field_error"]
    cfg = report["config"]
    sets = list(next(iter(agg.values())))
    first = reps[0]
    lines = [
        f"{first['n_arcs']} arcs of {cfg['body']} ({cfg['orbits']} orbits, "
        f"{cfg['radius_rb'][0]}-{cfg['radius_rb'][1]} R_B); truth: "
        f"{first['anomalies'].get('anomaly_count')} anomalies of "
        f"{100 * first['anomalies'].get('anomaly_mass_fraction', 0):.1f} % of the mass at "
        f"{first['anomalies'].get('anomaly_depth_ratio')} of the local surface radius. "
        + _FRAME_SENTENCE[cfg.get("frame", "centre-of-mass")]
        + " Every model is a residual on the constant-density shape prior. Relative field "
        "error of the whole model against the perturbing potential (1 = no correction); the "
        "paper's values in brackets. `-kaula`: alpha chosen by the truth's 1.05 R_B error (the "
        "paper's protocol); `-kaula-holdout`: by the cost on 12 % held-out arcs (no truth).",
        "",
        "| model | " + " | ".join(sets) + " |",
        "|---|" + "---|" * len(sets),
    ]
    for name, errs in agg.items():
        cells = [format_range(errs[k], "{:.3f}") for k in sets]
        if name in paper:
            cells = [with_paper(c, p, "{:g}") for c, p in zip(cells, paper[name], strict=False)]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines += ["", "Kaula alpha chosen, per repetition:", ""]
    for name in first["kaula_alpha"]:
        lines.append(f"- {name}: " + ", ".join(f"{r['kaula_alpha'][name]:g}" for r in reps))
    lines += ["", "## Against the paper", ""]
    net = [r["field_error"]["shape+network"] for r in reps]
    worst = {k: float(np.median([e[k] for e in net])) for k in sets}
    ratio = [
        min(
            min(r["field_error"][n][k] for n in r["field_error"] if "+sh" in n)
            / r["field_error"]["shape+network"][k]
            for k in sets
        )
        for r in reps
    ]
    bound = statements["network_every_shell"]
    lines += [
        "- network residual, median over repetitions: "
        + ", ".join(f"{k} {v:.3f}" for k, v in worst.items())
        + f" (target <= {bound:g} on every shell: {met(max(worst.values()) <= bound)}).",
        f"- best SH option of any degree and regularisation over the network, on the shell "
        f"where it comes closest: {np.median(ratio):.1f}x (median; {min(ratio):.1f}-"
        f"{max(ratio):.1f}x over {len(reps)} repetition(s); target >= "
        f"{statements['best_sh_over_network']:g}x).",
        "",
        "Wall time per repetition [s]: " + ", ".join(f"{r['wall_s']:.0f}" for r in reps),
    ]
    return lines
