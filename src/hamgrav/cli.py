"""The ``hamgrav`` command: a thin layer over the library."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from .bodies import BodyDataError, list_bodies, load_body
from .campaign import CampaignError, load_campaign, simulate_campaign
from .interiors import DEFAULT_TRUTH_MASCONS
from .io import DatasetError, save_arcs
from .tracking import SimulationError

app = typer.Typer(
    help="Learn small-body gravity fields from tracking arcs.",
    no_args_is_help=True,
    pretty_exceptions_show_locals=False,
)
console = Console()
err = Console(stderr=True)

_USER_ERRORS = (BodyDataError, CampaignError, DatasetError, SimulationError, ValueError)


def _fail(exc: Exception) -> None:
    err.print(f"[bold red]error:[/] {escape(str(exc))}", highlight=False)
    raise typer.Exit(code=2)


def _progress() -> Progress:
    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total}"),
        TimeElapsedColumn(),
        console=err,
        transient=False,
    )


@app.command()
def bodies() -> None:
    """List the bodies hamgrav can load (synthetic ones need no data folder)."""
    for name in list_bodies():
        console.print(name)


@app.command()
def body(
    name: str,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    mascons: Annotated[int, typer.Option(help="Uniform-truth mascon count.")] = (
        DEFAULT_TRUTH_MASCONS
    ),
) -> None:
    """Constants, Brillouin radius, envelope and perturbation figures of one body."""
    from .report import body_report

    try:
        report = body_report(load_body(name), n_mascons=mascons)
    except _USER_ERRORS as exc:
        _fail(exc)
    if as_json:
        sys.stdout.write(json.dumps(report) + "\n")
        return
    table = Table(title=escape(f"{report['name']}: {report['description']}"))
    table.add_column("quantity")
    table.add_column("value", justify="right")
    rows = [
        ("GM [m^3/s^2]", f"{report['gm_m3_s2']:.6g}"),
        ("spin period [s]", f"{report['spin_period_s']:.6g}"),
        ("synchronous radius (length unit) [m]", f"{report['synchronous_radius_m']:.2f}"),
        ("Brillouin radius R_B [m]", f"{report['brillouin_radius_m']:.2f}"),
        ("volume [m^3]", f"{report['volume_m3']:.5g}"),
        ("envelope (0-0.15 R_B) inside R_B", f"{report['envelope_fraction_inside_brillouin']:.3f}"),
    ]
    rows += [
        (f"median |a_pert|/|a_central| at {k} R_B", f"{v:.4f}")
        for k, v in report["perturbation_ratio"].items()
    ]
    check = report["uniform_truth_vs_polyhedron_r1.05"]
    rows += [
        (
            f"uniform truth ({report['truth_mascons']} mascons) vs polyhedron, 1.05 R_B: total V",
            f"{check['total_potential_rel_error']:.2e}",
        ),
        ("   ... perturbing V", f"{check['perturbing_potential_rel_error']:.2e}"),
    ]
    for q, v in rows:
        table.add_row(escape(q), v)
    console.print(table)


@app.command()
def simulate(
    campaign: Annotated[Path, typer.Argument(help="Campaign description (TOML).")],
    output: Annotated[Path, typer.Option("-o", "--output", help="Arcs file to write (HDF5).")],
    oem: Annotated[
        Path | None,
        typer.Option(help="Also export the noisy arcs as CCSDS OEM, one file per orbit, here."),
    ] = None,
) -> None:
    """Simulate a tracking campaign and write its arcs (HDF5)."""
    try:
        config = load_campaign(campaign)
        with _progress() as progress:
            task = progress.add_task(
                f"simulating {len(config.families)} orbits", total=len(config.families)
            )
            arcs = simulate_campaign(
                config, progress=lambda done, total: progress.update(task, completed=done)
            )
        save_arcs(arcs, output)
        if oem is not None:
            from .oem_export import export_oem_by_trajectory

            oem.mkdir(parents=True, exist_ok=True)
            export_oem_by_trajectory(arcs, oem)
    except _USER_ERRORS as exc:
        _fail(exc)
    console.print(
        f"wrote {arcs.n_arcs} arcs of {arcs.samples_per_arc} samples "
        f"({arcs.n_arcs * arcs.samples_per_arc * 6} scalars) to {output}"
    )


@app.command()
def demo(
    output: Annotated[Path, typer.Option("-o", "--output", help="Folder for the outputs.")] = Path(
        "demo-output"
    ),
    seed: Annotated[int, typer.Option(help="Campaign seed.")] = 1,
) -> None:
    """Run the pipeline on the synthetic contact binary (no data folder needed).

    Builds a head/tail truth, simulates a small tracking campaign, and writes the arcs (HDF5 and
    CCSDS OEM, one file per orbit), the body report (JSON) and a figure of the campaign to OUTPUT.
    """
    import time

    from .bodies import load_body
    from .campaign import Campaign
    from .fields import perturbing_potential, shell_points
    from .interiors import build_truth
    from .oem_export import export_oem_by_trajectory
    from .plots import plot_campaign
    from .report import body_report
    from .tracking import TrackingConfig, orbit_grid, simulate_orbits

    output.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    body_obj = load_body("synthetic")
    report = body_report(body_obj)
    (output / "body.json").write_text(json.dumps(report, indent=2) + "\n")
    campaign = Campaign(
        body="synthetic",
        interior="head-tail",
        n_mascons=400,
        seed=seed,
        families=tuple(orbit_grid(8, (1.2, 2.0), (10.0, 80.0))),
        tracking=TrackingConfig(arcs_per_orbit=4),
    )
    truth = build_truth(body_obj, "head-tail", n_mascons=campaign.n_mascons, seed=seed)
    with _progress() as progress:
        task = progress.add_task("simulating tracking", total=len(campaign.families))
        arcs = simulate_orbits(
            truth,
            list(campaign.families),
            campaign.tracking,
            seed=seed,
            progress=lambda done, total: progress.update(task, completed=done),
            config=campaign.as_dict(),
        )
    save_arcs(arcs, output / "arcs.h5")
    (output / "oem").mkdir(exist_ok=True)
    export_oem_by_trajectory(arcs, output / "oem")
    figure = plot_campaign(truth, arcs, output / "campaign.png")

    table = Table(title="synthetic contact binary, head twice as dense as the body")
    table.add_column("shell r/R_B")
    table.add_column("rms perturbing / rms central potential", justify="right")
    for s in (1.05, 1.2, 1.5, 2.0):
        pts = shell_points(s * truth.body.brillouin_radius, 400)
        dv = perturbing_potential(truth.mascons, pts)
        table.add_row(
            f"{s:.2f}", f"{np.sqrt(np.mean(dv**2)) * s * truth.body.brillouin_radius:.4f}"
        )
    console.print(table)
    console.print(
        f"{arcs.n_arcs} arcs x {arcs.samples_per_arc} samples "
        f"(sigma_r = {arcs.sigma_r_m * 100:.1f} cm, sigma_v = {arcs.sigma_v_m_s * 1e6:.2f} um/s); "
        f"envelope inside R_B: {report['envelope_fraction_inside_brillouin']:.3f}"
    )
    console.print(
        f"wrote {output}/arcs.h5, oem/*.oem, body.json, {figure.name} "
        f"in {time.perf_counter() - start:.1f} s"
    )
    console.print(
        "[dim]Estimators (network vs spherical harmonics) and descent planning are not part of "
        "this version yet.[/]"
    )


if __name__ == "__main__":
    app()
