"""The ``hamgrav`` command: a thin layer over the library."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated

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

app = typer.Typer(help="Learn small-body gravity fields from tracking arcs.", no_args_is_help=True)
console = Console()
err = Console(stderr=True)

_USER_ERRORS = (BodyDataError, CampaignError, DatasetError, SimulationError, ValueError)


def _fail(exc: Exception) -> None:
    err.print(f"[bold red]error:[/] {exc}", highlight=False)
    raise typer.Exit(code=2)


def _progress() -> Progress:
    return Progress(
        TextColumn("{task.description}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
        TimeElapsedColumn(), console=err, transient=False,
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
        (f"uniform truth ({report['truth_mascons']} mascons) vs polyhedron, 1.05 R_B: total V",
         f"{check['total_potential_rel_error']:.2e}"),
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
        Path | None, typer.Option(help="Also export the noisy arcs as a CCSDS OEM file.")
    ] = None,
) -> None:
    """Simulate a tracking campaign and write its arcs (HDF5)."""
    try:
        config = load_campaign(campaign)
        with _progress() as progress:
            task = progress.add_task(f"simulating {len(config.families)} orbits",
                                     total=len(config.families))
            arcs = simulate_campaign(
                config, progress=lambda done, total: progress.update(task, completed=done)
            )
        save_arcs(arcs, output)
        if oem is not None:
            from .oem_export import export_oem

            export_oem(arcs, oem)
    except _USER_ERRORS as exc:
        _fail(exc)
    console.print(
        f"wrote {arcs.n_arcs} arcs of {arcs.samples_per_arc} samples "
        f"({arcs.n_arcs * arcs.samples_per_arc * 6} scalars) to {output}"
    )


if __name__ == "__main__":
    app()
