"""Figures (PNG, matplotlib without a display)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .interiors import Truth  # noqa: E402
from .tracking import Arcs  # noqa: E402

__all__ = ["plot_campaign"]


def plot_campaign(truth: Truth, arcs: Arcs, path: str | Path, save: bool = True):
    """The shape, the Brillouin sphere and the tracked arcs in the body frame: a 3-D view and
    the equatorial (x-y) projection, lengths in metres. With ``save=False`` the figure is
    returned open, for more layers."""
    body = truth.body
    length = body.units.length_m
    verts = np.asarray(body.mesh.vertices) * length
    faces = np.asarray(body.mesh.faces)
    r_b = body.brillouin_radius_m
    fig = plt.figure(figsize=(11, 5))
    ax3 = fig.add_subplot(1, 2, 1, projection="3d")
    ax3.plot_trisurf(
        verts[:, 0], verts[:, 1], verts[:, 2], triangles=faces, color="0.7", linewidth=0, alpha=0.6
    )
    ax2 = fig.add_subplot(1, 2, 2)
    section = body.mesh.section(plane_origin=[0, 0, 0], plane_normal=[0, 0, 1])
    if section is not None:
        for line in section.discrete:
            ax2.fill(line[:, 0] * length, line[:, 1] * length, color="0.6")
    theta = np.linspace(0, 2 * np.pi, 200)
    ax2.plot(r_b * np.cos(theta), r_b * np.sin(theta), "k--", lw=0.8, label="Brillouin sphere")
    colours = plt.cm.viridis(np.linspace(0, 1, max(1, len(arcs.trajectory_kind))))
    for k in range(arcs.n_arcs):
        q = arcs.true_states[k, :, :3] * length
        c = colours[arcs.trajectory[k]]
        ax3.plot(q[:, 0], q[:, 1], q[:, 2], color=c, lw=1.5)
        ax2.plot(q[:, 0], q[:, 1], color=c, lw=1.5)
    lim = 2.2 * r_b
    for ax in (ax3,):
        ax.set_xlim(-lim, lim)
        ax.set_ylim(-lim, lim)
        ax.set_zlim(-lim, lim)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_zlabel("z [m]")
    ax2.set_aspect("equal")
    ax2.set_xlabel("x [m]")
    ax2.set_ylabel("y [m]")
    ax2.legend(loc="upper right", fontsize=8)
    fig.suptitle(
        f"{body.name}: {arcs.n_arcs} arcs on {len(arcs.trajectory_kind)} orbits "
        f"(body frame), truth interior '{truth.interior}'"
    )
    fig.tight_layout()
    if not save:
        return fig
    path = Path(path)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
