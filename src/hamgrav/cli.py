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


def _parse_model_option(model: str) -> tuple[str, int]:
    if model == "network":
        return "network", 0
    if model.startswith("sh:") and model[3:].isdigit() and int(model[3:]) >= 2:
        return "sh", int(model[3:])
    raise ValueError(f"--model must be 'network' or 'sh:L' with L >= 2 (e.g. sh:8), got {model!r}")


def _parse_floats(text: str, name: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise ValueError(f"{name} must be comma-separated numbers, got {text!r}") from None


@app.command()
def fit(
    arcs_file: Annotated[Path, typer.Argument(metavar="ARCS", help="Arcs file (HDF5).")],
    output: Annotated[Path, typer.Option("-o", "--output", help="Model file to write.")],
    model: Annotated[str, typer.Option(help="'network' or 'sh:L'.")] = "network",
    hidden: Annotated[str, typer.Option(help="Hidden layer sizes of the network.")] = "24,24",
    prior: Annotated[
        str | None, typer.Option(help="'shape': constant-density shape prior in the known part.")
    ] = None,
    solver: Annotated[
        str | None, typer.Option(help="'adam' or 'lm' (default: adam for the network, lm for SH).")
    ] = None,
    weighted: Annotated[bool, typer.Option(help="Divide residuals by the noise sigmas.")] = False,
    kaula: Annotated[
        str | None,
        typer.Option(help="Kaula weight ALPHA, or 'scan' (1e-8..1e-4, best 1.05 R_B field error)."),
    ] = None,
    init: Annotated[Path | None, typer.Option(help="Warm start from this model file.")] = None,
    steps: Annotated[int, typer.Option(help="Adam steps.")] = 1500,
    learning_rate: Annotated[float, typer.Option(help="Adam peak learning rate.")] = 1e-2,
    seed: Annotated[int, typer.Option(help="Seed (initialisation, split, batches).")] = 0,
    resume: Annotated[
        bool, typer.Option(help="Continue an interrupted fit from its checkpoint.")
    ] = False,
) -> None:
    """Fit a gravity correction to tracking arcs and write the model file."""
    from .estimator import GravityEstimator
    from .evaluate import evaluation_sets, field_errors
    from .io import load_arcs
    from .modelfile import (
        checkpoint_path_for,
        load_checkpoint,
        load_model,
        save_checkpoint,
        save_model,
    )

    try:
        term, degree = _parse_model_option(model)
        hidden_sizes = tuple(int(h) for h in _parse_floats(hidden, "--hidden"))
        if prior not in (None, "shape"):
            raise ValueError(f"--prior must be 'shape', got {prior!r}")
        kaula_value: float | str | None = None
        if kaula is not None:
            kaula_value = "scan" if kaula == "scan" else _parse_floats(kaula, "--kaula")[0]
            if term != "sh":
                raise ValueError("--kaula applies to spherical-harmonics models (--model sh:L)")
        arcs = load_arcs(arcs_file)
        output.parent.mkdir(parents=True, exist_ok=True)
        ckpt = checkpoint_path_for(output)

        def kaula_metric(params, fit_model):
            from .estimator import body_for_arcs

            sets = evaluation_sets(body_for_arcs(arcs), (1.05,), ())
            return field_errors(fit_model, params, arcs.truth, sets)["r1.05"]

        estimator = GravityEstimator(
            term,
            hidden=hidden_sizes,
            degree=degree,
            prior=prior,
            solver=solver,
            weighted=weighted,
            kaula=kaula_value,
            kaula_metric=kaula_metric,
            adam_steps=steps,
            learning_rate=learning_rate,
            seed=seed,
        )
        theta0, resume_state = None, None
        if init is not None:
            theta0 = load_model(init, expect_body=arcs.body_name).params
        if resume:
            if not ckpt.exists():
                raise ValueError(f"no checkpoint {ckpt} to resume from; run without --resume")
            theta0, resume_state = load_checkpoint(ckpt)
        with _progress() as progress:
            task = progress.add_task(
                "fitting", total=steps if estimator.solver_name == "adam" else None
            )

            def on_iteration(it, record):
                text = " ".join(f"{k} {v:.3e}" for k, v in record.items() if isinstance(v, float))
                progress.update(task, completed=it, description=f"fitting [{text}]")

            estimator.fit(
                arcs,
                init=theta0,
                callback=on_iteration,
                checkpoint=lambda th, st: save_checkpoint(ckpt, th, st),
                resume=resume_state,
            )
        fitted = estimator.fitted_
        fitted.solver["arcs_file"] = str(arcs_file)
        save_model(fitted, output)
        ckpt.unlink(missing_ok=True)
    except KeyboardInterrupt:
        err.print(
            f"interrupted; the last checkpoint is kept: resume with the same command "
            f"and --resume ({checkpoint_path_for(output)})"
        )
        raise typer.Exit(code=130) from None
    except _USER_ERRORS as exc:
        _fail(exc)
    result = estimator.result_
    console.print(
        f"wrote {output}: {estimator.model_.learnable.describe()['kind']} with "
        f"{estimator.model_.n_learn} parameters, {result.iterations} iterations in "
        f"{result.wall_s:.1f} s ({result.message})"
    )


@app.command()
def evaluate(
    model_file: Annotated[Path, typer.Argument(metavar="MODEL", help="Model file.")],
    shells: Annotated[str, typer.Option(help="Shell radii r / R_B.")] = "1.05,1.1,1.2",
    altitude: Annotated[str, typer.Option(help="Surface-following altitudes [m].")] = "30",
    arcs_file: Annotated[
        Path | None,
        typer.Option("--arcs", help="Arcs whose truth to compare with (default: the fit's)."),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """Relative field errors of a fitted model against the truth recorded with the arcs."""
    from .estimator import body_for_arcs
    from .evaluate import evaluation_sets, field_errors
    from .io import load_arcs
    from .modelfile import load_model

    try:
        fitted = load_model(model_file)
        source = arcs_file or fitted.solver.get("arcs_file")
        if not source:
            raise ValueError("the model file records no arcs file; pass --arcs ARCS")
        arcs = load_arcs(source)
        if arcs.body_name != fitted.body_name:
            raise ValueError(
                f"arcs are of body {arcs.body_name!r}, the model of {fitted.body_name!r}"
            )
        body_obj = body_for_arcs(arcs)
        sets = evaluation_sets(
            body_obj, _parse_floats(shells, "--shells"), _parse_floats(altitude, "--altitude")
        )
        errors = field_errors(fitted.model, fitted.params, arcs.truth, sets)
    except _USER_ERRORS as exc:
        _fail(exc)
    if as_json:
        sys.stdout.write(json.dumps({"model": str(model_file), "field_error": errors}) + "\n")
        return
    table = Table(title=escape(f"relative field error of {model_file} ({fitted.body_name})"))
    table.add_column("evaluation set")
    table.add_column("epsilon", justify="right")
    for name, value in errors.items():
        label = f"shell {name[1:]} R_B" if name.startswith("r") else f"surface + {name[1:-1]} m"
        table.add_row(label, f"{value:.4f}")
    console.print(table)


@app.command()
def select(
    model_file: Annotated[Path, typer.Argument(metavar="MODEL", help="Current model file.")],
    pool: Annotated[
        Path,
        typer.Option(
            help="Campaign TOML whose [orbits] and [tracking] describe the candidate pool."
        ),
    ],
    picks: Annotated[int, typer.Option(help="How many orbits to pick.")] = 3,
    seed: Annotated[int, typer.Option(help="Seed of the candidates' node and phase.")] = 0,
    output: Annotated[
        Path | None, typer.Option("-o", "--output", help="Write the picks as JSON.")
    ] = None,
) -> None:
    """D-optimal choice of the next orbits from a candidate pool, from predicted sensitivities
    at the current model (no measurements, no truth)."""
    from .design import (
        greedy_d_optimal,
        predicted_arcs,
        random_order_logdet,
        trajectory_informations,
    )
    from .estimator import body_in_frame
    from .modelfile import load_model

    try:
        fitted = load_model(model_file)
        config = load_campaign(pool)
        if config.body != fitted.body_name:
            raise ValueError(
                f"the pool is for body {config.body!r}, the model for {fitted.body_name!r}"
            )
        body_obj = body_in_frame(fitted.body_name, fitted.body_origin_m)
        with _progress() as progress:
            progress.add_task(f"predicting {len(config.families)} candidate orbits", total=None)
            candidates = predicted_arcs(
                fitted.model,
                fitted.params,
                list(config.families),
                config.tracking,
                brillouin_radius=body_obj.brillouin_radius,
                body_name=fitted.body_name,
                gm_m3_s2=fitted.gm_m3_s2,
                spin_period_s=fitted.spin_period_s,
                seed=seed,
            )
            infos = trajectory_informations(
                fitted.model, fitted.params[: fitted.model.n_learn], candidates
            )
        n_pick = min(picks, len(infos))
        chosen, logdets, gains = greedy_d_optimal(infos, n_pick)
        _, random_logdets = random_order_logdet(infos, n_pick, seed=seed)
    except _USER_ERRORS as exc:
        _fail(exc)
    family_of = candidates.trajectory_info["candidate"]
    rows = []
    for k, (c, ld, g) in enumerate(zip(chosen, logdets, gains, strict=True)):
        fam = config.families[int(family_of[c])]
        rows.append(
            {
                "pick": k + 1,
                "candidate": int(family_of[c]),
                "radius_rb": fam.radius_rb,
                "inclination_deg": fam.inclination_deg,
                "gain": float(g),
                "logdet": float(ld),
                "random_order_logdet": float(random_logdets[k]),
            }
        )
    table = Table(title="D-optimal picks (log det of the accumulated information)")
    for col in ("pick", "candidate", "r / R_B", "incl. [deg]", "gain", "log det", "random order"):
        table.add_column(col, justify="right")
    for r in rows:
        table.add_row(
            str(r["pick"]),
            str(r["candidate"]),
            f"{r['radius_rb']:.2f}",
            f"{r['inclination_deg']:.1f}",
            f"{r['gain']:.2f}",
            f"{r['logdet']:.2f}",
            f"{r['random_order_logdet']:.2f}",
        )
    console.print(table)
    if output is not None:
        output.write_text(json.dumps({"model": str(model_file), "picks": rows}, indent=2) + "\n")


experiment_app = typer.Typer(
    help="Experiments of the paper (write results/<name>/).", no_args_is_help=True
)
app.add_typer(experiment_app, name="experiment")


@experiment_app.command("solvers")
def experiment_solvers(
    output: Annotated[Path, typer.Option("-o", "--output")] = Path("results/solvers-itokawa"),
    body_name: Annotated[str, typer.Option("--body")] = "itokawa",
    interior: Annotated[str, typer.Option()] = "head-tail",
    orbits: Annotated[int, typer.Option()] = 16,
    arcs_per_orbit: Annotated[int, typer.Option()] = 7,
    hidden: Annotated[str, typer.Option()] = "24,24",
    adam_steps: Annotated[int, typer.Option()] = 1500,
    lm_iterations: Annotated[int, typer.Option()] = 20,
    stages: Annotated[int, typer.Option()] = 4,
    seed: Annotated[int, typer.Option()] = 0,
) -> None:
    """Adam vs LM on the network, unweighted vs weighted; continual warm starts; D-optimal."""
    from .experiments.solvers import run_solver_comparison, write_solver_report

    command = (
        " ".join(["hamgrav", *sys.argv[1:]])
        if sys.argv[0].endswith("hamgrav")
        else (
            f"hamgrav experiment solvers --body {body_name} --interior {interior} --orbits "
            f"{orbits} --arcs-per-orbit {arcs_per_orbit} --hidden {hidden} --adam-steps "
            f"{adam_steps} --lm-iterations {lm_iterations} --stages {stages} --seed {seed} "
            f"-o {output}"
        )
    )
    try:
        results = run_solver_comparison(
            body=body_name,
            interior=interior,
            orbits=orbits,
            arcs_per_orbit=arcs_per_orbit,
            hidden=tuple(int(h) for h in _parse_floats(hidden, "--hidden")),
            adam_steps=adam_steps,
            lm_iterations=lm_iterations,
            stages=stages,
            seed=seed,
            progress=lambda text: err.print(escape(text)),
        )
        write_solver_report(results, output, command)
    except _USER_ERRORS as exc:
        _fail(exc)
    console.print(f"wrote {output}/results.json, README.md, d_optimal.png")


@experiment_app.command("descent")
def experiment_descent(
    body_name: Annotated[str, typer.Option("--body")] = "itokawa",
    interior: Annotated[
        str | None,
        typer.Option(help="uniform|head-tail|void|anomalies (default: head-tail for Itokawa)."),
    ] = None,
    seed: Annotated[int, typer.Option()] = 0,
    orbits: Annotated[int, typer.Option()] = 16,
    arcs_per_orbit: Annotated[int, typer.Option()] = 7,
    descents: Annotated[int, typer.Option()] = 30,
    hidden: Annotated[str, typer.Option()] = "24,24",
    adam_steps: Annotated[int, typer.Option()] = 1500,
    lm_iterations: Annotated[int, typer.Option()] = 20,
    output: Annotated[Path, typer.Option("-o", "--output")] = Path("results/descent-itokawa"),
) -> None:
    """Ballistic descent planning from tracking alone (the paper's touchdown table)."""
    from .experiments.descent import run_descent_experiment, write_descent_report

    command = (
        f"hamgrav experiment descent --body {body_name}"
        + (f" --interior {interior}" if interior else "")
        + f" --seed {seed} --orbits {orbits} --arcs-per-orbit {arcs_per_orbit}"
        + f" --descents {descents} --hidden {hidden} --adam-steps {adam_steps}"
        + f" --lm-iterations {lm_iterations} -o {output}"
    )
    try:
        results, artefacts = run_descent_experiment(
            body=body_name,
            interior=interior,
            seed=seed,
            orbits=orbits,
            arcs_per_orbit=arcs_per_orbit,
            descents=descents,
            hidden=tuple(int(h) for h in _parse_floats(hidden, "--hidden")),
            adam_steps=adam_steps,
            lm_iterations=lm_iterations,
            progress=lambda text: err.print(escape(text)),
        )
        write_descent_report(results, artefacts, output, command)
    except _USER_ERRORS as exc:
        _fail(exc)
    table = Table(title=f"touchdown miss over {descents} descents")
    for col in ("model", "median [m]", "90th pct [m]", "worst [m]", "landed", "h30m", "r1.2"):
        table.add_column(col, justify="right")
    for name, st in results["models"].items():
        fe = results["field_error"][name]
        cells = ["-" if st[k] is None else f"{st[k]:.1f}" for k in ("median_m", "p90_m", "worst_m")]
        table.add_row(
            name, *cells, f"{st['landed']}/{st['total']}", f"{fe['h30m']:.3f}", f"{fe['r1.2']:.3f}"
        )
    console.print(table)
    console.print(
        f"wrote {output}/results.json, README.md, touchdown.png, geometry.png "
        f"({results['wall_s']} s)"
    )


@app.command()
def demo(
    output: Annotated[Path, typer.Option("-o", "--output", help="Folder for the outputs.")] = Path(
        "demo-output"
    ),
    seed: Annotated[int, typer.Option(help="Campaign seed.")] = 0,
) -> None:
    """The descent-planning pipeline on the synthetic contact binary (no data folder needed).

    Head twice as dense as the body; 12 orbits x 7 arcs (orbits dipping below the Brillouin
    sphere are redrawn: around this strongly perturbed body they dominate the cost); a
    353-parameter network (Adam, and Levenberg-Marquardt) against SH degree 4 and 8; 12
    descents from 1.3 R_B. Writes the
    results, a README, the figures and the arcs (HDF5 and CCSDS OEM) to OUTPUT.
    """
    from .experiments.descent import run_descent_experiment, write_descent_report
    from .oem_export import export_oem_by_trajectory

    command = f"hamgrav demo --seed {seed} -o {output}"
    results, artefacts = run_descent_experiment(
        body="synthetic",
        interior="head-tail",
        seed=seed,
        orbits=12,
        arcs_per_orbit=7,
        descents=12,
        hidden=(16, 16),
        adam_steps=1500,
        lm_iterations=25,
        sh_degrees=(4, 8),
        min_radius_rb=1.0,
        progress=lambda text: err.print(escape(text)),
    )
    write_descent_report(results, artefacts, output, command)
    save_arcs(artefacts["arcs"], output / "arcs.h5")
    (output / "oem").mkdir(exist_ok=True)
    export_oem_by_trajectory(artefacts["arcs"], output / "oem")

    table = Table(title="synthetic contact binary: fitted models (from tracking alone)")
    for col in ("model", "r1.05", "r1.2", "r1.5", "h30m", "median miss [m]", "worst [m]", "landed"):
        table.add_column(col, justify="right")
    for name, st in results["models"].items():
        fe = results["field_error"][name]
        cells = ["-" if st[k] is None else f"{st[k]:.1f}" for k in ("median_m", "worst_m")]
        table.add_row(
            name,
            *(f"{fe[k]:.3f}" for k in ("r1.05", "r1.2", "r1.5", "h30m")),
            *cells,
            f"{st['landed']}/{st['total']}",
        )
    console.print(table)
    console.print(
        "field errors: relative error of the perturbing potential (1 = no "
        "correction); r = shells in R_B, h30m = 30 m above the surface"
    )
    console.print(
        f"wrote {output}/README.md, results.json, touchdown.png, geometry.png, "
        f"arcs.h5, oem/ in {results['wall_s']} s"
    )


if __name__ == "__main__":
    app()
