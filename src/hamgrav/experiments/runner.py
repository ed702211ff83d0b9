"""The experiment runner: seeds, repetitions, dispatch over Dask, timing, progress, and the
results folder (results.json, README.md next to the paper's numbers, figures).

An experiment is an :class:`Experiment`: a frozen config type and a pure function
``run(config, seed) -> RunOutput`` of plain data. Repetitions (seeds s, s+1, ...) are work
units mapped over a ``dask.distributed`` client: in-process by default (one worker thread in
this process, sharing its compile cache), a LocalCluster of ``workers`` processes, or an
existing scheduler. A work unit is :func:`run_unit`, a function of plain data only (experiment
name, config dict, seed, body-data folder), so every mode gives the same numbers.

results.json: ``{"experiment", "config", "seeds", "command", "repetitions": [single-run
objects], "aggregate": {key: {model: {statistic: {"median", "min", "max", "n"}}}}, ...}``.
"""

from __future__ import annotations

import contextlib
import logging
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

from .. import __version__
from ..bodies.catalogue import bodies_dir, check_body_name
from ..errors import InputError
from ..files import make_folder, written_together
from ..report.readme import results_readme
from ..report.tables import aggregate, format_range, summarise
from ..report.writer import save_figure, write_json, write_text
from .base import Experiment, RunContext, RunOutput, _silent
from .config import ExperimentConfig
from .registry import experiment_names, get_experiment
from .schema import REPORT, render_checked, validate

__all__ = [
    "Experiment",
    "RunContext",
    "RunOutput",
    "get_experiment",
    "experiment_names",
    "run_unit",
    "run_experiment",
    "check_job_memory",
    "rerender_readme",
    "merge_reports",
    "read_report",
    "aggregate",
    "summarise",
    "dask_client",
    "format_range",
]


def _stderr_say(prefix: str) -> Callable[[str], None]:
    def say(text: str) -> None:
        print(f"{prefix}{text}", file=sys.stderr, flush=True)

    return say


def _cluster_map(function, items) -> list:
    """Map ``function`` over ``items`` on the cluster running the current task."""
    from dask.distributed import worker_client

    with worker_client() as client:
        return client.gather(client.map(function, list(items), pure=False))


def run_unit(
    experiment_name: str,
    config: dict,
    seed: int,
    bodies_folder: str | None = None,
    verbose: bool = False,
    prefix: str = "",
    nested: bool = False,
    distribute_fits: bool = False,
) -> RunOutput:
    """One repetition as a pure function of plain data (the Dask work unit); with ``nested``
    its own independent work (Kaula scans, candidate pools) is mapped over the cluster too,
    and with ``distribute_fits`` each fit's sums over arcs run on the cluster's workers (the
    unit leaves its worker thread while it waits for them)."""
    experiment = get_experiment(experiment_name)
    cfg = experiment.config_type.from_dict(config)
    ctx = RunContext(
        seed=int(seed),
        bodies_folder=bodies_folder,
        say=_stderr_say(prefix) if verbose else _silent,
        mapper=_cluster_map if nested else map,
    )
    start = time.perf_counter()
    if distribute_fits:
        from dataclasses import replace

        from dask.distributed import worker_client

        with worker_client() as client:
            out = experiment.run(cfg, replace(ctx, fit_client=client))
    else:
        out = experiment.run(cfg, ctx)
    result = {
        **out.result,
        "seed": int(seed),
        "wall_s": round(time.perf_counter() - start, 1),
        "peak_memory_mb": _peak_memory_mb(),
    }
    return RunOutput(result, out.artefacts)


def _peak_memory_mb() -> float:
    """Peak resident memory of this process so far [MB] (the worker's, on a cluster)."""
    import resource

    kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux
    return round(kib / 1024.0, 1)


@contextlib.contextmanager
def dask_client(workers: int = 0, scheduler: str | None = None) -> Iterator:
    """A ``dask.distributed`` client: an existing ``scheduler`` address, a LocalCluster of
    ``workers`` single-threaded processes (workers >= 1), or in-process (one worker thread)."""
    from dask.distributed import Client, LocalCluster

    if scheduler:
        from distributed.comm import parse_address
        from distributed.comm.addressing import parse_host_port

        try:
            # a malformed address is refused before a Client exists: a Client that fails in
            # its constructor leaves its event loop behind in this process
            parse_host_port(parse_address(scheduler)[1])
            client = Client(scheduler, timeout="10s")
        except (OSError, ValueError, TypeError) as exc:  # unreachable or malformed address
            raise InputError(
                f"--scheduler {scheduler}: cannot connect ({exc}); start the scheduler or give "
                "its address as tcp://HOST:PORT"
            ) from None
        with client:
            yield client
        return
    if workers and workers > 0:
        with (
            LocalCluster(
                n_workers=int(workers),
                threads_per_worker=1,
                processes=True,
                dashboard_address=":0",  # a free port: never clash with another cluster
                silence_logs=logging.CRITICAL,
            ) as cluster,
            Client(cluster) as client,
        ):
            yield client
        return
    with Client(
        processes=False,
        n_workers=1,
        threads_per_worker=1,
        dashboard_address=":0",  # a free port: never clash with another cluster
        silence_logs=logging.CRITICAL,
    ) as client:
        yield client


def run_experiment(
    experiment: Experiment | str,
    config: ExperimentConfig | None = None,
    *,
    seed: int = 0,
    repeat: int = 1,
    output: str | Path | None = None,
    workers: int = 0,
    scheduler: str | None = None,
    command: str = "",
    say: Callable[[str], None] | None = None,
    verbose: bool = True,
    max_memory: str | None = None,
    distribute_fits: bool = False,
) -> tuple[dict, list[RunOutput]]:
    """Run ``repeat`` repetitions (seeds ``seed``, ``seed + 1``, ...) of ``experiment`` and,
    with ``output``, write results.json, README.md and the figures there. With
    ``distribute_fits`` (needs ``workers`` or ``scheduler``) every fit of a repetition sends
    its arcs to the cluster's workers, which compute its sums over arcs
    (:class:`hamgrav.fit.distributed.DistributedArcProblem`): the path of a campaign too
    large for one process.

    The repetitions that run at once are sized first (:func:`check_job_memory`) against
    ``max_memory`` (``8GiB``...; default: the memory available now).

    Returns the report (results.json's content) and the repetitions' outputs in seed order.
    """
    if isinstance(experiment, str):
        experiment = get_experiment(experiment)
    config = config or experiment.default_config()
    # a config built in Python has not been through the checks of a config file or the
    # command line: run them here, before a cluster starts (each worker reads it again)
    config = experiment.config_type.from_dict(config.as_dict())
    if repeat < 1:
        raise InputError(f"--repeat must be at least 1, got {repeat}")
    if workers and scheduler:
        raise InputError("give --workers or --scheduler, not both (a scheduler has its workers)")
    if distribute_fits and not (workers or scheduler):
        raise InputError(
            "--distribute-fits sends each fit's arcs to a cluster's workers: give --workers N "
            "or --scheduler ADDRESS too"
        )
    check_job_memory(experiment, config, repeat, workers, scheduler, max_memory)
    say = say or _stderr_say("")
    seeds = [int(seed) + i for i in range(repeat)]
    folder = str(bodies_dir())
    if isinstance(getattr(config, "body", None), str):
        # before any cluster starts or campaign is simulated
        check_body_name(config.body, folder)
    start = time.perf_counter()
    outputs: dict[int, RunOutput] = {}
    mode = (
        f"scheduler {scheduler}"
        if scheduler
        else (f"LocalCluster of {workers} workers" if workers else "in-process")
    ) + (", each fit's arcs on the workers" if distribute_fits else "")
    say(f"{experiment.name}: {repeat} repetition(s), seeds {seeds[0]}-{seeds[-1]}, {mode}")
    with dask_client(workers, scheduler) as client:
        from dask.distributed import as_completed

        futures = {
            client.submit(
                run_unit,
                experiment.name,
                config.as_dict(),
                s,
                folder,
                verbose,
                f"[seed {s}] " if repeat > 1 else "",
                bool(workers or scheduler) and repeat == 1,
                distribute_fits,
                pure=False,
            ): s
            for s in seeds
        }
        for future in as_completed(futures):
            s = futures[future]
            outputs[s] = future.result()
            say(
                f"repetition {len(outputs)}/{repeat} done (seed {s}, "
                f"{outputs[s].result['wall_s']:.0f} s)"
            )
    ordered = [outputs[s] for s in seeds]
    repetitions = [o.result for o in ordered]
    report = {
        "experiment": experiment.name,
        "title": experiment.title,
        "hamgrav_version": __version__,
        "command": command,
        "config": config.as_dict(),
        "seeds": seeds,
        "dispatch": mode,
        "wall_s": round(time.perf_counter() - start, 1),
        "repetitions": repetitions,
        "aggregate": experiment.aggregate(repetitions),
    }
    if output is not None:
        write_report(experiment, report, ordered[0].artefacts, Path(output))
    return report, ordered


def check_job_memory(
    experiment: Experiment,
    config: ExperimentConfig,
    repeat: int,
    workers: int = 0,
    scheduler: str | None = None,
    max_memory: str | None = None,
) -> None:
    """Refuse, in one line with the figure and the fix, a run whose repetitions at once (one
    in-process, up to ``workers`` on a LocalCluster) need more memory than ``max_memory`` or,
    by default, than this machine has available. On an existing ``scheduler`` the workers'
    memory is not this machine's: the run is sized only against a stated ``max_memory``
    (per worker)."""
    from ..sizing import check_memory, memory_limit

    if scheduler and max_memory is None:
        return
    limit = memory_limit(max_memory)
    at_once = 1 if scheduler else max(1, min(repeat, workers or 1))
    parts = {what: at_once * size for what, size in config.memory_parts().items()}
    fix = config.memory_fix + (", or run fewer --workers" if at_once > 1 else "")
    job = f"experiment {experiment.name}"
    if at_once > 1:
        job += f" ({at_once} repetitions at once)"
    check_memory(job, parts, limit, fix)


def write_report(experiment: Experiment, report: dict, artefacts: dict, folder: Path) -> None:
    """results.json, README.md and the figures of ``report`` into ``folder``: all of them or,
    when a write fails (a full disk, an interrupt), none (a folder created for them is
    removed again)."""
    figures = experiment.figures(report, artefacts)
    report["figures"] = list(figures)
    with written_together():
        make_folder(folder)
        write_json(folder / "results.json", report)
        for name, fig in figures.items():
            save_figure(fig, folder / name)
        write_readme(experiment, report, folder)


def read_report(folder: str | Path) -> dict:
    """The results.json of ``folder``, checked against the report's schema."""
    import json

    folder = Path(folder)
    path = folder / "results.json"
    if not path.is_file():
        raise InputError(f"no results.json in {folder}; run the experiment first")
    try:
        report = json.loads(path.read_text())
    except ValueError as exc:
        raise InputError(f"{path} is not an experiment's results ({exc})") from None
    validate(report, REPORT, str(path), "restore the file (or run the experiment again)")
    return report


def _portable(folder: str | Path) -> str:
    """How a merged report names a folder it was merged from: as given when relative, else
    relative to the working directory, else by its name alone (a scratch folder elsewhere on
    this machine: its path means nothing where the report is read)."""
    path = Path(folder)
    if not path.is_absolute():
        return str(path)
    try:
        return str(path.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return path.name


def merge_reports(folders: list[str | Path], output: str | Path) -> Path:
    """Write into ``output`` one results folder of the repetitions of ``folders``: runs of
    one experiment with the same config (and hamgrav version) on other seeds, e.g. seeds 0-3
    and 4-7 run on two days or machines. Every repetition is a pure function of its seed, so
    the merged report is what one run of all the seeds gives: its repetitions in seed order,
    the aggregate computed again, the wall times added; its command is that single run's
    (the first run's with ``--seed`` and ``--repeat`` covering all seeds) and it records the
    runs it was merged from. The figures (drawn from the first repetition's artefacts, which
    results.json does not hold) are copied from the folder holding the lowest seed."""
    import re
    import shutil

    if len(folders) < 2:
        raise InputError("give two or more results folders to merge")
    if any(Path(f).resolve() == Path(output).resolve() for f in folders):
        raise InputError(f"-o {output} is one of the folders merged; give a new folder")
    reports = [read_report(f) for f in folders]
    first = reports[0]
    for folder, report in zip(folders[1:], reports[1:], strict=True):
        for key in ("experiment", "config", "hamgrav_version"):
            if report.get(key) != first.get(key):
                raise InputError(
                    f"{folder} holds a run with another {key} than {folders[0]}; merge runs of "
                    "one experiment and config only"
                )
    seeds = sorted(s for r in reports for s in r["seeds"])
    if len(set(seeds)) != len(seeds):
        raise InputError("the folders share seeds; merge runs of other seeds only")
    if seeds != list(range(seeds[0], seeds[0] + len(seeds))):
        raise InputError(
            f"the seeds {seeds} leave gaps; merge runs whose seeds follow on from each other"
        )
    experiment = get_experiment(first["experiment"])
    repetitions = sorted((rep for r in reports for rep in r["repetitions"]), key=_seed_of)
    lowest = min(range(len(reports)), key=lambda i: min(reports[i]["seeds"]))
    command = re.sub(r"--seed \S+", lambda _: f"--seed {seeds[0]}", first["command"])
    command = re.sub(r"--repeat \S+", lambda _: f"--repeat {len(seeds)}", command)
    if "--seed " not in command:
        command += f" --seed {seeds[0]}"
    if "--repeat " not in command:
        command += f" --repeat {len(seeds)}"
    report = {
        **first,
        "command": re.sub(r"-o \S+", lambda _: f"-o {Path(output)}", command),
        "seeds": seeds,
        "dispatch": "; ".join(sorted({r["dispatch"] for r in reports})),
        "wall_s": round(sum(float(r["wall_s"]) for r in reports), 1),
        "repetitions": repetitions,
        "aggregate": experiment.aggregate(repetitions),
        "figures": reports[lowest].get("figures", []),
        "merged_from": [
            {
                "folder": _portable(f),
                "command": re.sub(r"-o (\S+)", lambda m: f"-o {_portable(m[1])}", r["command"]),
                "seeds": r["seeds"],
            }
            for f, r in zip(folders, reports, strict=True)
        ],
    }
    folder = Path(output)
    lines = render_checked(
        lambda r: readme_lines(experiment, r, folder), report, "the merged report", "check them"
    )
    with written_together():
        make_folder(folder)
        write_json(folder / "results.json", report)
        for name in report["figures"]:
            source = Path(folders[lowest]) / name
            if source.is_file() and source.resolve() != (folder / name).resolve():
                shutil.copyfile(source, folder / name)
        write_text(folder / "README.md", lines)
    return folder / "README.md"


def _seed_of(repetition: dict) -> int:
    return int(repetition.get("seed", 0))


def rerender_readme(folder: str | Path) -> Path:
    """Write README.md again from the results.json in ``folder`` (no computation)."""
    folder = Path(folder)
    path = folder / "results.json"
    report = read_report(folder)
    fix = "restore the file (or run the experiment again)"
    experiment = get_experiment(report["experiment"])
    # results written before figure names were recorded: the PNG files beside them
    report.setdefault("figures", sorted(p.name for p in folder.glob("*.png")))
    # rendered in memory first: a hand-edited value met while rendering leaves the old README
    lines = render_checked(lambda r: readme_lines(experiment, r, folder), report, str(path), fix)
    write_text(folder / "README.md", lines)
    return folder / "README.md"


#: A hand-written file in a results folder whose text the README includes under "Notes".
NOTES_FILE = "NOTES.md"


def write_readme(experiment: Experiment, report: dict, folder: Path) -> None:
    """README.md of ``report`` (its tables, the command, the configuration) into ``folder``."""
    write_text(folder / "README.md", readme_lines(experiment, report, folder))


def readme_lines(experiment: Experiment, report: dict, folder: Path) -> list[str]:
    """The lines of README.md of ``report`` (the notes file is read from ``folder``)."""
    notes = folder / NOTES_FILE
    return results_readme(
        experiment.title,
        report,
        experiment.readme(report),
        experiment.figure_captions,
        # the analysts' reading of these numbers (why they differ from the paper's), kept by
        # hand beside the generated tables and carried over when the README is re-rendered
        notes.read_text() if notes.is_file() else None,
    )
