"""Figures, built as plain matplotlib ``Figure`` objects from plain data (lengths in metres).

No pyplot and no backend choice here: the figures work in scripts (saved by
:func:`hamgrav.report.writer.save_figure`), in notebooks (display the returned figure) and on
machines without a display.
"""

from __future__ import annotations

import matplotlib
import numpy as np
from matplotlib.figure import Figure

__all__ = [
    "campaign_figure",
    "orbits_and_radii_figure",
    "miss_cdf_figure",
    "logdet_figure",
    "residual_figure",
]


def _shape_and_arcs_3d(ax, vertices_m, faces, arc_positions_m, arc_trajectory) -> list:
    """The shape and the arcs (n, m, 3) [m] on a 3-D axis, one colour per trajectory; returns
    the colours (indexed by trajectory)."""
    ax.plot_trisurf(
        vertices_m[:, 0],
        vertices_m[:, 1],
        vertices_m[:, 2],
        triangles=faces,
        color="0.7",
        linewidth=0,
        alpha=0.6,
    )
    n_traj = int(np.max(arc_trajectory)) + 1 if len(arc_trajectory) else 1
    colours = [tuple(c) for c in matplotlib.colormaps["viridis"](np.linspace(0, 1, n_traj))]
    for q, k in zip(arc_positions_m, arc_trajectory, strict=True):
        ax.plot(q[:, 0], q[:, 1], q[:, 2], color=colours[int(k)], lw=1.5)
    return colours


def _cube_limits(ax, lim: float) -> None:
    """Equal [-lim, lim] limits [m] and labelled axes on a 3-D axis."""
    ax.set_xlim(-lim, lim)
    ax.set_ylim(-lim, lim)
    ax.set_zlim(-lim, lim)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")


def campaign_figure(
    vertices_m: np.ndarray,
    faces: np.ndarray,
    brillouin_radius_m: float,
    arc_positions_m: np.ndarray,
    arc_trajectory: np.ndarray,
    *,
    title: str = "",
    paths_m=(),
) -> Figure:
    """The shape, the Brillouin sphere and tracked arcs (n, m, 3) [m] in the body frame, with
    optional extra paths (e.g. descents): a 3-D view and the equatorial (x-y) projection with
    the shape's z = 0 cross-section."""
    import trimesh

    fig = Figure(figsize=(11, 5))
    ax3 = fig.add_subplot(1, 2, 1, projection="3d")
    colours = _shape_and_arcs_3d(ax3, vertices_m, faces, arc_positions_m, arc_trajectory)
    ax2 = fig.add_subplot(1, 2, 2)
    mesh = trimesh.Trimesh(vertices_m, faces, process=False)
    section = mesh.section(plane_origin=[0, 0, 0], plane_normal=[0, 0, 1])
    if section is not None:
        for line in section.discrete:
            ax2.fill(line[:, 0], line[:, 1], color="0.6")
    angle = np.linspace(0, 2 * np.pi, 200)
    r_b = brillouin_radius_m
    ax2.plot(r_b * np.cos(angle), r_b * np.sin(angle), "k--", lw=0.8, label="Brillouin sphere")
    for q, k in zip(arc_positions_m, arc_trajectory, strict=True):
        ax2.plot(q[:, 0], q[:, 1], color=colours[int(k)], lw=1.5)
    for path in paths_m:
        ax3.plot(path[:, 0], path[:, 1], path[:, 2], color="C3", lw=0.8)
        ax2.plot(path[:, 0], path[:, 1], color="C3", lw=0.8)
    _cube_limits(ax3, 2.2 * r_b)
    ax2.set_aspect("equal")
    ax2.set_xlabel("x [m]")
    ax2.set_ylabel("y [m]")
    ax2.legend(loc="upper right", fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def orbits_and_radii_figure(
    vertices_m: np.ndarray,
    faces: np.ndarray,
    brillouin_radius_m: float,
    arc_positions_m: np.ndarray,
    arc_trajectory: np.ndarray,
    *,
    shaded_rb: tuple[float, float] | None = None,
    title: str = "",
) -> Figure:
    """Where the data are: the shape and the tracked arcs (n, m, 3) [m] in the body frame (a
    3-D view), and the histogram of the samples' radii in units of the Brillouin radius, R_B
    marked; ``shaded_rb`` (low, high) [R_B] shades an evaluation range (e.g. the deep-region
    bins) to show whether samples reach it."""
    fig = Figure(figsize=(11, 4.8))
    ax3 = fig.add_subplot(1, 2, 1, projection="3d")
    _shape_and_arcs_3d(ax3, vertices_m, faces, arc_positions_m, arc_trajectory)
    radii = np.linalg.norm(arc_positions_m, axis=-1).ravel() / brillouin_radius_m
    _cube_limits(ax3, max(1.1, float(radii.max(initial=1.0))) * brillouin_radius_m)
    ax = fig.add_subplot(1, 2, 2)
    if shaded_rb is not None:
        ax.axvspan(*shaded_rb, color="0.85", label="evaluation bins")
    ax.hist(radii, bins=40, color="C0", label=f"{radii.size} tracked samples")
    ax.axvline(1.0, color="k", ls="--", lw=1, label="Brillouin radius")
    ax.set_xlabel("r / R_B")
    ax.set_ylabel("samples")
    ax.set_xlim(left=min(shaded_rb[0] if shaded_rb else 1.0, float(radii.min(initial=1.0))) - 0.05)
    ax.legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def miss_cdf_figure(
    misses_m: dict[str, list[float]],
    totals: dict[str, int],
    title: str,
    *,
    dashed: set[str] = frozenset(),
) -> Figure:
    """Fraction of descents within a miss distance [m], one step curve per model; ``totals``
    are the descents that landed under the truth (the curves' denominators); the models in
    ``dashed`` are drawn dashed (e.g. a comparison block)."""
    fig = Figure(figsize=(6.5, 4.5))
    ax = fig.add_subplot()
    for name, misses in misses_m.items():
        misses = np.sort(misses)
        frac = np.arange(1, len(misses) + 1) / max(totals[name], 1)
        ax.step(
            np.concatenate([[0.0], misses]),
            np.concatenate([[0.0], frac]),
            where="post",
            label=f"{name} ({len(misses)}/{totals[name]})",
            lw=2,
            ls="--" if name in dashed else "-",
        )
    ax.axhline(0.5, color="k", ls=":", lw=1)
    ax.set_xscale("symlog", linthresh=1.0)
    ax.set_xlim(left=0.0)
    ax.set_xlabel("miss distance [m]")
    ax.set_ylabel("fraction of descents")
    ax.set_ylim(0, 1.02)
    ax.legend(fontsize=8)
    ax.set_title(title)
    fig.tight_layout()
    return fig


def logdet_figure(greedy: list[float], randoms: list[list[float]]) -> Figure:
    """log det of the accumulated information against orbits selected: greedy D-optimal and
    random orders."""
    fig = Figure(figsize=(6, 4))
    ax = fig.add_subplot()
    picks = np.arange(1, len(greedy) + 1)
    for r in randoms:
        ax.plot(picks, r, color="0.6", lw=1)
    ax.plot(picks, greedy, color="C3", lw=2.5, label="D-optimal (greedy)")
    ax.plot([], [], color="0.6", label="random orders")
    ax.set_xlabel("orbits selected")
    ax.set_ylabel("log det of accumulated information")
    ax.legend()
    fig.tight_layout()
    return fig


def residual_figure(
    time_s: np.ndarray,
    position_sigmas: np.ndarray,
    velocity_sigmas: np.ndarray,
    *,
    title: str = "",
) -> Figure:
    """Residuals of tracking arcs against time, in noise sigmas: position residuals over
    sigma_r (top) and rotating-frame velocity residuals over sigma_v (bottom), one line per arc
    and component (x, y, z in three colours), at times ``time_s`` (n_arcs, k) [s] drawn in
    hours since the earliest sample; ``position_sigmas`` and ``velocity_sigmas`` are
    (n_arcs, k, 3). Each line's ``gid`` is "position arc A x" (quantity, arc A, component), so
    that what is drawn can be read back; the dotted lines mark +-1 sigma."""
    time_s = np.asarray(time_s, dtype=float)
    hours = (time_s - (time_s.min() if time_s.size else 0.0)) / 3600.0
    fig = Figure(figsize=(9, 6))
    axes = fig.subplots(2, 1, sharex=True)
    panels = (
        ("position", position_sigmas, "position residual / sigma_r"),
        ("velocity", velocity_sigmas, "velocity residual / sigma_v"),
    )
    for ax, (name, values, label) in zip(axes, panels, strict=True):
        values = np.asarray(values, dtype=float)
        for a in range(len(hours)):
            for c, axis in enumerate("xyz"):
                ax.plot(
                    hours[a],
                    values[a, :, c],
                    color=f"C{c}",
                    lw=0.8,
                    marker=".",
                    ms=2,
                    label=axis if a == 0 else None,
                    gid=f"{name} arc {a} {axis}",
                )
        for level in (-1.0, 1.0):
            ax.axhline(level, color="k", ls=":", lw=0.8)
        ax.set_ylabel(label)
    axes[0].legend(fontsize=8, ncols=3, loc="upper right")
    axes[1].set_xlabel("time since the first sample [h]")
    if title:
        axes[0].set_title(title)
    fig.tight_layout()
    return fig
