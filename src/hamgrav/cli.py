"""The ``hamgrav`` command: a thin layer over the library.

Every option is checked before any work starts, and every output path before anything is
computed. Errors caused by input, data or environment (:class:`hamgrav.errors.HamgravError`)
are printed in one line and exit with status 2 (so do the option errors of typer itself);
warnings (:class:`hamgrav.errors.HamgravWarning`) in one line too. Anything else is a bug: it
is reported in one line asking for a report and exits with status 70; ``hamgrav --debug``
shows its traceback instead. Ctrl-C exits with status 130 and SIGTERM (what a batch
scheduler or ``kill`` sends) with status 143 (128 + the signal), each saying what was kept. A
disk that refuses a write (full, quota, size limit, I/O error) is one line (status 2) naming
the file, and leaves no part of the file behind.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where it arrives like Ctrl-C's KeyboardInterrupt, so that the same
    clean-up runs (temporary files removed, the last complete checkpoint kept)."""

    signum = signal.SIGTERM


#: The stop signal that arrived during the command, if any (see :func:`_as_interruption`).
_signalled: list[int] = []


def _raise_terminated(signum, frame):
    _signalled[:] = [signum]
    raise Terminated


def _raise_interrupted(signum, frame):
    _signalled[:] = [signum]
    raise KeyboardInterrupt


def _as_interruption(exc: BaseException) -> KeyboardInterrupt | None:
    """The KeyboardInterrupt or Terminated behind ``exc``: ``exc`` itself, one in its chain
    of causes, or, when a stop signal arrived during the command, that signal's. A signal
    can arrive inside a library call that turns the exception raised there into one of its
    own (numpy's comparison of structured arrays reports any failure as a TypeError: one
    of 50 kills of the kill test): it is still the user's interruption, not a bug."""
    seen = exc
    while seen is not None:
        if isinstance(seen, KeyboardInterrupt):
            return seen
        seen = seen.__cause__ or seen.__context__
    if _signalled:
        return Terminated() if _signalled[0] == signal.SIGTERM else KeyboardInterrupt()
    return None


def _stopped(exc: BaseException) -> tuple[str, int]:
    """How a command was stopped (for its message) and its exit status: 128 + the signal."""
    if isinstance(exc, Terminated):
        return "terminated (SIGTERM)", 128 + signal.SIGTERM
    return "interrupted", 128 + signal.SIGINT


class _DeferInterrupt:
    """Hold Ctrl-C and SIGTERM while the libraries load (a second or two), then exit with
    one line.

    A KeyboardInterrupt raised inside an import is not reliably seen: some libraries import
    their optional dependencies under ``except BaseException`` and swallow it, so a Ctrl-C
    at the wrong moment was simply lost and the command ran on. Only the main thread can
    install the handler; an ignored signal (a background job) stays ignored.
    """

    def __enter__(self):
        self.hit = None
        self.previous = {}
        if threading.current_thread() is threading.main_thread():
            for signum, default in (
                (signal.SIGINT, signal.default_int_handler),
                (signal.SIGTERM, signal.SIG_DFL),
            ):
                if signal.getsignal(signum) is default:
                    self.previous[signum] = signal.signal(signum, self._hold)
        return self

    def _hold(self, signum, frame):
        self.hit = self.hit or signum

    def __exit__(self, *exc):
        for signum, handler in self.previous.items():
            signal.signal(signum, handler)
        if self.hit or (exc[0] is not None and issubclass(exc[0], KeyboardInterrupt)):
            how = "terminated (SIGTERM)" if self.hit == signal.SIGTERM else "interrupted"
            sys.stderr.write(f"{how} while starting; nothing was done\n")
            raise SystemExit(128 + (self.hit or signal.SIGINT))
        return False


with _DeferInterrupt():
    import functools
    import inspect
    import json
    import math
    import warnings
    from pathlib import Path
    from typing import Annotated

    import click
    import typer
    from rich.console import Console
    from rich.markup import escape
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
    from rich.table import Table

    from .bodies.catalogue import load_body
    from .bodies.interiors import DEFAULT_TRUTH_MASCONS
    from .errors import DiskError, DistributedError, HamgravError, HamgravWarning, InputError
    from .files import (
        check_output,
        check_writable_folder,
        disk_error,
        make_folder,
        remove_partial_files,
        written_together,
    )

# Help texts are plain text: their units in brackets ([m], [deg]) are not rich markup.
app = typer.Typer(
    help="Learn small-body gravity fields from tracking arcs.",
    no_args_is_help=True,
    pretty_exceptions_show_locals=False,
    rich_markup_mode=None,
)
console = Console()
err = Console(stderr=True)

#: Exit status of an internal error (a bug): EX_SOFTWARE of sysexits.h.
BUG_EXIT = 70
#: Where bugs are reported.
ISSUES = "the hamgrav issue tracker"
_debug = {"on": False}


@app.callback()
def _main(
    debug: Annotated[
        bool,
        typer.Option(
            "--debug",
            help="Show the traceback of an internal error (a bug) instead of a one-line report.",
            envvar="HAMGRAV_DEBUG",
        ),
    ] = False,
) -> None:
    """Learn small-body gravity fields from tracking arcs."""
    _debug["on"] = debug


def _fail(exc: Exception) -> None:
    err.print(f"[bold red]error:[/] {escape(str(exc))}", highlight=False, soft_wrap=True)
    raise typer.Exit(code=2)


def _warn(message, category, filename, lineno, file=None, line=None) -> None:
    """Print hamgrav's warnings in one line (other warnings keep Python's format)."""
    if issubclass(category, HamgravWarning):
        err.print(
            f"[bold yellow]warning:[/] {escape(str(message))}", highlight=False, soft_wrap=True
        )
    else:
        err.print(escape(warnings.formatwarning(message, category, filename, lineno, line)))


class _CommandSignals:
    """While a command runs, SIGTERM raises :class:`Terminated` (in the main thread, unless
    SIGTERM is ignored or already handled), and a KeyboardInterrupt or Terminated that
    Python could not raise (it arrived in a destructor or a weakref callback, where Python
    prints "Exception ignored" and carries on: one of 50 kills of the kill test) is kept
    quietly and raised at the fit's next iteration by :func:`_stop_if_signalled`. What was
    there before comes back after."""

    def __enter__(self):
        self.previous = None
        self.previous_int = None
        _swallowed.clear()
        _signalled.clear()
        main = threading.current_thread() is threading.main_thread()
        if main and signal.getsignal(signal.SIGTERM) is signal.SIG_DFL:
            self.previous = signal.signal(signal.SIGTERM, _raise_terminated)
        if main and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
            self.previous_int = signal.signal(signal.SIGINT, _raise_interrupted)
        previous = self.hook = sys.unraisablehook

        def keep_swallowed(unraisable):
            if isinstance(unraisable.exc_value, KeyboardInterrupt):
                _swallowed[:] = [unraisable.exc_value]
            else:
                previous(unraisable)

        sys.unraisablehook = keep_swallowed
        return self

    def __exit__(self, *exc):
        sys.unraisablehook = self.hook
        if self.previous is not None:
            signal.signal(signal.SIGTERM, self.previous)
        if self.previous_int is not None:
            signal.signal(signal.SIGINT, self.previous_int)
        return False


#: The KeyboardInterrupt or Terminated that Python swallowed during the command, if any.
_swallowed: list[BaseException] = []


def _stop_if_signalled() -> None:
    """Raise a KeyboardInterrupt or Terminated that Python swallowed (see
    :class:`_CommandSignals`)."""
    if _swallowed:
        raise _swallowed.pop()


def _report_stop(exc: KeyboardInterrupt) -> None:
    """Say in one line that the command was stopped, with nothing half-written, and exit with
    128 + the signal."""
    remove_partial_files()
    how, status = _stopped(exc)
    err.print(
        f"{how}; no file is left half-written (hamgrav writes each file whole or not at all)",
        highlight=False,
        soft_wrap=True,
    )
    raise typer.Exit(code=status) from None


def _command(typer_app: typer.Typer, *args, **kwargs):
    """``typer_app.command(*args, **kwargs)`` with hamgrav's error handling: user errors in
    one line (status 2; a disk that refuses a write too), Ctrl-C and SIGTERM in one line
    (status 130 and 143), bugs reported as bugs (status 70, the traceback with --debug)."""

    def register(func):
        @functools.wraps(func)
        def run(*a, **k):
            with warnings.catch_warnings(), _CommandSignals():
                warnings.simplefilter("always", HamgravWarning)
                warnings.showwarning = _warn
                try:
                    return func(*a, **k)
                except HamgravError as exc:
                    _fail(exc)
                except KeyboardInterrupt as exc:
                    _report_stop(exc)
                except (
                    typer.Exit,
                    typer.Abort,
                    click.exceptions.Exit,
                    click.ClickException,
                    click.Abort,
                ):
                    raise
                except Exception as exc:
                    stop = _as_interruption(exc)
                    if stop is not None:
                        _report_stop(stop)
                    disk = disk_error(exc, getattr(exc, "filename", None) or "a file")
                    if disk is not None:  # a write outside hamgrav's own (a library's cache)
                        _fail(disk)
                    if _debug["on"]:
                        raise
                    err.print(
                        f"[bold red]internal error[/] (a bug in hamgrav, not in your input): "
                        f"{escape(type(exc).__name__)}: {escape(str(exc))}. Please report it "
                        f"to {ISSUES} with the command you ran; 'hamgrav --debug ...' shows "
                        "the traceback.",
                        highlight=False,
                        soft_wrap=True,
                    )
                    raise typer.Exit(code=BUG_EXIT) from None

        return typer_app.command(*args, **kwargs)(run)

    return register


class _Progress(Progress):
    """A progress display whose closing line is written whole: a Ctrl-C or SIGTERM that
    arrives while it closes is held until it has ended its line and raised then, so the
    command's one-line report of the signal starts a line of its own."""

    def __exit__(self, *exc):
        held = []
        previous = {}
        if threading.current_thread() is threading.main_thread():
            for signum in (signal.SIGINT, signal.SIGTERM):
                if callable(signal.getsignal(signum)):  # not ignored, not the default action
                    previous[signum] = signal.signal(signum, lambda n, f: held.append(n))
        try:
            super().__exit__(*exc)
        finally:
            for signum, handler in previous.items():
                signal.signal(signum, handler)
        if held and exc[0] is None:  # raised as the handler would have, now the line is done
            signal.raise_signal(held[0])


def _progress() -> Progress:
    return _Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total}"),
        TimeElapsedColumn(),
        console=err,
        transient=False,
    )


def _say(text: str) -> None:
    err.print(escape(text), highlight=False)


# ------------------------------------------------------------------------------ option checks
# One place per kind of option value: every command calls these before it does any work.


def _number(value, name: str, low: float, *, open_low: bool = False, integer: bool = False):
    """``value`` if it is a finite number >= ``low`` (> with ``open_low``), an integer with
    ``integer``; else :class:`InputError` naming the option ``name``."""
    kind = "an integer" if integer else "a finite number"
    bound = f"{'>' if open_low else '>='} {low:g}"
    ok = isinstance(value, int | float) and not isinstance(value, bool)
    ok = ok and math.isfinite(value) and (value > low if open_low else value >= low)
    if integer:
        ok = ok and float(value).is_integer()
    if not ok:
        raise InputError(f"{name} must be {kind} {bound}, got {value!r}")
    return int(value) if integer else float(value)


def _floats(text: str, name: str, low: float = -math.inf, *, open_low: bool = False) -> list[float]:
    """The comma-separated finite numbers of option ``name`` (at least one), each >= ``low``
    (> with ``open_low``)."""
    words = [w.strip() for w in text.split(",") if w.strip()]
    try:
        values = [float(w) for w in words]
    except ValueError:
        raise InputError(f"{name} must be comma-separated numbers, got {text!r}") from None
    if not values:
        raise InputError(f"{name} needs at least one number, got {text!r}")
    return [_number(v, name, low, open_low=open_low) for v in values]


def _ints(text: str, name: str, low: int = 1) -> list[int]:
    """The comma-separated integers >= ``low`` of option ``name`` (at least one)."""
    words = [w.strip() for w in text.split(",") if w.strip()]
    try:
        if not words:
            raise ValueError
        values = [int(w) for w in words]
    except ValueError:
        raise InputError(
            f"{name} must be comma-separated integers >= {low}, got {text!r}"
        ) from None
    return [_number(v, name, low, integer=True) for v in values]


def _seed(value, name: str = "--seed", count: int = 1) -> int:
    """A seed: an integer >= 0 whose ``count`` consecutive seeds (repetitions) all fit the
    64-bit integer seeds are stored in (:data:`hamgrav.core.arcs.MAX_SEED`)."""
    from .core.arcs import MAX_SEED

    seed = _number(value, name, 0, integer=True)
    if seed + count - 1 > MAX_SEED:
        runs = f" with --repeat {count} (seeds up to {name} + {count - 1})" if count > 1 else ""
        raise InputError(
            f"{name} must be an integer in [0, 2**63 - 1]{runs}: seeds are stored as 64-bit "
            f"integers, got {value!r}; give a smaller seed"
        )
    return seed


def _output(path: Path | None, name: str = "-o", **inputs: Path | None) -> Path | None:
    """Check an output file before the work that produces it (see :func:`check_output`);
    ``inputs``: the command's input files by name, which the output must not replace."""
    return None if path is None else check_output(path, name, inputs)


def _output_folder(path: Path, name: str) -> Path:
    """An output folder: created if missing; anything else than a folder there is refused."""
    if path.exists() and not path.is_dir():
        raise InputError(f"{name} {path} exists and is not a folder; give a folder path")
    check_writable_folder(path, name)
    return make_folder(path)


def _command_line(words: list[str], options: dict) -> str:
    """The command that reproduces a run: ``words`` then every option that was given."""
    parts = ["hamgrav", *words]
    for name, value in options.items():
        if value is None:
            continue
        flag = "-o" if name == "output" else "--" + name.replace("_", "-")
        if value is False:
            # a switch given off (its default is on): --no-<name>
            parts.append("--no-" + name.replace("_", "-"))
        else:
            parts += [flag] if value is True else [flag, str(value)]
    return " ".join(parts)


#: The --body option of commands that read arcs or a model: they record their body.
BodyOption = Annotated[
    str | None,
    typer.Option(
        "--body",
        help="The body: a catalogue name or a body TOML (default: the one the arcs or model "
        "file records; older files, which record only a name, are looked up by it).",
    ),
]

MaxMemoryOption = Annotated[
    str | None,
    typer.Option(
        "--max-memory",
        help="Refuse the job before it starts if its arrays need more memory than this (e.g. "
        "8GiB; default: the memory available now).",
    ),
]


def _body_for(spec: str | None, arcs=None, fitted=None):
    """The body of a command on ``arcs`` (or a model ``fitted``): ``--body`` when given
    (checked against them), else the one they record."""
    from .fit.estimator import body_for_arcs, body_for_model, body_with_arcs

    if spec is None:
        return body_for_arcs(arcs) if arcs is not None else body_for_model(fitted)
    return body_with_arcs(load_body(spec), arcs if arcs is not None else fitted, f"--body {spec}")


@_command(app)
def bodies() -> None:
    """List the bodies hamgrav can load (synthetic ones need no data folder)."""
    from .bodies.catalogue import SYNTHETIC_BODIES, BodyDataError, bodies_dir, read_catalogue

    for name in SYNTHETIC_BODIES:
        console.print(name)
    try:
        catalogue = read_catalogue(bodies_dir())
    except BodyDataError as exc:
        warnings.warn(f"{exc} Only the synthetic bodies are listed.", HamgravWarning, 1)
        return
    for name in sorted(catalogue):
        console.print(name)


@_command(app)
def body(
    name: Annotated[str, typer.Argument(help="A catalogue name, 'synthetic' or a body TOML file.")],
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    mascons: Annotated[
        str, typer.Option(help="Uniform-truth mascon count (an integer; 1e4 is read as 10000).")
    ] = str(DEFAULT_TRUTH_MASCONS),
) -> None:
    """Constants, Brillouin radius, envelope and perturbation figures of one body."""
    from .bodies.summary import body_report
    from .sim.campaign import MAX_TRUTH_MASCONS

    count = _floats(mascons, "--mascons")
    if len(count) != 1 or not count[0].is_integer() or not 10 <= count[0] <= MAX_TRUTH_MASCONS:
        raise InputError(
            f"--mascons must be one integer in [10, {MAX_TRUTH_MASCONS}] (the truth is "
            f"compressed from about 120000 volume samples), got {mascons!r}"
        )
    report = body_report(load_body(name), n_mascons=int(count[0]))
    if as_json:
        sys.stdout.write(json.dumps(report, allow_nan=False) + "\n")
        return
    table = Table(title=escape(f"{report['name']}: {report['description']}"))
    table.add_column("quantity")
    table.add_column("value", justify="right")
    check = report["uniform_truth_vs_polyhedron_r1.05"]
    rows = [
        ("GM [m^3/s^2]", f"{report['gm_m3_s2']:.6g}"),
        ("spin period [s]", f"{report['spin_period_s']:.6g}"),
        ("synchronous radius (length unit) [m]", f"{report['synchronous_radius_m']:.2f}"),
        ("Brillouin radius R_B [m]", f"{report['brillouin_radius_m']:.2f}"),
        ("volume [m^3]", f"{report['volume_m3']:.5g}"),
        ("bulk density GM / (G V) [kg/m^3]", f"{report['bulk_density_kg_m3']:.4g}"),
        (
            "centre of mass at constant density [m, shape frame]",
            ", ".join(f"{v:.3f}" for v in report["constant_density_centre_m"]),
        ),
        ("envelope (0-0.15 R_B) inside R_B", f"{report['envelope_fraction_inside_brillouin']:.3f}"),
        *(
            (f"median |a_pert|/|a_central| at {k} R_B", f"{v:.4f}")
            for k, v in report["perturbation_ratio"].items()
        ),
        (
            f"uniform truth ({report['truth_mascons']} mascons) vs polyhedron, 1.05 R_B: total V",
            f"{check['total_potential_rel_error']:.2e}",
        ),
        ("   ... perturbing V", f"{check['perturbing_potential_rel_error']:.2e}"),
    ]
    for q, v in rows:
        table.add_row(escape(q), v)
    console.print(table)


@_command(app)
def simulate(
    campaign: Annotated[Path, typer.Argument(help="Campaign description (TOML).")],
    output: Annotated[Path, typer.Option("-o", "--output", help="Arcs file to write (HDF5).")],
    oem: Annotated[
        Path | None,
        typer.Option(help="Also export the noisy arcs as CCSDS OEM, one file per orbit, here."),
    ] = None,
    spk: Annotated[
        Path | None,
        typer.Option(
            help="Also write the noisy arcs as a SPICE SPK (type 13, J2000, target -1000 - k "
            "for orbit k) to this file (.bsp)."
        ),
    ] = None,
    max_memory: MaxMemoryOption = None,
) -> None:
    """Simulate a tracking campaign and write its arcs (HDF5)."""
    from .bodies.catalogue import check_body_name
    from .errors import BodyDataError
    from .io.arcs import save_arcs
    from .io.oem import export_oem_by_trajectory
    from .sim.campaign import load_campaign, simulate_campaign
    from .sizing import check_memory, memory_limit

    limit = memory_limit(max_memory)
    _simulate_outputs(campaign, output, oem, spk)
    config = load_campaign(campaign)
    try:  # before the simulation starts
        check_body_name(config.body)
    except BodyDataError as exc:
        raise InputError(f"{campaign}: body: {exc}") from None
    check_memory(
        f"simulating {campaign}",
        config.memory_parts(),
        limit,
        "lower [orbits] count, [tracking] arcs_per_orbit or samples_per_arc",
    )
    n = len(config.families)
    with _progress() as progress:
        task = progress.add_task(f"simulating {n} orbits", total=n)
        arcs = simulate_campaign(
            config, progress=lambda done, total: progress.update(task, completed=done)
        )
    with written_together():  # the arcs file and its exports, or none of them
        save_arcs(arcs, output)
        if oem is not None:
            export_oem_by_trajectory(arcs, _output_folder(oem, "--oem"))
        if spk is not None:
            from .io.spk import write_spk

            write_spk(arcs, spk, load_body(config.body))
    console.print(
        f"wrote {arcs.n_arcs} arcs of {arcs.samples_per_arc} samples "
        f"({arcs.n_arcs * arcs.samples_per_arc * 6} scalars) to {output}"
    )


def _simulate_outputs(campaign: Path, output: Path, oem: Path | None, spk: Path | None) -> None:
    """simulate's output paths checked before the simulation: the arcs file, the SPK file
    and the OEM folder, each writable and none of them an input."""
    _output(output, CAMPAIGN=campaign)
    if spk is not None:
        check_output(spk, "--spk", {"CAMPAIGN": campaign, "-o": output})
    if oem is not None:
        if oem.exists() and not oem.is_dir():
            raise InputError(f"--oem {oem} exists and is not a folder; give a folder path")
        check_writable_folder(oem, "--oem")


def _rotation_option(pole_ra, pole_dec, prime_meridian, rotation_epoch, body):
    """The rotation model of the import commands' pole options (None when none is given),
    at the body's spin rate; all three angles or none."""
    from .bodies.rotation import RotationModel

    given = [v is not None for v in (pole_ra, pole_dec, prime_meridian)]
    if any(given) and not all(given):
        raise InputError("give all of --pole-ra, --pole-dec and --prime-meridian, or none")
    if not all(given):
        return None
    return RotationModel(pole_ra, pole_dec, prime_meridian, body.spin_period_s, rotation_epoch)


def _origin_option(origin: str | None):
    """The import commands' --origin x,y,z [m] as three floats (None when not given)."""
    if origin is None:
        return None
    origin_m = _floats(origin, "--origin")
    if len(origin_m) != 3:
        raise InputError(f"--origin must be three numbers x,y,z [m], got {origin!r}")
    return origin_m


def _import_options(output: Path, inputs: dict, body_name: str, origin, pole):
    """The import commands' output checked against their ``inputs``, then (body, rotation
    model or None, origin [m] or None) of --body, the ``pole`` options (--pole-ra,
    --pole-dec, --prime-meridian, --rotation-epoch) and --origin."""
    _output(output, **inputs)
    body_obj = load_body(body_name)
    return body_obj, _rotation_option(*pole, body_obj), _origin_option(origin)


def _say_imported(arcs, output: Path, source: str) -> None:
    """One line on the arcs an import wrote: counts, frames, epoch, noise, dropped samples."""
    cfg = arcs.config
    console.print(
        f"wrote {arcs.n_arcs} arcs of {arcs.samples_per_arc} samples {source} to {output} "
        f"(frames: {', '.join(cfg['frames'])}; canonical time 0 = {cfg['epoch_tdb']} TDB; "
        f"noise from {cfg['noise_from']}: sigma_r {arcs.sigma_r_m:.4g} m, sigma_v "
        f"{arcs.sigma_v_m_s:.4g} m/s; {cfg['dropped_samples']} samples dropped)",
        highlight=False,
    )


ArcsOutputOption = Annotated[
    Path, typer.Option("-o", "--output", help="Arcs file to write (HDF5).")
]
SamplesOption = Annotated[
    int | None,
    typer.Option(help="Samples per arc (default: each gap-free run of samples is one arc)."),
]
MaxGapOption = Annotated[
    float | None,
    typer.Option(help="Split where samples are more than this apart [s] (1.5 median step)."),
]
SigmaROption = Annotated[float | None, typer.Option(help="Position noise per component [m].")]
SigmaVOption = Annotated[
    float | None, typer.Option(help="Rotating-frame velocity noise per component [m/s].")
]
OriginOption = Annotated[
    str | None, typer.Option(help="Frame origin in the body mesh's frame, x,y,z [m].")
]
RotationEpochOption = Annotated[
    str, typer.Option(help="TDB epoch (ISO) of the prime meridian angle W0.")
]
OemEpochOption = Annotated[
    str | None,
    typer.Option(
        help="TDB epoch of canonical time 0 (ISO; default: the epoch in hamgrav's own "
        "COMMENT lines, else the first sample)."
    ),
]
OemPoleRaOption = Annotated[
    float | None, typer.Option(help="Inertial frames: pole right ascension [deg, ICRF].")
]
OemPoleDecOption = Annotated[
    float | None, typer.Option(help="Inertial frames: pole declination [deg, ICRF].")
]
OemPrimeMeridianOption = Annotated[
    float | None,
    typer.Option(help="Inertial frames: prime meridian W0 at --rotation-epoch [deg]."),
]
SpkEpochOption = Annotated[
    str | None,
    typer.Option(
        help="TDB epoch of canonical time 0 (ISO; default: the epoch in hamgrav's own "
        "SPK comment, else the first sample)."
    ),
]
SpkPoleRaOption = Annotated[
    float | None, typer.Option(help="No body frame in the kernels: pole RA [deg, ICRF].")
]
SpkPoleDecOption = Annotated[
    float | None, typer.Option(help="No body frame in the kernels: pole dec [deg, ICRF].")
]
SpkPrimeMeridianOption = Annotated[
    float | None,
    typer.Option(help="No body frame in the kernels: prime meridian W0 [deg]."),
]
SpkStartOption = Annotated[
    str | None, typer.Option(help="TDB epoch (ISO) to read from (default: coverage start).")
]
SpkStopOption = Annotated[
    str | None, typer.Option(help="TDB epoch (ISO) to read to (default: coverage end).")
]
SpkStepOption = Annotated[
    float | None,
    typer.Option(help="Sample every this many seconds [s] (default: the segments' epochs)."),
]
SpkCenterOption = Annotated[
    int | None,
    typer.Option(help="NAIF ID of the body in the SPKs (default: the body's own)."),
]
SpkTargetOption = Annotated[
    list[str],
    typer.Option(
        help="Spacecraft NAIF ID or name, one trajectory each (repeat for several; "
        "hamgrav's own SPKs: -1000, -1001, ...), or 'all': every target the SPKs give "
        "relative to the body."
    ),
]


@_command(app, "import-oem")
def import_oem_command(
    files: Annotated[list[Path], typer.Argument(metavar="FILE...", help="CCSDS OEM files.")],
    body_name: Annotated[
        str,
        typer.Option("--body", help="The central body (catalogue name or body TOML file)."),
    ],
    output: ArcsOutputOption,
    samples: SamplesOption = None,
    max_gap: MaxGapOption = None,
    sigma_r: SigmaROption = None,
    sigma_v: SigmaVOption = None,
    epoch: OemEpochOption = None,
    origin: OriginOption = None,
    pole_ra: OemPoleRaOption = None,
    pole_dec: OemPoleDecOption = None,
    prime_meridian: OemPrimeMeridianOption = None,
    rotation_epoch: RotationEpochOption = "2000-01-01T12:00:00",
) -> None:
    """Turn CCSDS OEM tracking files (KVN or XML, one trajectory each) into an arcs file.

    States in an inertial frame (ICRF, EME2000) are rotated into the body-fixed frame with the
    body's rotation model (pole and prime meridian from the options or the catalogue, spin
    rate from the body's spin period). The arcs carry no truth: fit them, and evaluate
    reports residuals against the noise."""
    from .io.arcs import save_arcs
    from .io.oem_import import import_oem

    pole = (pole_ra, pole_dec, prime_meridian, rotation_epoch)
    inputs = {f"FILE {f}": f for f in files}
    body_obj, rotation, origin_m = _import_options(output, inputs, body_name, origin, pole)
    arcs = import_oem(
        files,
        body_obj,
        samples=samples,
        max_gap_s=max_gap,
        rotation=rotation,
        epoch=epoch,
        sigma_r_m=sigma_r,
        sigma_v_m_s=sigma_v,
        origin_m=origin_m,
    )
    save_arcs(arcs, output)
    _say_imported(arcs, output, f"from {len(files)} files")


@_command(app, "import-spk")
def import_spk_command(
    kernels: Annotated[
        list[Path],
        typer.Argument(metavar="KERNELS...", help="SPICE kernels: SPKs (.bsp), PCK/FK."),
    ],
    body_name: Annotated[
        str, typer.Option("--body", help="The central body: a catalogue name or a body TOML.")
    ],
    target: SpkTargetOption,
    output: ArcsOutputOption,
    start: SpkStartOption = None,
    stop: SpkStopOption = None,
    step: SpkStepOption = None,
    samples: SamplesOption = None,
    max_gap: MaxGapOption = None,
    sigma_r: SigmaROption = None,
    sigma_v: SigmaVOption = None,
    epoch: SpkEpochOption = None,
    origin: OriginOption = None,
    center: SpkCenterOption = None,
    pole_ra: SpkPoleRaOption = None,
    pole_dec: SpkPoleDecOption = None,
    prime_meridian: SpkPrimeMeridianOption = None,
    rotation_epoch: RotationEpochOption = "2000-01-01T12:00:00",
) -> None:
    """Turn SPICE SPK trajectories (one spacecraft per --target) into an arcs file.

    States relative to the body are taken in the body-fixed frame the kernels define (a PCK
    or FK), else in J2000 rotated with a rotation model (the options, hamgrav's own SPK
    comment, or the catalogue). The arcs carry no truth: fit them, and evaluate reports
    residuals against the noise."""
    from .io.arcs import save_arcs
    from .io.spk import import_spk

    pole = (pole_ra, pole_dec, prime_meridian, rotation_epoch)
    inputs = {f"KERNEL {k}": k for k in kernels}
    body_obj, rotation, origin_m = _import_options(output, inputs, body_name, origin, pole)
    arcs = import_spk(
        kernels,
        body_obj,
        target,
        start=start,
        stop=stop,
        step_s=step,
        samples=samples,
        max_gap_s=max_gap,
        rotation=rotation,
        epoch=epoch,
        sigma_r_m=sigma_r,
        sigma_v_m_s=sigma_v,
        origin_m=origin_m,
        centre=center,
    )
    save_arcs(arcs, output)
    _say_imported(arcs, output, f"of {arcs.n_trajectories} targets")


def _model_option(model: str) -> dict:
    """Estimator settings of a --model value: a named configuration, sh:L, or sh:auto /
    sh:auto:L (the degree chosen by cross-validation among 2..12 or 2..L)."""
    from .fit.estimator import AUTO_DEGREES, PRESETS, preset

    if model in PRESETS:
        return preset(model)
    if model.startswith("sh:") and model[3:].isdecimal() and 2 <= int(model[3:]) <= MAX_SH_DEGREE:
        return {"term": "sh", "degree": int(model[3:])}
    if model == "sh:auto":
        return {"term": "sh", "degree": AUTO_DEGREES}
    top = model[len("sh:auto:") :]
    if model.startswith("sh:auto:") and top.isdecimal() and 3 <= int(top) <= MAX_SH_DEGREE:
        return {"term": "sh", "degree": tuple(range(2, int(top) + 1))}
    raise InputError(
        f"--model must be one of {', '.join(PRESETS)}, 'sh:L' with 2 <= L <= {MAX_SH_DEGREE} "
        f"(e.g. sh:8), or 'sh:auto' / 'sh:auto:L' (degree chosen from the arcs, 2..12 or "
        f"2..L), got {model!r}"
    )


#: Largest SH degree --model accepts: (L+1)^2 - 4 coefficients, 1677 at 40, already far
#: more than any campaign of hamgrav constrains (the paper goes to 16).
MAX_SH_DEGREE = 40
#: Largest hidden layer --hidden accepts (the paper's networks have 16 or 24 units).
MAX_HIDDEN = 1024


def _check_fit_memory(settings: dict, hidden_sizes, arcs, limit) -> None:
    """Refuse a fit whose design blocks and normal matrices cannot fit in ``limit`` (one
    member's parameters: the members of network-best are fitted one at a time)."""
    import numpy as np

    from .core.terms import SphericalHarmonics
    from .fit.estimator import AUTO_DEGREES
    from .sizing import check_memory, fit_bytes, network_parameters

    if settings["term"] == "network":
        n_params, fix = network_parameters(hidden_sizes), "use fewer or smaller --hidden layers"
    elif settings["term"] == "sh":
        # sh:auto: its most flexible candidate is the largest fit it makes
        degree = settings["degree"]
        largest = max(AUTO_DEGREES if degree == "auto" else np.atleast_1d(degree))
        n_params = SphericalHarmonics(int(largest), 1.0).n_params
        fix = "lower the degree of --model sh:L"
    else:
        return
    check_memory(
        f"fitting {n_params} parameters to {arcs.n_arcs} arcs",
        fit_bytes(arcs.n_arcs, arcs.samples_per_arc, n_params),
        limit,
        fix,
    )


# --------------------------------------------------------------------------------- fit options
# Module-level option types keep each command's signature short (typer reads them as any
# annotation).
FitModelOption = Annotated[
    str,
    typer.Option(
        help="'network-best' (the mean of 3 networks fitted by LM with a harmonic penalty: "
        "recommended), 'network' (the paper's Adam protocol), 'sh:L', or 'sh:auto' / "
        "'sh:auto:L' (SH of degree chosen from the arcs by cross-validation among 2..12 / "
        "2..L).",
    ),
]
HiddenOption = Annotated[str, typer.Option(help="Hidden layer sizes of the network.")]
PlacementOption = Annotated[
    str,
    typer.Option(
        help="With --prior shape: 'centred' (its constant-density centre of mass moved to the "
        "frame's origin) or 'in-place' (the shape where it is, plus the point dipole that takes "
        "the offset back out: the field near the surface of the shape itself).",
    ),
]
SofteningOption = Annotated[
    float,
    typer.Option(
        help="Softening r_c of the network's envelope [R_B]: R_w^3 / (r^2 + r_c^2)^(3/2) for "
        "(R_w / r)^3, which caps how much a change of the network is amplified deep inside "
        "the Brillouin sphere (0: none; a continued fit gives its model's).",
    ),
]
PriorOption = Annotated[
    str | None,
    typer.Option(help="'shape': constant-density shape prior in the known part."),
]
SolverOption = Annotated[
    str | None,
    typer.Option(
        help="'adam' or 'lm' (default: the model's own: LM for network-best and sh:L, Adam "
        "for network). Naming a solver with network-best fits one network instead of the "
        "mean of three, and 'adam' leaves out the harmonic penalty.",
    ),
]
WeightedOption = Annotated[
    bool,
    typer.Option(
        help="Whiten each sample's residual by the tracking noise: positions / sigma_r, "
        "rotating-frame velocities / sigma_v.",
    ),
]
ShareOption = Annotated[
    str | None,
    typer.Option(
        metavar="KIND=SHARE",
        help="Weigh the arcs of one trajectory kind as a set at SHARE (in (0, 1)) of the "
        "cost, the other arcs at the rest, each measured by what no correction leaves on it "
        "(e.g. descent=0.2: a few descents near the surface otherwise take nearly all of it).",
    ),
]
KaulaOption = Annotated[
    str | None,
    typer.Option(
        help="SH: Kaula weight ALPHA, or 'cv' (chosen from the arcs by cross-validation "
        "among 1e-4..1e-8 and 0; no truth needed).",
    ),
]
HarmonicOption = Annotated[
    str | None,
    typer.Option(
        help="Network fitted by LM: weight of the harmonic penalty (0: off; default: the "
        "model's own, 1e-5 for network-best), or 'cv' (chosen from the arcs by "
        "cross-validation among 1e-3..1e-6).",
    ),
]
FoldsOption = Annotated[
    int,
    typer.Option(
        help="Folds of the cross-validation of 'cv' / 'sh:auto': for --kaula cv and sh:auto "
        "whole arcs, the simplest candidate within one standard error of the lowest held-out "
        "cost kept; for --harmonic cv bands of altitude, the lowest held-out cost kept (see "
        "--cv-group).",
    ),
]
CvGroupOption = Annotated[
    str | None,
    typer.Option(
        help="What a fold of the cross-validation holds out whole: 'arc', 'trajectory' (every "
        "arc of one trajectory), or 'altitude' (the arcs sorted by their lowest radius into "
        "bands, lowest first: the lowest band predicted from the arcs above it, a check of "
        "the field below the tracking). Default: altitude for --harmonic cv, arc for --kaula "
        "cv and sh:auto. Each keeps its rule: the lowest held-out cost for --harmonic cv, "
        "one standard error otherwise.",
    ),
]
InitOption = Annotated[
    Path | None,
    typer.Option(
        help="Continue this model (same structure) on ARCS, which should hold all the arcs "
        "so far: a continual stage, recorded in the model file's stage history.",
    ),
]
AnchorOption = Annotated[
    float | None,
    typer.Option(
        help="With --init: hold the learned field near the continued model's where the new "
        "arcs (those in ARCS after the model's own) do not reach, with this weight w "
        "(dimensionless, measured like --harmonic's, e.g. 1e-4): new tracking corrects the "
        "field where it flies, not everywhere. Network fitted by LM only.",
    ),
]
AnchorClearanceOption = Annotated[
    float | None,
    typer.Option(
        "--anchor-clearance-m",
        help="With --anchor: the harmonic penalty's collocation points within this distance "
        "[m] of a new arc's sample are free of the anchor (default: 0.1 of the Brillouin "
        "radius).",
    ),
]
AnchorOnOption = Annotated[
    str | None,
    typer.Option(
        help="With --anchor: the quantity held, 'acceleration' (rows weighted by (r/R_w)^4, "
        "R_w the network's envelope radius, the synchronous radius; the default) or "
        "'potential' (unweighted rows, as the relative field error counts a change near the "
        "surface; the same W holds it otherwise than the acceleration).",
    ),
]
StepsOption = Annotated[
    int, typer.Option(help="Adam steps (when the solver is Adam; LM ignores it).")
]
LearningRateOption = Annotated[
    float,
    typer.Option(help="Adam peak learning rate (when the solver is Adam)."),
]
ResumeOption = Annotated[
    bool,
    typer.Option(help="Continue an interrupted fit from its checkpoint."),
]
StrictOption = Annotated[
    bool,
    typer.Option(
        help="Exit with status 3 when the fit does not clearly beat no correction on its "
        "held-out arcs, or looks overfit (held-out cost per arc over 10x the training's).",
    ),
]
WorkersOption = Annotated[
    int,
    typer.Option(
        help="Sum the fit over the arcs on a Dask LocalCluster of N worker processes, "
        "which hold the arcs in chunks (0: in-process threads). Same numbers to rounding.",
    ),
]
SchedulerOption = Annotated[
    str | None,
    typer.Option(help="Sum the fit over the arcs on the workers of this Dask scheduler."),
]


@_command(app)
def fit(
    arcs_file: Annotated[Path, typer.Argument(metavar="ARCS", help="Arcs file (HDF5).")],
    output: Annotated[Path, typer.Option("-o", "--output", help="Model file to write.")],
    model: FitModelOption = "network-best",
    hidden: HiddenOption = "24,24",
    envelope_softening_rb: SofteningOption = 0.0,
    prior: PriorOption = None,
    prior_placement: PlacementOption = "centred",
    solver: SolverOption = None,
    weighted: WeightedOption = False,
    share: ShareOption = None,
    kaula: KaulaOption = None,
    harmonic: HarmonicOption = None,
    folds: FoldsOption = 5,
    cv_group: CvGroupOption = None,
    init: InitOption = None,
    anchor: AnchorOption = None,
    anchor_clearance_m: AnchorClearanceOption = None,
    anchor_on: AnchorOnOption = None,
    steps: StepsOption = 1500,
    learning_rate: LearningRateOption = 1e-2,
    seed: Annotated[int, typer.Option(help="Seed (initialisation, split, batches).")] = 0,
    resume: ResumeOption = False,
    strict: StrictOption = False,
    body: BodyOption = None,
    max_memory: MaxMemoryOption = None,
    workers: WorkersOption = 0,
    scheduler: SchedulerOption = None,
) -> None:
    """Fit a gravity correction to tracking arcs and write the model file.

    The model file is written in every case, with the fit's outcome and diagnostics. An
    interrupted fit keeps a checkpoint beside it (OUTPUT.checkpoint.npz): --resume continues
    it, and a fresh fit refuses to start over it."""
    from .io.arcs import load_arcs
    from .io.fit_run import checkpoint_for_fit, prepare_fit
    from .sizing import memory_limit

    # options, then the output, then the inputs: all before any computation
    settings, kaula_value, hidden_sizes = _fit_options(
        model, hidden, prior, solver, kaula, harmonic, folds, cv_group, workers, scheduler, steps
    )
    settings |= _softening_option(envelope_softening_rb, settings["term"])
    settings |= _placement_option(prior_placement, prior)
    _number(learning_rate, "--learning-rate", 0.0, open_low=True)
    _seed(seed)
    shared = _share(share)
    _anchor_options(anchor, anchor_clearance_m, anchor_on, init)
    limit = memory_limit(max_memory)
    _output(output, ARCS=arcs_file)  # -o MODEL --init MODEL continues the model in place
    ckpt = checkpoint_for_fit(output, resume)
    arcs = load_arcs(arcs_file)
    _check_fit_memory(settings, hidden_sizes, arcs, limit)
    body_obj = _body_for(body, arcs=arcs)
    settings |= {"adam_steps": steps, "learning_rate": learning_rate}
    settings |= {"prior": prior, "kaula": kaula_value, "seed": seed, "folds": folds}
    estimator = _fit_estimator(settings, arcs, arcs_file, weighted, body_obj)
    weights = None if shared is None else _share_weights(estimator, arcs, arcs_file, *shared)
    run = prepare_fit(
        estimator,
        arcs,
        output,
        init=init,
        resume=resume,
        checkpoint=ckpt,
        init_name="--init",
        arc_weights=weights,
        anchor=_anchor_settings(anchor, anchor_clearance_m, anchor_on, body_obj),
    )
    _run_and_write(run, arcs_file, workers, scheduler, steps)
    _report_fit(estimator, output, settings["term"], strict)


def _anchor_options(weight, clearance_m, quantity, init) -> None:
    """Refuse field-anchor options that cannot act (see ``hamgrav fit --help``)."""
    from .fit.anchor import ANCHOR_QUANTITIES

    if weight is None:
        given = {"--anchor-clearance-m": clearance_m, "--anchor-on": quantity}
        for name, value in given.items():
            if value is not None:
                raise InputError(f"{name} sets the field anchor: give --anchor W too")
        return
    _number(weight, "--anchor", 0.0, open_low=True)
    if init is None:
        raise InputError(
            "--anchor holds a continued fit near the model it continues: give --init MODEL"
        )
    if clearance_m is not None:
        _number(clearance_m, "--anchor-clearance-m", 0.0)
    if quantity is not None and quantity not in ANCHOR_QUANTITIES:
        raise InputError(
            f"--anchor-on must be one of {', '.join(ANCHOR_QUANTITIES)}, got {quantity!r}"
        )


def _anchor_settings(weight, clearance_m, quantity, body):
    """The field anchor of ``hamgrav fit`` (None without --anchor), its clearance in the
    body's canonical length (default: 0.1 of the Brillouin radius)."""
    from .fit.anchor import AnchorSettings

    if weight is None:
        return None
    clearance = (
        0.1 * body.brillouin_radius
        if clearance_m is None
        else float(body.units.to_length(clearance_m))
    )
    return AnchorSettings(float(weight), clearance, quantity=quantity or "acceleration")


def _run_and_write(run, arcs_file: Path, workers: int, scheduler, steps: int) -> None:
    """Run the prepared fit ``run`` and write its model; a fit stopped by a signal, a full
    disk or a lost cluster ends in one line that says what was kept (:func:`_fit_stopped`)."""
    output, ckpt = run.output, run.checkpoint
    before = _file_id(output)  # to tell, if stopped, whether this run wrote the model
    try:
        _run_fit(run, workers, scheduler, steps)
        # inside the same try: a signal between the fit and the model's write (a loaded
        # machine delivers one there) must still say the checkpoint is kept
        run.write(arcs_file)
    except (KeyboardInterrupt, DiskError, DistributedError) as exc:
        _fit_stopped(exc, ckpt, output, written=_file_id(output) not in (None, before))
    except Exception as exc:
        stop = _as_interruption(exc)
        if stop is None:
            raise
        _fit_stopped(stop, ckpt, output, written=_file_id(output) not in (None, before))


def _share(share: str | None) -> tuple[str, float] | None:
    """--share KIND=SHARE as (kind, share), checked; None when not given."""
    if share is None:
        return None
    kind, sep, value = share.partition("=")
    try:
        number = float(value)
    except ValueError:
        number = math.nan
    if not sep or not kind.strip() or not 0.0 < number < 1.0:
        raise InputError(
            f"--share must be KIND=SHARE with SHARE in (0, 1), e.g. descent=0.2; got {share!r}"
        )
    return kind.strip(), number


def _share_weights(estimator, arcs, arcs_file: Path, kind: str, share: float):
    """The arc weights (n_arcs,) of --share KIND=SHARE on ``arcs`` (one propagation of
    every arc with no correction); says what they are."""
    import numpy as np

    from .fit.weights import share_weights

    choices = estimator.choices()
    if choices:
        chosen = {"degree": "--model sh:auto", "kaula": "--kaula cv", "harmonic": "--harmonic cv"}
        raise InputError(
            f"--share and {' and '.join(chosen[c] for c in choices)} do not go together: the "
            "cross-validation scores unweighted arcs; give the value itself or leave out --share"
        )
    kinds = sorted(set(arcs.trajectory_kind))
    in_set = np.asarray(arcs.trajectory_kind)[arcs.trajectory] == kind
    if not in_set.any() or in_set.all():
        raise InputError(
            f"--share {kind}={share:g}: arcs {arcs_file} have "
            + ("no" if not in_set.any() else "only")
            + f" arcs of kind {kind!r} (their kinds: {', '.join(kinds)}); a share weighs one "
            "kind against the others"
        )
    weights = share_weights(estimator.no_correction_costs(arcs), in_set, share)
    console.print(
        f"--share {kind}={share:g}: the {int(in_set.sum())} {kind} arcs weigh "
        f"{weights[in_set][0]:.3g} each, the other {int((~in_set).sum())} arcs 1"
    )
    return weights


def _fit_estimator(settings: dict, arcs, arcs_file: Path, weighted: bool, body_obj):
    """The estimator of fit's ``settings`` on ``body_obj``; --weighted refused for arcs
    without a noise level."""
    from .fit.estimator import GravityEstimator, has_noise

    if weighted and not has_noise(arcs):
        raise InputError(
            f"--weighted: arcs {arcs_file} record no tracking noise (noise-free arcs) to whiten "
            "by; leave out --weighted"
        )
    return GravityEstimator(**settings, weighted=weighted, body=body_obj)


def _placement_option(value: str, prior: str | None) -> dict:
    """fit's --prior-placement checked: the estimator setting (none for the default)."""
    if value not in ("centred", "in-place"):
        raise InputError(f"--prior-placement must be 'centred' or 'in-place', got {value!r}")
    if value == "centred":
        return {}
    if prior != "shape":
        raise InputError("--prior-placement in-place needs --prior shape")
    return {"prior_placement": value}


def _softening_option(value: float, term: str) -> dict:
    """fit's --envelope-softening-rb checked: the estimator setting (none when 0)."""
    _number(value, "--envelope-softening-rb", 0.0)
    if not value:
        return {}
    if term != "network":
        raise InputError(
            "--envelope-softening-rb applies to networks (--model network-best or network)"
        )
    return {"envelope_softening_rb": float(value)}


def _fit_options(
    model, hidden, prior, solver, kaula, harmonic, folds, cv_group, workers, scheduler, steps
) -> tuple[dict, float | str | None, tuple[int, ...]]:
    """fit's options checked: (estimator settings of --model, --hidden, --solver,
    --harmonic and --cv-group; the --kaula value; the hidden layer sizes)."""
    from .fit.selection import GROUPS as CV_GROUPS

    settings = _model_option(model) | {"cv_group": cv_group}
    term = settings["term"]
    hidden_sizes = tuple(_ints(hidden, "--hidden"))
    if max(hidden_sizes) > MAX_HIDDEN:
        raise InputError(f"--hidden layers must have at most {MAX_HIDDEN} units, got {hidden}")
    if prior not in (None, "shape"):
        raise InputError(f"--prior must be 'shape', got {prior!r}")
    if solver not in (None, "adam", "lm"):
        raise InputError(f"--solver must be 'adam' or 'lm', got {solver!r}")
    kaula_value = _weight_or_cv(kaula, "--kaula", "ALPHA")
    if kaula_value is not None and term != "sh":
        raise InputError("--kaula applies to spherical-harmonics models (--model sh:L)")
    harmonic_value = _weight_or_cv(harmonic, "--harmonic", "W")
    if harmonic_value is not None and (term != "network" or solver == "adam"):
        raise InputError(
            "--harmonic applies to networks fitted by LM (--model network-best, or --solver lm)"
        )
    _number(folds, "--folds", 2, integer=True)
    _number(workers, "--workers", 0, integer=True)
    if workers and scheduler:
        raise InputError("give --workers or --scheduler, not both (a scheduler has its workers)")
    _number(steps, "--steps", 1, integer=True)
    if cv_group is not None and cv_group not in CV_GROUPS:
        raise InputError(f"--cv-group must be one of {', '.join(CV_GROUPS)}, got {cv_group!r}")
    if solver is not None:  # a solver by name replaces the configuration's
        settings = {**settings, "solver": solver, "warm_solver": None, "members": 1}
        if solver == "adam":  # the harmonic penalty is an LM objective term
            settings["harmonic"] = None
    if term == "network":
        settings = {**settings, "hidden": hidden_sizes}
    if harmonic_value is not None:
        settings["harmonic"] = harmonic_value or None
    return settings, kaula_value, hidden_sizes


def _run_fit(run, workers: int, scheduler: str | None, steps: int) -> None:
    """Run the prepared fit ``run`` (an :class:`hamgrav.io.fit_run.FitRun`) with a progress
    display, on a Dask cluster with ``workers`` or ``scheduler``."""
    estimator = run.estimator
    with contextlib.ExitStack() as cluster, _progress() as progress:
        if workers or scheduler:
            from .experiments.runner import dask_client

            estimator.client = cluster.enter_context(dask_client(workers, scheduler))
        total = steps if estimator.solver_name == "adam" else None
        choices = estimator.choices()
        # the cross-validation fits come first and report no iterations: say what runs
        first = (
            f"choosing {', '.join(choices)} by {estimator.folds}-fold cross-validation "
            f"({sum(map(len, choices.values())) * estimator.folds} fits), then fitting"
            if choices
            else "fitting"
        )
        task = progress.add_task(first, total=total)

        def on_iteration(it, record):
            _stop_if_signalled()
            text = " ".join(f"{k} {v:.3e}" for k, v in record.items() if isinstance(v, float))
            progress.update(task, completed=it, description=f"fitting [{text}]")

        with warnings.catch_warnings():
            # said below, after the fit's summary, in the command's words
            warnings.filterwarnings("ignore", message="the fit looks overfit")
            run.fit(on_iteration)


def _report_fit(estimator, output: Path, term: str, strict: bool) -> None:
    """What a fit wrote, its choices by cross-validation and its warnings; with ``strict``,
    exit with status 3 when it failed to improve or looks overfit."""
    from .fit.diagnostics import OVERFIT_FACTOR

    result = estimator.result_
    diag = estimator.diagnostics_
    console.print(
        f"wrote {output}: {term} with {estimator.model_.n_learn} parameters, "
        f"{result.iterations} iterations in {result.wall_s:.1f} s ({result.outcome.value}: "
        f"{result.message}); cost on the {diag['checked_on']} {diag['relative_cost']:.3g} of "
        f"no correction; {diag['constrained_parameters']} of {diag['n_params']} parameter "
        "directions constrained by the arcs"
    )
    for selection in getattr(estimator, "selection_", ()):
        for line in selection.lines():
            console.print(line, highlight=False)
    failed = False
    if not diag["improved"]:
        err.print(
            "[bold yellow]warning:[/] the fit does not clearly improve on no correction "
            f"(cost ratio {diag['relative_cost']:.3g} on the {diag['checked_on']}); do not use "
            "this model",
            highlight=False,
            soft_wrap=True,
        )
        failed = True
    if diag.get("overfit"):
        err.print(
            "[bold yellow]warning:[/] the fit looks overfit: a held-out arc costs "
            f"{diag['held_out_to_training']:.3g}x a training arc (above {OVERFIT_FACTOR:g}x); "
            "choose its settings from the arcs (--kaula cv, --harmonic cv, --model sh:auto) or "
            "use a smaller model",
            highlight=False,
            soft_wrap=True,
        )
        failed = True
    if failed and strict:
        raise typer.Exit(code=3)


def _weight_or_cv(value: str | None, name: str, metavar: str) -> float | str | None:
    """A --kaula / --harmonic value: None, one weight >= 0, or "cv" (refusing the truth
    scan, which needs a truth: an experiments' option)."""
    if value is None or value == "cv":
        return value
    if value == "scan":
        raise InputError(
            f"{name} scan scored each weight by the field error against the truth (an "
            f"experiments' protocol); choose it from the arcs with {name} cv"
        )
    label = f"{name} (one weight {metavar} >= 0, or 'cv')"
    values = _floats(value, label, 0.0)
    if len(values) != 1:
        raise InputError(f"{label} takes one value, got {value!r}")
    return values[0]


def _check_shells(radii) -> None:
    """Refuse shells so far out that the truth's perturbing potential is lost to round-off
    (see :data:`hamgrav.core.fields.MAX_SHELL_RB`)."""
    from .core.fields import MAX_SHELL_RB

    if max(radii) > MAX_SHELL_RB:
        raise InputError(
            f"--shells (radii r / R_B) must be at most {MAX_SHELL_RB:g}, got {max(radii):g}: "
            "farther out the perturbing potential is below float64 round-off of the total; "
            "give shells within 1000 R_B"
        )


def _file_id(path: Path) -> tuple | None:
    """What tells the file at ``path`` from one written over it (None: no file)."""
    try:
        st = path.stat()
    except OSError:
        return None
    return st.st_dev, st.st_ino, st.st_mtime_ns


def _fit_stopped(exc: BaseException, ckpt: Path, output: Path, written: bool) -> None:
    """End a fit stopped by Ctrl-C, SIGTERM or a disk error, in one line that says what was
    kept: the model when this run ``written`` it whole, else the last complete checkpoint,
    else nothing (and then nothing blocks a plain rerun)."""
    from .io.fit_run import checkpoint_progress

    remove_partial_files()
    how, status = _stopped(exc)
    if written:  # the model is complete: its checkpoint is stale
        ckpt.unlink(missing_ok=True)
        kept = f"the fit is complete and its model written: {output}"
    elif ckpt.exists():
        kept = (
            f"the last checkpoint is kept ({checkpoint_progress(ckpt)}): continue with the same "
            f"command and --resume ({ckpt})"
        )
    else:
        kept = None
    if isinstance(exc, DiskError):  # the disk's error, then what was kept
        kept = kept or "the fit had no checkpoint yet: nothing was saved, run the command again"
        raise DiskError(exc.path, exc.reason, f"{exc.fix}; {kept}") from None
    if isinstance(exc, DistributedError):  # the cluster's error, then what was kept
        kept = kept or "the fit had no checkpoint yet: nothing was saved, run the command again"
        raise DistributedError(f"{exc}; {kept}") from None
    if kept is None:
        text = f"{how} before the first checkpoint; nothing was saved: run the same command again"
    else:
        text = f"{how}; {kept}"
    err.print(text, highlight=False, soft_wrap=True)
    raise typer.Exit(code=status) from None


# ---------------------------------------------------------------------------- evaluate options
JsonOption = Annotated[bool, typer.Option("--json", help="Print one JSON object.")]
TruthArcsOption = Annotated[
    Path | None,
    typer.Option(
        "--arcs",
        help="Arcs whose truth to compare with (default: the fit's); refused unless they "
        "hold the truth the model was fitted against.",
    ),
]
UncertaintyOption = Annotated[
    bool,
    typer.Option(
        "--uncertainty",
        "--sigma",
        help="The formal sigma of the potential on each set, SH or network (and, with a "
        "truth, how well it is calibrated).",
    ),
]
PointsOption = Annotated[
    Path | None,
    typer.Option(
        "--points",
        help="CSV of points [m] in the model's body-fixed frame, header x_m,y_m,z_m: write "
        "the field there to -o (needs no arcs and no truth).",
    ),
]
FieldOutputOption = Annotated[
    Path | None,
    typer.Option("-o", "--output", help="Field CSV written for --points."),
]
FigureOption = Annotated[
    Path | None,
    typer.Option(
        help="PNG of every arc's position and velocity residuals against time in noise "
        "sigmas (arcs without a truth)."
    ),
]


@_command(app)
def evaluate(
    model_file: Annotated[Path, typer.Argument(metavar="MODEL", help="Model file.")],
    shells: Annotated[str, typer.Option(help="Shell radii r / R_B (>= 1).")] = "1.05,1.1,1.2",
    altitude: Annotated[str, typer.Option(help="Surface-following altitudes [m] (>= 0).")] = "30",
    arcs_file: TruthArcsOption = None,
    as_json: JsonOption = False,
    uncertainty: UncertaintyOption = False,
    body: BodyOption = None,
    points_file: PointsOption = None,
    output: FieldOutputOption = None,
    figure: FigureOption = None,
) -> None:
    """Relative field errors of a fitted model against the truth recorded with the arcs.

    Arcs without a truth (imported tracking) give what needs none instead: residuals per arc
    against the noise, a chi-square, and the fitted field on the requested sets; --figure
    draws the residuals. --uncertainty (or --sigma) adds the formal standard deviation of the
    potential, sqrt(g^T C g), with C from the arcs' noise through the fit's normal equations
    (with a network's harmonic penalty when it had one) scaled by the a posteriori variance
    factor (see hamgrav.fit.covariance).

    --points FILE.csv -o FIELD.csv evaluates the model alone at the points of the file (a
    header line x_m,y_m,z_m, then x,y,z [m] per line, in the fit's body-fixed frame) and
    writes x_m, y_m, z_m, the potential potential_m2_s2 (V > 0, GM/r for a point mass), the
    acceleration ax_m_s2, ay_m_s2, az_m_s2 (grad V) and the potential's parts
    potential_central_m2_s2 (GM/r), potential_known_m2_s2 (the known part beyond it, e.g. the
    shape prior) and potential_correction_m2_s2 (the learned term), which add up to
    potential_m2_s2."""
    from .bodies.evaluation import evaluation_sets
    from .io.model_arcs import truth_arcs
    from .io.models import load_model

    if points_file is not None:
        alone = arcs_file is None and not uncertainty and figure is None
        _evaluate_at_points(model_file, points_file, output, as_json, alone)
        return
    if output is not None:
        raise InputError(
            f"-o {output} is the field file of --points; give --points FILE.csv, or leave out -o"
        )
    figure = _output(figure, "--figure", model=model_file, arcs=arcs_file)
    # shells inside R_B cut through the body, where the truth's mascons are singular
    radii = _floats(shells, "--shells (radii r / R_B)", 1.0)
    _check_shells(radii)
    altitudes = _floats(altitude, "--altitude (metres above the surface)", 0.0)
    fitted = load_model(model_file)
    arcs = truth_arcs(fitted, model_file, arcs_file)
    if figure is not None and arcs.has_truth:
        raise InputError(
            f"--figure {figure}: residual figures are drawn for arcs without a truth (imported "
            "tracking), and these arcs hold one; leave out --figure"
        )
    body = _body_for(body, arcs=arcs)
    sets = evaluation_sets(body, radii, altitudes)
    report = _uncertainty(fitted, arcs, body, sets, arcs_file) if uncertainty else None
    if not arcs.has_truth:
        _evaluate_without_truth(model_file, fitted, arcs, sets, as_json, report, figure)
        return
    _evaluate_with_truth(model_file, fitted, arcs, sets, as_json, report)


def _uncertainty(fitted, arcs, body, sets, arcs_file: Path | None) -> dict:
    """evaluate --uncertainty: the formal uncertainty of the potential on ``sets``
    (:func:`hamgrav.fit.covariance.potential_uncertainty`), refused for noise-free arcs."""
    from .fit.covariance import potential_uncertainty
    from .fit.estimator import has_noise

    if not has_noise(arcs):
        raise InputError(
            f"--uncertainty: arcs {arcs_file or fitted.training.get('arcs_file')} record no "
            "tracking noise (noise-free arcs), so the formal errors are undefined; leave out "
            "--uncertainty, or pass --arcs with arcs that have a noise level"
        )
    return potential_uncertainty(fitted, arcs, body, sets)


def _evaluate_with_truth(model_file: Path, fitted, arcs, sets, as_json: bool, uncertainty):
    """The evaluate report of arcs with a truth: the relative field error on each set (and,
    with ``uncertainty``, sigma_V and its calibration), as JSON or a table."""
    from .bodies.evaluation import set_label
    from .core.fields import field_errors

    errors = field_errors(fitted.model, fitted.params, arcs.truth, sets)
    bad = [name for name, value in errors.items() if not math.isfinite(value)]
    if bad:
        raise InputError(
            f"model {model_file} gives a non-finite field error on {', '.join(bad)} (its "
            "potential overflows there); the model is unusable: fit it again"
        )
    if as_json:
        out = {"model": str(model_file), "field_error": errors}
        if uncertainty is not None:
            out["uncertainty"] = uncertainty
        sys.stdout.write(json.dumps(out, allow_nan=False) + "\n")
        return
    table = Table(title=escape(f"relative field error of {model_file} ({fitted.body_name})"))
    table.add_column("evaluation set")
    table.add_column("epsilon", justify="right")
    if uncertainty is not None:
        for col in ("RMS sigma_V", "RMS error / sigma_V", "1 / 2 sigma"):
            table.add_column(escape(col), justify="right")
    for name, value in errors.items():
        cells = [set_label(name), f"{value:.4f}"]
        if uncertainty is not None:
            u = uncertainty[name]
            cells += [
                f"{u['rms_sigma_v_m2_s2']:.3g}",
                f"{u['rms_z']:.3g}",
                f"{u['within_1_sigma']:.2f} / {u['within_2_sigma']:.2f}",
            ]
        table.add_row(*cells)
    console.print(table)
    if uncertainty is not None:
        console.print(_covariance_note(uncertainty["covariance"]), highlight=False)
        console.print(
            escape(
                "sigma_V [m^2/s^2]: formal, from the tracking noise (anchors included) scaled "
                "by the a posteriori variance factor; 1 / 2 sigma: the fractions of points whose "
                "error is within 1 and 2 sigma_V, 0.68 and 0.95 when sigma_V is honest (fewer: "
                "model error, e.g. omitted degrees, dominates)"
            ),
            highlight=False,
        )


def _covariance_note(c: dict) -> str:
    """One line on a formal covariance: rank per member and variance factors."""
    ranks = "/".join(map(str, c["ranks"]))
    factors = "/".join(f"{f:.3g}" for f in c["variance_factors"])
    members = f" (each of {c['members']} members)" if c["members"] > 1 else ""
    penalty = " by the arcs and the harmonic penalty" if c.get("harmonic_penalty") else ""
    return (
        f"formal covariance: {ranks} of {c['parameters_per_member']} parameter directions "
        f"constrained{penalty}{members}, a posteriori variance factor {factors}"
    )


NO_TRUTH_NOTE = (
    "these arcs carry no truth (imported tracking): relative field errors need simulated "
    "arcs ('hamgrav simulate')"
)


def _evaluate_at_points(
    model_file: Path, points_file: Path, output: Path | None, as_json: bool, alone: bool
):
    """evaluate --points: the field of the model at the points of ``points_file`` [m],
    written as CSV to ``output`` (columns in :func:`evaluate`'s docstring); refused unless
    ``alone`` (no --arcs, --uncertainty or --figure given)."""
    import numpy as np

    from .io.models import load_model
    from .io.points import read_points_csv, write_columns_csv

    if not alone:
        raise InputError(
            "--points evaluates the model alone at the points; leave out --arcs, "
            "--uncertainty and --figure, or run evaluate without --points for them"
        )
    if output is None:
        raise InputError(f"--points {points_file} needs -o FIELD.csv, the file to write")
    output = _output(output, "-o", model=model_file, points=points_file)
    fitted = load_model(model_file)
    points, lines = read_points_csv(points_file)
    parts = {name: fitted.potential(points, name) for name in ("central", "known", "correction")}
    columns = {"x_m": points[:, 0], "y_m": points[:, 1], "z_m": points[:, 2]}
    columns["potential_m2_s2"] = fitted.potential(points)
    acceleration = fitted.acceleration(points)
    columns.update({f"a{axis}_m_s2": acceleration[:, c] for c, axis in enumerate("xyz")})
    columns.update({f"potential_{name}_m2_s2": values for name, values in parts.items()})
    finite = np.isfinite(np.column_stack(list(columns.values()))).all(axis=1)
    if not finite.all():
        k = int(np.argmin(finite))
        raise InputError(
            f"{points_file} line {lines[k]}: model {model_file} has no finite field at "
            f"({', '.join(f'{v:g}' for v in points[k])}) m (the origin, or a point mass of the "
            "model); remove the point"
        )
    write_columns_csv(output, columns)
    if as_json:
        out = {"model": str(model_file), "points": str(points_file), "output": str(output)}
        sys.stdout.write(json.dumps({**out, "n_points": len(points)}) + "\n")
    else:
        console.print(f"wrote the field at {len(points)} points to {output}", highlight=False)


def _evaluate_without_truth(
    model_file, fitted, arcs, sets, as_json: bool, uncertainty, figure: Path | None = None
) -> None:
    """The evaluate report of arcs without a truth: residuals, chi-square, fitted field;
    with ``figure``, the residuals against time drawn there (PNG)."""
    from .fit.residuals import field_summary, residual_report, residual_series

    series = residual_series(fitted, arcs)
    report = residual_report(fitted, arcs, series)
    field = field_summary(fitted, sets)
    if figure is not None:
        from .report.figures import residual_figure
        from .report.writer import save_figure

        drawn = residual_figure(
            series.time_s,
            series.position_m / arcs.sigma_r_m,
            series.velocity_m_s / arcs.sigma_v_m_s,
            title=f"residuals of {model_file.name} on {arcs.n_arcs} arcs (no truth)",
        )
        save_figure(drawn, figure)
    if as_json:
        out = {
            "model": str(model_file),
            "field_error": None,
            "note": NO_TRUTH_NOTE,
            "residuals": report,
            "field": field,
        }
        if figure is not None:
            out["figure"] = str(figure)
        if uncertainty is not None:
            out["uncertainty"] = uncertainty
        sys.stdout.write(json.dumps(out, allow_nan=False) + "\n")
        return
    _print_residuals(model_file, arcs, report)
    _print_fitted_field(field, uncertainty)
    if figure is not None:
        console.print(f"wrote the residual figure {figure}", highlight=False)
    console.print(NO_TRUTH_NOTE, highlight=False)


def _print_residuals(model_file: Path, arcs, report: dict) -> None:
    """The residual table and chi-square line of evaluate on arcs without a truth."""
    import numpy as np

    rp, rv = np.asarray(report["rms_position_m"]), np.asarray(report["rms_velocity_mm_s"])
    table = Table(title=escape(f"residuals of {model_file} on {arcs.n_arcs} arcs (no truth)"))
    table.add_column("quantity")
    table.add_column("median", justify="right")
    table.add_column("max", justify="right")
    table.add_column("noise sigma", justify="right")
    table.add_row(
        escape("RMS position residual [m]"),
        f"{np.median(rp):.4g}",
        f"{rp.max():.4g}",
        f"{report['sigma_r_m']:.4g}",
    )
    table.add_row(
        escape("RMS velocity residual [mm/s]"),
        f"{np.median(rv):.4g}",
        f"{rv.max():.4g}",
        f"{report['sigma_v_mm_s']:.4g}",
    )
    console.print(table)
    console.print(
        f"chi2 {report['chi2']:.6g} on {report['dof']} degrees of freedom: "
        f"chi2/dof {report['chi2_per_dof']:.4g} (no correction: "
        f"{report['chi2_per_dof_no_correction']:.4g}); about 1 when the model explains the "
        "arcs down to the noise (white noise and each arc's noisy first sample)",
        highlight=False,
    )


def _print_fitted_field(field: dict, uncertainty: dict | None) -> None:
    """The fitted field's RMS table of evaluate on arcs without a truth (with sigma_V and
    the covariance note when ``uncertainty`` is given)."""
    from .bodies.evaluation import set_label

    table = Table(title="fitted field (RMS over each set)")
    columns = ["evaluation set", "perturbing V [m^2/s^2]", "learned V [m^2/s^2]"]
    columns += ["perturbing |a| [m/s^2]"] + (["sigma_V [m^2/s^2]"] if uncertainty else [])
    for col in columns:
        table.add_column(escape(col), justify="right")
    for name, row in field.items():
        learned = row.get("rms_learnable_potential_m2_s2")
        cells = [
            set_label(name),
            f"{row['rms_perturbing_potential_m2_s2']:.4g}",
            "-" if learned is None else f"{learned:.4g}",
            f"{row['rms_perturbing_acceleration_m_s2']:.4g}",
        ]
        if uncertainty:
            cells.append(f"{uncertainty[name]['rms_sigma_v_m2_s2']:.3g}")
        table.add_row(*cells)
    console.print(table)
    if uncertainty:
        console.print(_covariance_note(uncertainty["covariance"]), highlight=False)


@_command(app, "export")
def export_command(
    model_file: Annotated[Path, typer.Argument(metavar="MODEL", help="Model file.")],
    fmt: Annotated[
        str, typer.Option("--format", help="icgem or shadr (SH coefficients), json (network).")
    ],
    output: Annotated[Path, typer.Option("-o", "--output", help="File to write.")],
    degree: Annotated[
        int | None,
        typer.Option(help="SH degree (default: the SH model's; 8 for a projected network)."),
    ] = None,
    arcs_file: Annotated[
        Path | None,
        typer.Option("--arcs", help="Arcs for the formal errors (default: the fit's arcs)."),
    ] = None,
    errors: Annotated[
        bool, typer.Option(help="Write formal errors of SH models (needs the fit's arcs).")
    ] = True,
    body: BodyOption = None,
) -> None:
    """Write a model for other tools: SH coefficients (ICGEM, SHADR) or a network (JSON).

    ICGEM and SHADR hold the whole potential (central term C00 = 1, the known part such as
    a shape prior, the learned correction) as fully normalised coefficients with GM [m^3/s^2]
    and the reference radius [m]; a network is projected on the sphere at the reference
    radius (the Brillouin radius). JSON holds a network's layers with the known part."""
    from .io.models import load_model

    fmt = fmt.lower()
    if fmt not in ("icgem", "shadr", "json"):
        raise InputError(f"--format must be icgem, shadr or json, got {fmt!r}")
    if degree is not None:
        _number(degree, "--degree", 2, integer=True)
        if degree > MAX_SH_DEGREE:
            raise InputError(f"--degree must be at most {MAX_SH_DEGREE}, got {degree}")
    _output(output, MODEL=model_file, **{"--arcs": arcs_file})
    fitted = load_model(model_file)
    if fmt == "json":
        from .io.network_json import write_network_json

        write_network_json(fitted, output)
        console.print(f"wrote {output}: the network and the known part, canonical units")
        return
    from .io.model_arcs import sh_formal_covariance
    from .io.shformats import model_export, write_icgem, write_shadr

    # an SH model is exported at its own degree and radius, with its formal errors
    is_sh = fitted.sh_expansion() is not None
    body_obj = None if is_sh else _body_for(body, fitted=fitted)
    covariance, note = None, "no formal errors (--no-errors)"
    if errors and is_sh:
        covariance, note = sh_formal_covariance(fitted, arcs_file)
    elif errors:
        note = "no formal errors: they are computed for SH models only"
    export = model_export(fitted, degree=degree, body=body_obj, covariance=covariance)
    if fmt == "icgem":
        write_icgem(export, output, source=str(model_file))
    else:
        write_shadr(export, output)
    _say_exported(export, output, note)


def _say_exported(export, output: Path, note: str) -> None:
    """What export wrote: degree, GM, reference radius, contents and accuracy."""
    console.print(
        f"wrote {output}: degree {export.degree}, GM {export.gm_m3_s2:.10g} m^3/s^2, reference "
        f"radius {export.reference_radius_m:.10g} m, fully normalised, C00 = 1 (central term "
        f"included), {note}",
        highlight=False,
    )
    for line in export.contents:
        console.print(f"  {line}", highlight=False)
    for name, value in export.accuracy.items():
        console.print(
            f"  relative RMS difference from hamgrav's perturbing potential on r = {name[1:-1]} R:"
            f" {value:.3e}",
            highlight=False,
        )


@_command(app)
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
    body: BodyOption = None,
    max_memory: MaxMemoryOption = None,
) -> None:
    """D-optimal choice of the next orbits from a candidate pool, from predicted sensitivities
    at the current model (no measurements, no truth)."""
    from .files import atomic_path
    from .fit.design import select_orbits
    from .io.models import load_model
    from .sim.campaign import load_campaign
    from .sizing import memory_limit

    _number(picks, "--picks", 1, integer=True)
    _seed(seed)
    limit = memory_limit(max_memory)
    _output(output, MODEL=model_file, **{"--pool": pool})
    fitted = load_model(model_file)
    config = load_campaign(pool)
    body_obj = _body_for(body, fitted=fitted)
    _check_pool(config, pool, fitted, model_file, body_obj, picks, limit)
    with _progress() as progress:
        progress.add_task(f"predicting {len(config.families)} candidate orbits", total=None)
        rows = select_orbits(
            fitted,
            list(config.families),
            config.tracking,
            brillouin_radius=body_obj.brillouin_radius,
            picks=picks,
            seed=seed,
        )
    console.print(_picks_table(rows))
    if output is not None:
        text = json.dumps({"model": str(model_file), "picks": rows}, indent=2, allow_nan=False)
        with atomic_path(output) as tmp:
            tmp.write_text(text + "\n")


def _check_pool(config, pool: Path, fitted, model_file: Path, body_obj, picks: int, limit):
    """Refuse a select pool of another body than the model's (another shape), fewer
    candidates than --picks, or more memory than ``limit`` [bytes]."""
    from .sizing import check_memory, pool_bytes

    if config.body != fitted.body_name and (
        load_body(config.body).mesh_sha256 != body_obj.mesh_sha256
    ):
        raise InputError(
            f"the pool {pool} is for body {config.body!r}, the model {model_file} for "
            f"{fitted.body_name!r} (another shape)"
        )
    if picks > len(config.families):
        raise InputError(
            f"--picks {picks} is more than the {len(config.families)} candidate orbits of "
            f"the pool {pool}"
        )
    tracking = config.tracking
    check_memory(
        f"choosing from the pool {pool}",
        pool_bytes(
            len(config.families),
            tracking.arcs_per_orbit,
            tracking.samples_per_arc,
            fitted.model.n_learn,
        ),
        limit,
        "lower [orbits] count, [tracking] arcs_per_orbit or samples_per_arc of the pool",
    )


def _picks_table(rows: list[dict]) -> Table:
    """The table of select's D-optimal picks."""
    table = Table(title="D-optimal picks (log det of the accumulated information)")
    for col in ("pick", "candidate", "r / R_B", "incl. [deg]", "gain", "log det", "random order"):
        table.add_column(escape(col), justify="right")
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
    return table


# ------------------------------------------------------------------------------ experiments
experiment_app = typer.Typer(
    help="Experiments of the paper (write results/<name>/).",
    no_args_is_help=True,
    rich_markup_mode=None,
)
app.add_typer(experiment_app, name="experiment")


def _run_and_report(
    experiment,
    config,
    *,
    seed,
    repeat,
    output,
    workers,
    scheduler,
    command,
    max_memory=None,
    distribute_fits=False,
):
    from .experiments.runner import run_experiment

    report, outputs = run_experiment(
        experiment,
        config,
        seed=seed,
        repeat=repeat,
        output=output,
        workers=workers,
        scheduler=scheduler,
        command=command,
        say=_say,
        max_memory=max_memory,
        distribute_fits=distribute_fits,
    )
    return report, outputs


def _experiment_command(experiment):
    """A typer command for ``experiment`` whose options are its config's fields."""
    config_type = experiment.config_type
    defaults = experiment.default_config()

    def command(**kwargs):
        given = dict(kwargs)
        runner = {
            k: kwargs.pop(k)
            for k in (
                "config",
                "seed",
                "repeat",
                "output",
                "workers",
                "scheduler",
                "max_memory",
                "distribute_fits",
            )
        }
        given.pop("max_memory")  # a limit of this machine, not of the results: not recorded
        given["output"] = runner["output"] or experiment.default_output
        for name, default in (("repeat", 1), ("workers", 0), ("distribute_fits", False)):
            if given[name] == default:
                given[name] = None
        base = config_type.from_toml(runner["config"]) if runner["config"] else defaults
        from .experiments.config import COMMAND_LINE

        config = base.updated(kwargs, COMMAND_LINE)
        output = runner["output"] or Path(experiment.default_output)
        if output.exists() and not output.is_dir():
            raise InputError(f"-o {output} exists and is not a folder; give a folder path")
        check_writable_folder(output, "-o")
        _number(runner["repeat"], "--repeat", 1, integer=True)
        _seed(runner["seed"], count=runner["repeat"])
        _number(runner["workers"], "--workers", 0, integer=True)
        report, _ = _run_and_report(
            experiment,
            config,
            seed=runner["seed"],
            repeat=runner["repeat"],
            output=output,
            workers=runner["workers"],
            scheduler=runner["scheduler"],
            command=_command_line(["experiment", experiment.name], given),
            max_memory=runner["max_memory"],
            distribute_fits=runner["distribute_fits"],
        )
        console.print(f"wrote {output}/results.json, README.md and figures ({report['wall_s']} s)")

    params = _experiment_params(experiment)
    command.__signature__ = inspect.Signature(params)
    command.__annotations__ = {p.name: p.annotation for p in params}
    command.__doc__ = experiment.title
    return command


# The runner's options of every experiment command: (name, type, default, help); {output}
# is the experiment's default output folder.
RUNNER_OPTIONS = (
    ("config", Path | None, None, "Config file (TOML); options given here override it."),
    ("seed", int, 0, "First seed; repetitions use seed, seed+1, ..."),
    ("repeat", int, 1, "Repetitions (seeds redraw truth mascons, orbits, noise, descents)."),
    ("output", Path | None, None, "Output folder [default: {output}]."),
    ("workers", int, 0, "Run on a Dask LocalCluster of N worker processes (0: in-process)."),
    ("scheduler", str | None, None, "Address of an existing Dask scheduler."),
    (
        "distribute_fits",
        bool,
        False,
        "Send each fit's arcs to the cluster's workers, which compute its sums over arcs "
        "(with --workers or --scheduler; numbers as in-process, to rounding).",
    ),
    (
        "max_memory",
        str | None,
        None,
        "Refuse the run before it starts if the repetitions that run at once need more "
        "memory than this (e.g. 8GiB; default: the memory available now; per worker with "
        "--scheduler, where nothing is checked without it).",
    ),
)


def _experiment_params(experiment) -> list[inspect.Parameter]:
    """The options of an experiment's command: one per field of its config (default None:
    the config's own), then the runner's (config file, seed, repeat, output, workers,
    scheduler, max memory)."""
    import dataclasses

    config_type = experiment.config_type
    types_ = config_type.field_types()
    defaults = experiment.default_config()
    params = []
    for f in dataclasses.fields(config_type):
        kind = types_[f.name]
        default = getattr(defaults, f.name)
        shown = ",".join(map(str, default)) if isinstance(default, tuple) else default
        params.append(
            inspect.Parameter(
                f.name,
                inspect.Parameter.KEYWORD_ONLY,
                default=None,
                annotation=Annotated[
                    str | None if isinstance(default, tuple) else kind | None,
                    typer.Option(help=f"{f.metadata.get('help', '')} [default: {shown}]"),
                ],
            )
        )
    for name, kind, default, text in RUNNER_OPTIONS:
        text = text.replace("{output}", str(experiment.default_output))
        opt = (
            typer.Option("-o", "--output", help=text)
            if name == "output"
            else typer.Option(help=text)
        )
        params.append(
            inspect.Parameter(
                name,
                inspect.Parameter.KEYWORD_ONLY,
                default=default,
                annotation=Annotated[kind, opt],
            )
        )
    return params


@_command(experiment_app, "readme")
def experiment_readme(
    folder: Annotated[Path, typer.Argument(help="A results folder holding results.json.")],
) -> None:
    """Write a results folder's README.md again from its results.json (no computation)."""
    from .experiments.runner import rerender_readme

    path = rerender_readme(folder)
    console.print(f"wrote {path}")


@_command(experiment_app, "merge")
def experiment_merge(
    folders: Annotated[
        list[Path], typer.Argument(help="Results folders of one experiment and config.")
    ],
    output: Annotated[Path, typer.Option("-o", "--output", help="Folder to write.")],
) -> None:
    """Merge runs of one experiment and config on other seeds into one results folder (as
    one run of all their seeds: results.json, README and the figures)."""
    from .experiments.runner import merge_reports

    if output.exists() and not output.is_dir():
        raise InputError(f"-o {output} exists and is not a folder; give a folder path")
    check_writable_folder(output, "-o")
    path = merge_reports(folders, output)
    console.print(f"wrote {path}")


def _register_experiments() -> None:
    from .experiments.runner import experiment_names, get_experiment

    for name in experiment_names():
        experiment = get_experiment(name)
        _command(experiment_app, name)(_experiment_command(experiment))


with _DeferInterrupt():  # imports the experiments (and with them the numerical core)
    _register_experiments()


@_command(app)
def demo(
    output: Annotated[Path, typer.Option("-o", "--output", help="Folder for the outputs.")] = Path(
        "demo-output"
    ),
    seed: Annotated[int, typer.Option(help="Campaign seed.")] = 0,
) -> None:
    """The descent-planning pipeline on the synthetic contact binary (no data folder needed).

    Head twice as dense as the body; 12 orbits x 7 arcs kept above the Brillouin sphere; a
    353-parameter network (Adam, and Levenberg-Marquardt) against SH 4 and 8, from tracking
    alone and as residuals on the constant-density shape prior; 12 descents from 1.3 R_B.
    Writes the results, a README, the figures and the arcs (HDF5 and CCSDS OEM) to OUTPUT.
    """
    from .experiments.descent import DescentExperimentConfig
    from .experiments.runner import get_experiment
    from .io.arcs import save_arcs
    from .io.oem import export_oem_by_trajectory

    _seed(seed)
    if output.exists() and not output.is_dir():
        raise InputError(f"-o {output} exists and is not a folder; give a folder path")
    check_writable_folder(output, "-o")
    report, outputs = _run_and_report(
        get_experiment("descent"),
        DescentExperimentConfig.demo(),
        seed=seed,
        repeat=1,
        output=output,
        workers=0,
        scheduler=None,
        command=_command_line(["demo"], {"seed": seed, "output": output}),
    )
    arcs = outputs[0].artefacts["arcs"]
    save_arcs(arcs, output / "arcs.h5")
    export_oem_by_trajectory(arcs, _output_folder(output / "oem", "the OEM folder"))
    result = report["repetitions"][0]
    console.print(_demo_table(result))
    console.print(
        "field errors: relative error of the perturbing potential (1 = no correction); "
        "r = shells in R_B, h30m = 30 m above the surface; misses: distance between the "
        "touchdown point each model predicts and the true one; rows named shape...: the "
        "imaged shape at constant density (known physics) alone, and models of the residual "
        "on it"
    )
    from .report.descent import data_coverage

    coverage = data_coverage(result, DescentExperimentConfig.demo().altitude_m)
    if coverage:
        console.print(coverage, highlight=False)
    captions = get_experiment("descent").figure_captions
    for name in report.get("figures", []):
        console.print(f"{output / name}: {captions.get(name, '')}", highlight=False)
    console.print(
        f"wrote {output}/README.md, results.json, the figures, arcs.h5 (the arcs) and oem/ "
        f"(CCSDS OEM, one file per orbit) in {report['wall_s']:.0f} s"
    )


def _demo_table(result: dict) -> Table:
    """The demo's table: field errors and descent misses per model."""
    table = Table(title="synthetic contact binary: models fitted to the tracking")
    for col in ("model", "r1.05", "r1.2", "r1.5", "h30m", "median miss [m]", "worst [m]", "landed"):
        table.add_column(escape(col), justify="right", no_wrap=col == "model")
    for name, st in result["models"].items():
        fe = result["field_error"][name]
        cells = ["-" if st[k] is None else f"{st[k]:.1f}" for k in ("median_m", "worst_m")]
        table.add_row(
            name,
            *(f"{fe[k]:.3f}" for k in ("r1.05", "r1.2", "r1.5", "h30m")),
            *cells,
            f"{st['landed']}/{st['total']}",
        )
    return table


def main(args: list[str] | None = None) -> None:
    """The ``hamgrav`` console script: :data:`app`, with Ctrl-C and SIGTERM held while typer
    builds the command from its functions (as while the libraries load), where a Ctrl-C
    showed typer's traceback."""
    with _DeferInterrupt():
        command = typer.main.get_command(app)
    command(args, prog_name="hamgrav")


if __name__ == "__main__":
    main()
