"""The README and figures of the uncertainty experiment: the calibration table, the
covariance of each fit, the network's checks, and error beside sigma."""

from __future__ import annotations

import numpy as np
from matplotlib.colors import LogNorm
from matplotlib.figure import Figure

from ..bodies.evaluation import set_label
from .tables import format_range, range_row

__all__ = ["uncertainty_readme", "maps_figure", "calibration_figure", "verdict"]

#: What an honest sigma gives for Gaussian errors: fractions within 1 and 2 sigma and the
#: median |error| / sigma.
HONEST = (0.683, 0.954, 0.674)


def verdict(within_1: float, within_2: float, median_z: float) -> str:
    """One word on a calibration row: "honest" when the median |error| / sigma lies within
    a factor 1.5 of 0.674 and at least 85 % of the points are within 2 sigma, "optimistic"
    (sigma too small) when the median ratio is above that band, "pessimistic" below it,
    "mixed" otherwise (median fine, tails heavy)."""
    low, high = HONEST[2] / 1.5, HONEST[2] * 1.5
    if median_z > high:
        return "optimistic"
    if median_z < low:
        return "pessimistic"
    return "honest" if within_2 >= 0.85 else "mixed"


def _calibration_table(table: dict, models: list[str], sets: list[str]) -> list[str]:
    lines = [
        "| model | set | within 1 sigma | within 2 sigma | median abs(error) / sigma | "
        "RMS error [m^2/s^2] | RMS sigma [m^2/s^2] | verdict |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for model in models:
        for s in sets:
            row = table.get(f"{model} {s}")
            if row is None:
                continue
            cells = [
                format_range(row["within_1_sigma"], "{:.2f}"),
                format_range(row["within_2_sigma"], "{:.2f}"),
                format_range(row["median_abs_z"], "{:.2f}"),
                format_range(row["rms_error_m2_s2"], "{:.2g}"),
                format_range(row["rms_sigma_m2_s2"], "{:.2g}"),
                verdict(
                    row["within_1_sigma"]["median"],
                    row["within_2_sigma"]["median"],
                    row["median_abs_z"]["median"],
                ),
            ]
            lines.append(f"| {model} | {set_label(s)} | " + " | ".join(cells) + " |")
    return lines


def uncertainty_readme(report: dict) -> list[str]:
    """README lines of an uncertainty report (see :mod:`hamgrav.experiments.uncertainty`)."""
    reps, agg, cfg = report["repetitions"], report["aggregate"], report["config"]
    first = reps[0]
    models = list(first["covariance"])
    sets = list(next(iter(first["field_error"].values())))
    best = first["fits"].get("network-best", {})
    lines = [
        f"{first['n_arcs']} orbital arcs of {cfg['body']} ({cfg['interior']} interior; "
        f"{cfg['orbits']} orbits x {cfg['arcs_per_orbit']} arcs of 40 samples at 14 s, "
        "sigma_r = 5 cm). SH "
        + ", ".join(str(d) for d in cfg["sh_degrees"])
        + " (LM, all arcs) and network-best (the mean of "
        f"{len(best.get('members', [])) or 1} networks of {cfg['hidden']} hidden units, LM, "
        f"harmonic penalty {cfg['harmonic']:g}, {best.get('n_validation', 0)} arcs held out) "
        "fitted to the same arcs.",
        "",
        "sigma_V(q) = sqrt(g^T C g), g = dV/dtheta compiled from the same expressions as the "
        "dynamics, C the formal covariance of the fitted parameters (hamgrav.fit.covariance): "
        "white noise on every sample plus each arc's anchor noise carried along the arc, "
        "through the fit's normal equations; the pseudo-inverse over the directions the arcs "
        f"constrain (eigenvalues above {cfg['thresholds'][0]:g} of the largest); scaled by "
        "the a posteriori variance factor (the fit's residual sum over its expected value "
        "under the stated noise). For network-best: the data-only normal matrix of each member "
        "(the harmonic penalty's rows are left out), the members' cross-covariances included "
        f"(they share the noise), the mean's 1/{len(best.get('members', [])) or 1} in g. "
        "`network-best+penalty` is the same fit "
        "with the harmonic penalty's Gauss-Newton rows J^T J in each member's normal matrix "
        "(as a Kaula weight would be for SH): the noise response of the penalised fit, and "
        "what `hamgrav evaluate --uncertainty` reports for a network fitted with the penalty.",
        "",
        "## Calibration",
        "",
        "The error is V_model - V_truth of the perturbing potential at each point of the set. "
        f"An honest sigma puts {HONEST[0]:.2f} of the points within 1 sigma, {HONEST[1]:.2f} "
        f"within 2 sigma, and the median abs(error) / sigma at {HONEST[2]:.2f}; verdict: "
        "'honest' when the median ratio is within a factor 1.5 of that and at least 0.85 are "
        "within 2 sigma, 'optimistic' when sigma is too small, 'pessimistic' when too large.",
        "",
        *_calibration_table(agg["calibration"], models, sets),
        "",
        "Formal covariance of each fit (first repetition): directions constrained by the "
        "arcs (rank) of the parameters per member, and the a posteriori variance factor "
        "(1: the residuals are as large as the stated noise makes them):",
        "",
        "| model | parameters per member | rank | variance factor |",
        "|---|---|---|---|",
    ]
    for name, c in first["covariance"].items():
        lines.append(
            f"| {name} | {c['parameters_per_member']} | {'/'.join(map(str, c['ranks']))} | "
            + " / ".join(f"{f:.3g}" for f in c["variance_factors"])
            + " |"
        )
    if agg.get("redraws"):
        lines += [
            "",
            "### The noise response: refits to noise redraws",
            "",
            f"Each model fitted again to {cfg['redraws']} noise redraws of the same true arcs "
            "(same orbits, initialisations and held-out arcs): the RMS over the set of the "
            "pointwise standard deviation of the fitted perturbing potential over the fit and "
            "its refits (what the noise alone moves; no truth needed), beside the RMS formal "
            "sigma (a posteriori). The ratio is 1 when the linearised noise propagation "
            f"describes the fit (with {cfg['redraws'] + 1} fits the spread itself is uncertain "
            "by some 30-50 %):",
            "",
            "| model | set | RMS refit spread [m^2/s^2] | RMS formal sigma [m^2/s^2] | "
            "sigma / spread |",
            "|---|---|---|---|---|",
        ]
        for model in models:
            for s in sets:
                row = agg["redraws"].get(f"{model} {s}")
                if row is not None:
                    lines.append(
                        f"| {model} | {set_label(s)} | "
                        f"{format_range(row['rms_spread_m2_s2'], '{:.2g}')} | "
                        f"{format_range(row['rms_sigma_m2_s2'], '{:.2g}')} | "
                        f"{format_range(row['sigma_over_spread'], '{:.2f}')} |"
                    )
    lines += [
        "",
        "### Without the variance factor (a priori: the stated noise)",
        "",
        *_calibration_table(agg["calibration_a_priori"], models, sets),
        "",
        "### The rank threshold (first repetition; a posteriori)",
        "",
        "Fractions within 1 / 2 sigma per set at each relative eigenvalue threshold of the "
        "pseudo-inverse (the rank kept per member in brackets):",
        "",
        "| model | threshold (rank) | " + " | ".join(set_label(s) for s in sets) + " |",
        "|---|---|" + "---|" * len(sets),
    ]
    for name, scan in first["thresholds"].items():
        for t, row in scan.items():
            cells = [
                f"{row[s]['within_1_sigma']:.2f} / {row[s]['within_2_sigma']:.2f}" for s in sets
            ]
            ranks = "/".join(map(str, row["ranks"]))
            lines.append(f"| {name} | {t} ({ranks}) | " + " | ".join(cells) + " |")
    net = first.get("network") or {}
    if net:
        lines += [
            "",
            "### network-best: the members (first repetition)",
            "",
            "RMS sigma from the members' block-diagonal covariance (as if each member had its "
            "own noise draw) over the full one: "
            + ", ".join(
                f"{set_label(s)} {v:.2f}" for s, v in net["block_diagonal_sigma_ratio"].items()
            )
            + ".",
            "",
            "The members' spread (standard deviation / sqrt(members): what the "
            "initialisations leave uncertain, which the formal sigma does not see) as a sigma, "
            "alone and added in quadrature to the formal sigma:",
            "",
            "| sigma | set | within 1 sigma | within 2 sigma | median abs(error) / sigma | "
            "RMS sigma [m^2/s^2] |",
            "|---|---|---|---|---|---|",
        ]
        for label, key in (("spread", "spread"), ("formal + spread", "formal_plus_spread")):
            for s, row in net[key].items():
                lines.append(
                    f"| {label} | {set_label(s)} | {row['within_1_sigma']:.2f} | "
                    f"{row['within_2_sigma']:.2f} | {row['median_abs_z']:.2f} | "
                    f"{row['rms_sigma_m2_s2']:.2g} |"
                )
    lines += [
        "",
        "Relative field error (1 = no correction):",
        "",
        "| model | " + " | ".join(set_label(s) for s in sets) + " |",
        "|---|" + "---|" * len(sets),
    ]
    for name, errs in agg["field_error"].items():
        lines.append(range_row([name], errs, sets))
    lines += ["", "Fit outcomes (first repetition):", ""]
    for name, f in first["fits"].items():
        lines.append(
            f"- {name}: {f['solver']}, {f['outcome']}, {f['iterations']} iterations, "
            f"{f['wall_s']:.1f} s"
        )
    lines += ["", "Wall time per repetition [s]: " + ", ".join(f"{r['wall_s']:.0f}" for r in reps)]
    return lines


def _lon_lat(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r = np.linalg.norm(points, axis=1)
    return np.degrees(np.arctan2(points[:, 1], points[:, 0])), np.degrees(
        np.arcsin(points[:, 2] / r)
    )


def maps_figure(data: dict, scale: float, title: str) -> Figure:
    """|error| and sigma_V [m^2/s^2] side by side on the 1.2 R_B shell (else the first set),
    longitude x latitude, one row per model with one logarithmic colour scale."""
    sets = data["sets"]
    name = "r1.2" if "r1.2" in sets else next(iter(sets))
    entry = sets[name]
    models = [k for k in entry if k != "points"]
    lon, lat = _lon_lat(entry["points"])
    fig = Figure(figsize=(10, 2.9 * len(models)), layout="constrained")
    axes = fig.subplots(len(models), 2, squeeze=False)
    for row, model in zip(axes, models, strict=True):
        err, sigma = (scale * np.abs(v) for v in entry[model])
        both = np.concatenate([err, sigma])
        positive = both[both > 0]
        norm = LogNorm(vmin=np.percentile(positive, 1), vmax=positive.max())
        for ax, values, label in ((row[0], err, "|error|"), (row[1], sigma, "formal sigma")):
            dots = ax.scatter(lon, lat, c=np.maximum(values, norm.vmin), s=14, norm=norm)
            ax.set_title(f"{model}: {label}", fontsize=9)
            ax.set_xlim(-180, 180)
            ax.set_ylim(-90, 90)
            ax.set_xlabel("longitude [deg]")
            ax.set_ylabel("latitude [deg]")
        fig.colorbar(dots, ax=list(row), label="[m^2/s^2]")
    fig.suptitle(f"{title}: {set_label(name)}")
    return fig


def calibration_figure(data: dict, scale: float, title: str) -> Figure:
    """|error| against sigma_V [m^2/s^2] at every evaluation point, one panel per model,
    coloured by set, with the 1-sigma (solid) and 2-sigma (dashed) lines."""
    sets = data["sets"]
    models = [k for k in next(iter(sets.values())) if k != "points"]
    fig = Figure(figsize=(4.2 * len(models), 4.2))
    axes = fig.subplots(1, len(models), squeeze=False)[0]
    for ax, model in zip(axes, models, strict=True):
        lo, hi = np.inf, 0.0
        for name, entry in sets.items():
            err, sigma = (scale * np.abs(v) for v in entry[model])
            ax.scatter(sigma, np.maximum(err, 1e-30), s=3, alpha=0.4, label=set_label(name))
            lo = min(lo, float(np.min(sigma[sigma > 0], initial=np.inf)))
            hi = max(hi, float(sigma.max()), float(err.max()))
        line = np.array([lo, hi])
        ax.plot(line, line, "k-", lw=1)
        ax.plot(line, 2 * line, "k--", lw=1)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_ylim(bottom=max(lo * 1e-2, 1e-30))
        ax.set_xlabel("formal sigma [m^2/s^2]")
        ax.set_ylabel("|error| [m^2/s^2]")
        ax.set_title(model)
    axes[0].legend(fontsize=7, markerscale=3)
    fig.suptitle(title)
    fig.tight_layout()
    return fig
