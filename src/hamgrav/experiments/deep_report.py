"""README and figures of the deep-region experiment (:mod:`hamgrav.experiments.deep`): the
aggregate next to the paper's numbers, the stage-by-stage exterior error, the geometry, the
error by radial bin and the equatorial maps."""

from __future__ import annotations

import re

import matplotlib
import numpy as np
from matplotlib.colors import LogNorm
from matplotlib.figure import Figure

from ..report.figures import orbits_and_radii_figure
from .runner import format_range

__all__ = ["PAPER", "deep_readme", "geometry_figure", "bins_figure", "maps_figure"]

#: The paper's numbers (67P, 126 arcs, one run): SH 8 exterior error (shells 1.2-1.7 R_B);
#: 300 m above the surface inside the Brillouin sphere, SH 4 / 8 / 12; the network's deepest
#: and worst radial bin; median error over the patches where SH is worse than no correction.
PAPER = {
    "sh8_exterior": 0.012,
    "deep": {"sh4": 0.65, "sh8": 1.34, "sh12": 45.0},
    "network_deepest_bin": 0.29,
    "network_worst_bin": 0.51,
    "patch_median_sh": 2.7,
    "patch_median_network": 0.27,
}


def _sh_rows(models) -> list[str]:
    """The SH rows among ``models``, by degree."""
    return sorted((m for m in models if re.fullmatch(r"sh\d+", m)), key=lambda m: int(m[2:]))


def _network_row(models) -> str:
    """The network row among ``models`` (the one row that is not SH)."""
    return next(m for m in models if not re.fullmatch(r"sh\d+", m))


def _cell(summary: dict, model: str, key: str, fmt: str = "{:.3g}") -> str:
    return format_range(summary.get(model, {}).get(key), fmt)


def _count(reps: list[dict], test) -> str:
    """``n of N``: repetitions where ``test(rep)`` holds (a missing value fails)."""
    return f"{sum(bool(test(r)) for r in reps)} of {len(reps)}"


def _le(value, bound) -> bool:
    return value is not None and value <= bound


def _gt(value, bound) -> bool:
    return value is not None and value > bound


def deep_readme(report: dict) -> list[str]:
    """README lines of a deep-region report."""
    reps = report["repetitions"]
    cfg = report["config"]
    first = reps[0]
    summary = report["aggregate"]["summary"]
    bins_agg = report["aggregate"]["deep_bins"]
    models = list(first["summary"])
    sh, net = _sh_rows(models), _network_row(models)
    labels = list(first["deep_bin_points"])
    # the deepest bin is the first that holds points (the summary's "deepest_bin")
    deepest = next((k for k, n in first["deep_bin_points"].items() if n), labels[0])
    shells = ", ".join(f"{s:g}" for s in cfg["shells_rb"])
    lines = [
        f"{first['n_arcs']} arcs of {cfg['body']} ({cfg['interior']} interior, "
        f"{cfg['n_mascons']} truth mascons): {cfg['orbits']} orbits on a grid of start radii "
        f"{cfg['radius_rb'][0]:g}-{cfg['radius_rb'][1]:g} R_B x inclinations "
        f"{cfg['inclination_deg'][0]:g}-{cfg['inclination_deg'][1]:g} deg, "
        f"{cfg['arcs_per_orbit']} arcs of 40 samples at 14 s each; orbits dipping below "
        f"{cfg['min_radius_rb']:g} R_B are redrawn. The orbits arrive in "
        f"{len(first['stages'])} stages in a fixed order (orbits by stage: "
        + "; ".join(",".join(map(str, s["orbits"])) for s in first["stages"])
        + "); every model is fitted on the identical arcs, each stage warm-started from the "
        f"previous one: SH of degree {', '.join(m[2:] for m in sh)} (LM) and `{net}` (the "
        f"network-best configuration, hidden layers {','.join(map(str, cfg['hidden']))}"
        + (
            f", with the harmonic penalty of weight {cfg['harmonic']:g}: its Laplacian, scaled "
            "by (r / R_w)^5, pushed to zero at 1500 points outside the body"
            if cfg.get("harmonic")
            else ""
        )
        + "). "
        "Errors are relative errors of the perturbing potential (1 = no correction): "
        f"`exterior` is the mean over the shells {shells} R_B, `deep` the "
        f"{cfg['altitude_m']:g} m surface-following set inside the Brillouin sphere "
        "(r < R_B), and the bins split that set by r / R_B.",
        "",
        "Tracked samples, r / R_B:",
        "",
        "| seed | samples | min | q1 | median | q3 | max | below 0.96 R_B |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in reps:
        q = r["radius_rb"]
        lines.append(
            f"| {r['seed']} | {q['n_samples']} | {q['min']:.3f} | {q['q1']:.3f} | "
            f"{q['median']:.3f} | {q['q3']:.3f} | {q['max']:.3f} | {q['below_floor']} |"
        )
    lines += ["", "## Against the paper", ""]
    lines += _paper_rows(reps, summary, sh, net, deepest, cfg["altitude_m"])
    lines += [
        "",
        "## Final models",
        "",
        "| model | exterior | deep | " + " | ".join(labels) + " | patch median |",
        "|---|---|---|" + "---|" * len(labels) + "---|",
    ]
    for m in models:
        cells = [_cell(summary, m, "exterior"), _cell(summary, m, "deep")]
        cells += [format_range(bins_agg.get(m, {}).get(k), "{:.3g}") for k in labels]
        cells.append(_cell(summary, m, "patch_median"))
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "Points of the surface-following set per bin: "
        + ", ".join(f"{k} {n}" for k, n in first["deep_bin_points"].items())
        + ". Patches: the points of the equatorial map (outside the body) where SH "
        + " or SH ".join(str(d) for d in cfg["map_degrees"])
        + " is worse than no correction, "
        + ", ".join(
            f"{r['patch_points']} points"
            + (
                ""
                if r["patch_inside_brillouin"] is None
                else f" ({100 * r['patch_inside_brillouin']:.0f} % inside R_B)"
            )
            for r in reps
        )
        + " per repetition; the map error is pointwise, |V_model - V_true| / |V_true|, "
        "so it is large for every model where the true perturbing potential changes sign.",
        "",
        "Exterior error by stage (first repetition):",
        "",
        "| stage | arcs | " + " | ".join(models) + " |",
        "|---|---|" + "---|" * len(models),
    ]
    for k, st in enumerate(first["stages"]):
        cells = [format_range(_one(st["exterior_error"].get(m)), "{:.3g}") for m in models]
        lines.append(f"| {k + 1} | {st['n_arcs']} | " + " | ".join(cells) + " |")
    lines += ["", "Fits of the last stage (first repetition):", ""]
    for m in models:
        f = first["fits"][m]
        lines.append(
            f"- {m}: {f['solver']}, {f['outcome']}, {f['iterations']} iterations, "
            f"{f['wall_s']:.1f} s"
        )
    lines += [
        "",
        "Known differences of set-up (the paper does not fix them): the truth is "
        f"{cfg['n_mascons']} k-means mascons of the shape; the orbit grid, the redraw floor "
        "and the stage order are ours. The paper quotes one run; seeds change the truth's "
        "mascons, the orbits' node and phase, and the noise.",
        "",
        "Wall time per repetition [s]: " + ", ".join(f"{r['wall_s']:.0f}" for r in reps),
    ]
    return lines


def _one(value) -> dict | None:
    """A single value as a one-repetition summary (for :func:`format_range`)."""
    if value is None:
        return None
    return {"median": value, "min": value, "max": value, "n": 1}


def _paper_rows(reps, summary, sh, net, deepest, altitude) -> list[str]:
    """The paper's numbers (300 m above the surface) beside ours at ``altitude`` [m] (median,
    min-max over the repetitions)."""
    deep = PAPER["deep"]
    sh_deep = [d for d in deep if d in sh]
    rows = [
        "| quantity | ours | paper | target | met |",
        "|---|---|---|---|---|",
        f"| SH 8 exterior error, shells 1.2-1.7 R_B | {_cell(summary, 'sh8', 'exterior')} | "
        f"{PAPER['sh8_exterior']} | | |",
        "| SH "
        + " / ".join(d[2:] for d in deep)
        + f", {altitude:g} m set inside R_B | "
        + " / ".join(_cell(summary, d, "deep") for d in deep)
        + " | "
        + " / ".join(f"{v:g}" for v in deep.values())
        + " | | |",
        f"| SH 8 at {altitude:g} m worse than no correction | {_cell(summary, 'sh8', 'deep')} | "
        f"{deep['sh8']} | > 1 | "
        + (_count(reps, lambda r: _gt(r["summary"]["sh8"]["deep"], 1.0)) if "sh8" in sh else "-")
        + " |",
        f"| network, deepest bin ({deepest}) | {_cell(summary, net, 'deepest_bin')} | "
        f"{PAPER['network_deepest_bin']} | <= {PAPER['network_deepest_bin']} | "
        + _count(reps, lambda r: _le(r["summary"][net]["deepest_bin"], 0.29))
        + " |",
        f"| network, worst bin | {_cell(summary, net, 'worst_bin')} | "
        f"{PAPER['network_worst_bin']} | | |",
        "| patch median, SH 8 / 12 | "
        + " / ".join(_cell(summary, m, "patch_median") for m in ("sh8", "sh12"))
        + " | "
        f"{PAPER['patch_median_sh']} | | |",
        f"| patch median, network | {_cell(summary, net, 'patch_median')} | "
        f"{PAPER['patch_median_network']} | | |",
    ]
    if len(sh_deep) < len(deep):
        rows.append("")
        rows.append("(-: a degree the paper quotes was not fitted in this run.)")
    return rows


def geometry_figure(report: dict, artefacts: dict) -> Figure:
    """The arcs over the shape and the histogram of the samples' radii (first repetition),
    the deep-region bins shaded."""
    edges = report["config"]["deep_bins_rb"]
    first = report["repetitions"][0]
    return orbits_and_radii_figure(
        artefacts["vertices_m"],
        artefacts["faces"],
        artefacts["brillouin_radius_m"],
        artefacts["arc_positions_m"],
        artefacts["arc_trajectory"],
        shaded_rb=(edges[0], edges[-1]),
        title=f"{first['body']}: {first['n_arcs']} arcs (body frame, seed {first['seed']})",
    )


def bins_figure(report: dict) -> Figure:
    """Error by radial bin per model: the median over the repetitions, min-max shaded."""
    agg = report["aggregate"]["deep_bins"]
    edges = np.asarray(report["config"]["deep_bins_rb"], dtype=float)
    centres = 0.5 * (edges[:-1] + edges[1:])
    fig = Figure(figsize=(6.5, 4.2))
    ax = fig.add_subplot()
    for i, (model, by_bin) in enumerate(agg.items()):
        labels = list(report["repetitions"][0]["deep_bin_points"])
        stats = [by_bin.get(k, {}) for k in labels]
        med = np.array([np.nan if s.get("median") is None else s["median"] for s in stats])
        ax.plot(centres, med, "o-", color=f"C{i}", label=model)
        lo = np.array([np.nan if s.get("min") is None else s["min"] for s in stats])
        hi = np.array([np.nan if s.get("max") is None else s["max"] for s in stats])
        if np.any(hi > lo):
            ax.fill_between(centres, lo, hi, color=f"C{i}", alpha=0.2, lw=0)
    ax.axhline(1.0, color="k", ls=":", lw=1, label="no correction")
    ax.set_yscale("log")
    ax.set_xticks(centres, list(report["repetitions"][0]["deep_bin_points"]), fontsize=8)
    ax.set_xlabel(f"r / R_B, {report['config']['altitude_m']:g} m above the surface")
    ax.set_ylabel("relative field error")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def maps_figure(report: dict, artefacts: dict) -> Figure:
    """Pointwise error maps in the equatorial plane for the SH map degrees and the network,
    one logarithmic colour scale, the body's cross-section masked (first repetition)."""
    maps = artefacts["maps"]
    models = [f"sh{d}" for d in report["config"]["map_degrees"]]
    models.append(_network_row(maps["errors"]))
    axis = maps["axis_m"]
    n = len(axis)
    images = {m: maps["errors"][m].reshape(n, n) for m in models}
    finite = np.concatenate([v[np.isfinite(v) & (v > 0)] for v in images.values()])
    lo = min(float(np.percentile(finite, 1)), 0.1) if finite.size else 1e-3
    hi = max(float(np.percentile(finite, 99)), 10.0) if finite.size else 10.0
    cmap = matplotlib.colormaps["magma_r"].with_extremes(bad="0.6")
    fig = Figure(figsize=(4.2 * len(models), 4.0))
    axes = fig.subplots(1, len(models), squeeze=False)[0]
    extent = (axis[0], axis[-1], axis[0], axis[-1])
    r_b = artefacts["brillouin_radius_m"]
    angle = np.linspace(0, 2 * np.pi, 200)
    for ax, m in zip(axes, models, strict=True):
        masked = np.ma.masked_invalid(images[m])
        image = ax.imshow(
            masked,
            origin="lower",
            extent=extent,
            cmap=cmap,
            norm=LogNorm(vmin=lo, vmax=hi),
        )
        ax.contour(axis, axis, masked, levels=[1.0], colors="w", linewidths=0.6)
        ax.plot(r_b * np.cos(angle), r_b * np.sin(angle), "k--", lw=0.8)
        ax.set_title(m)
        ax.set_xlabel("x [m]")
        ax.set_aspect("equal")
    axes[0].set_ylabel("y [m]")
    fig.colorbar(image, ax=list(axes), shrink=0.8, label="|V_model - V_true| / |V_true|")
    return fig
