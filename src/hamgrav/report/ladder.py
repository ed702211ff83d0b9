"""The deep-ladder experiment's README and figure, from results.json."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from .tables import format_range

__all__ = ["ladder_readme", "ladder_figure"]


def _rows_of(agg: dict) -> list[str]:
    """The models of the ladder, in their order of appearance."""
    return list(dict.fromkeys(key.split("/")[0] for key in agg))


def _rungs_of(agg: dict, row: str) -> list[str]:
    return [key.split("/", 1)[1] for key in agg if key.split("/")[0] == row]


def _rung_text(rung: str, rung_texts: dict[str, str]) -> str:
    base, _, weight = rung.partition(":")
    text = rung_texts.get(base, base)
    return f"{text}, harmonic weight {weight}" if weight else text


def ladder_readme(report: dict, rung_texts: dict[str, str]) -> list[str]:
    """The README body: one table per model, rung by rung (median and range)."""
    agg = report["aggregate"]["ladder"]
    config = report["config"]
    reps = report["repetitions"]
    first = reps[0]
    lines = [
        f"{first['n_arcs']} arcs of {first['body']} and {first['n_descents']} tracked "
        f"descents per repetition, the deep experiment's campaign (samples "
        f"{first['radius_rb']['min']:.2f}-{first['radius_rb']['max']:.2f} R_B). Rung (a) is "
        f"fitted on {first['oracle_points']['deep']} surface-following points inside R_B "
        f"(drawn from those at {', '.join(f'{h:g}' for h in config['oracle_altitudes_m'])} "
        "m), rung (b) on the "
        f"{first['oracle_points']['arcs']} true sample positions of the arcs"
        + (
            f", rung (b+e) on those and the descents' {first['oracle_points']['descents']}"
            if "descents" in first["oracle_points"]
            else ""
        )
        + ". Errors are "
        "relative errors of the perturbing potential (1 = no correction): `on its points` an "
        "oracle fit's error on the points it was fitted on, `exterior` the mean "
        f"over the shells {', '.join(f'{s:g}' for s in config['shells_rb'])} R_B, `deep` the "
        f"{config['altitude_m']:g} m surface-following set inside R_B, then its radial bins.",
        "",
    ]
    for row in _rows_of(agg):
        rungs = _rungs_of(agg, row)
        bins = [k for k in agg[f"{row}/{rungs[0]}"] if k.startswith("bin ")]
        lines += [
            f"### {row}",
            "",
            "| rung | on its points | exterior | deep | " + " | ".join(b[4:] for b in bins) + " |",
            "|---|---|---|---|" + "---|" * len(bins),
        ]
        for rung in rungs:
            stats = agg[f"{row}/{rung}"]
            keys = ("on_points", "exterior", "deep", *bins)
            cells = [format_range(stats.get(k), "{:.3g}") for k in keys]
            lines.append(f"| {_rung_text(rung, rung_texts)} | " + " | ".join(cells) + " |")
        lines.append("")
    return lines


def ladder_figure(report: dict) -> Figure:
    """Error against r / R_B per rung: deep bins (their centres) and exterior shells."""
    agg = report["aggregate"]["ladder"]
    config = report["config"]
    edges = np.asarray(config["deep_bins_rb"], float)
    centres = list((edges[:-1] + edges[1:]) / 2)
    shells = list(config["shells_rb"])
    rows = _rows_of(agg)
    fig = Figure(figsize=(5.2 * len(rows), 4.2))
    axes = fig.subplots(1, len(rows), squeeze=False)[0]
    for ax, row in zip(axes, rows, strict=True):
        for rung in _rungs_of(agg, row):
            stats = agg[f"{row}/{rung}"]
            bins = [k for k in stats if k.startswith("bin ")]
            deep = [stats[b]["median"] for b in bins]
            exterior = stats["exterior"]["median"]
            x = centres[: len(deep)] + [float(np.mean(shells))]
            y = [np.nan if v is None else v for v in [*deep, exterior]]
            ax.plot(x, y, marker="o", label=rung)
        ax.axvline(1.0, color="grey", ls="--", lw=0.8)
        ax.axhline(1.0, color="black", lw=0.6)
        ax.set_yscale("log")
        ax.set_xlabel("r / R_B (deep bins; last point: mean over the exterior shells)")
        ax.set_ylabel("relative error of the perturbing potential")
        ax.set_title(row)
        ax.legend(fontsize=7)
    fig.tight_layout()
    return fig
