"""Property-based fuzz of every reader and of the command line's option parsing.

Each case either raises a :class:`~hamgrav.errors.HamgravError` whose message names the file
(or option), or returns exactly what was written (or, for a file without its checksum, which
is how files of older hamgrav look, valid values with a warning). Any other exception fails
the test, and so does a reader returning something else than what was written: silent
acceptance of damaged data. Example counts are bounded so that the module runs in well under
a minute on two cores; the number of cases run is printed at the end of the module.
"""

import functools
import gzip
import itertools
import json
import math
import shutil
import tempfile
import warnings
from collections import Counter
from dataclasses import replace
from pathlib import Path

import h5py
import numpy as np
import pytest
import typer
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hamgrav.bodies.catalogue import load_body
from hamgrav.bodies.interiors import _read_mascon_csv
from hamgrav.cli import app
from hamgrav.core.arcs import MAX_SEED, Arcs
from hamgrav.core.fields import MAX_SHELL_RB
from hamgrav.core.mascons import MasconSet
from hamgrav.core.model import Model
from hamgrav.core.terms import PointMass, SphericalHarmonics
from hamgrav.errors import HamgravError, HamgravWarning
from hamgrav.fit.fitted import FittedModel
from hamgrav.io.arcs import MAX_STATE, load_arcs, save_arcs
from hamgrav.io.models import load_checkpoint, load_model, save_checkpoint, save_model
from hamgrav.sim.campaign import Campaign, load_campaign
from hamgrav.sim.tracking import MAX_ORBIT_RADIUS_RB

FUZZ = settings(
    max_examples=600,
    deadline=None,
    derandomize=True,  # the same cases on every run: a failure is reproducible
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
CASES: Counter = Counter()
runner = CliRunner()
#: The click command built once: typer's runner would rebuild every command per invocation.
COMMAND = typer.main.get_command(app)
_BASE = tempfile.TemporaryDirectory(prefix="hamgrav-fuzz-")
_SERIAL = itertools.count()


def _fresh_folder() -> Path:
    """A new empty folder for one case; the previous case's folder is removed (the
    reference files' folder, the first, is kept)."""
    serial = next(_SERIAL)
    folder = Path(_BASE.name) / str(serial)
    if serial > 1:
        shutil.rmtree(Path(_BASE.name) / str(serial - 1), ignore_errors=True)
    folder.mkdir()
    return folder


@pytest.fixture(scope="module", autouse=True)
def _report_cases(request):
    _originals()  # folder 0
    yield
    _BASE.cleanup()
    total = sum(CASES.values())
    line = f"fuzz cases run: {total} (" + ", ".join(f"{k} {v}" for k, v in CASES.items()) + ")"
    capture = request.config.pluginmanager.get_plugin("capturemanager")
    reporter = request.config.pluginmanager.get_plugin("terminalreporter")
    if capture is not None and reporter is not None:
        with capture.global_and_fixture_disabled():
            reporter.write_line("")
            reporter.write_line(line)


# ------------------------------------------------------------------------------ reference data
def _arcs() -> Arcs:
    rng = np.random.default_rng(3)
    times = np.cumsum(rng.uniform(0.01, 0.02, size=(3, 5)), axis=1)
    states = rng.uniform(-2.0, 2.0, size=(3, 5, 6))
    return Arcs(
        times=times,
        states=states,
        true_states=states + 1e-4,
        trajectory=np.array([0, 0, 1], dtype=np.int64),
        trajectory_kind=("orbit", "orbit"),
        trajectory_info={"radius_rb": np.array([1.5, 2.0]), "initial_state": states[:2, 0]},
        body_name="synthetic",
        gm_m3_s2=2.5,
        spin_period_s=43200.0,
        body_origin_m=(0.5, -0.25, 0.0),
        sigma_r_m=0.05,
        sigma_v_m_s=1e-6,
        truth=MasconSet(rng.normal(size=(4, 3)) * 0.1, np.full(4, 0.25)),
        interior="uniform",
        interior_parameters={"contrast": 1.0},
        seed=3,
        config={"body": "synthetic", "seed": 3},
    )


def _fitted() -> FittedModel:
    rng = np.random.default_rng(4)
    return FittedModel(
        model=Model((PointMass(),), SphericalHarmonics(2, 0.7)),
        params=rng.normal(size=5) * 1e-3,
        body_name="synthetic",
        gm_m3_s2=2.5,
        spin_period_s=43200.0,
        body_origin_m=(0.5, -0.25, 0.0),
        solver={"name": "levenberg-marquardt", "arcs_file": "/data/arcs.h5"},
        history={"cost": [3.0, 2.0, 1.0]},
        training={"arcs_sha256": "ab" * 32, "truth_sha256": "cd" * 32},
    )


ARCS = _arcs()
FITTED = _fitted()


@functools.cache
def _originals() -> dict[str, bytes]:
    """The bytes of an untouched arcs file, model file and checkpoint (written once; not a
    fixture, so that a failing case does not print them)."""
    folder = _fresh_folder()
    arcs = save_arcs(ARCS, folder / "arcs.h5").read_bytes()
    model = save_model(FITTED, folder / "model.h5").read_bytes()
    state = {"solver": "adam", "step": 3, "m": np.ones(5), "best_val": np.float64(np.inf)}
    ckpt = save_checkpoint(folder / "c.npz", FITTED.params, state, {"solver": "adam"})
    return {"arcs": arcs, "model": model, "checkpoint": ckpt.read_bytes()}


def _same_arcs(a: Arcs, b: Arcs) -> bool:
    arrays = ("times", "states", "true_states", "trajectory")
    same = all(np.array_equal(getattr(a, k), getattr(b, k)) for k in arrays)
    same &= np.array_equal(a.truth.positions, b.truth.positions)
    same &= np.array_equal(a.truth.masses, b.truth.masses)
    same &= a.trajectory_info.keys() == b.trajectory_info.keys() and all(
        np.array_equal(a.trajectory_info[k], b.trajectory_info[k]) for k in a.trajectory_info
    )
    meta = (
        "body_name",
        "gm_m3_s2",
        "spin_period_s",
        "body_origin_m",
        "sigma_r_m",
        "sigma_v_m_s",
        "interior",
        "interior_parameters",
        "seed",
        "config",
        "trajectory_kind",
    )
    return bool(same) and all(getattr(a, k) == getattr(b, k) for k in meta)


def _valid_arcs(a: Arcs) -> bool:
    """What every accepted arcs file must satisfy, checksum or not."""
    return bool(
        np.all(np.isfinite(a.states))
        and np.all(np.isfinite(a.true_states))
        and np.max(np.abs(a.states)) <= MAX_STATE
        and np.all(np.diff(a.times, axis=1) > 0)
        and a.gm_m3_s2 > 0
        and a.spin_period_s > 0
        and math.isfinite(a.gm_m3_s2 + a.spin_period_s + a.sigma_r_m + a.sigma_v_m_s)
        and np.all(np.isfinite(a.truth.masses))
    )


def _same_fitted(a: FittedModel, b: FittedModel) -> bool:
    return (
        a.model.key() == b.model.key()
        and np.array_equal(a.params, b.params)
        and all(
            getattr(a, k) == getattr(b, k)
            for k in (
                "body_name",
                "gm_m3_s2",
                "spin_period_s",
                "body_origin_m",
                "estimate_trajectory_params",
                "prior",
                "solver",
                "history",
                "stages",
                "training",
            )
        )
    )


def _valid_fitted(a: FittedModel) -> bool:
    return bool(
        np.all(np.isfinite(a.params))
        and a.gm_m3_s2 > 0
        and a.spin_period_s > 0
        and np.all(np.isfinite(a.body_origin_m))
    )


def _outcome(read, path: Path):
    """(value or None, warned, error or None) of ``read(path)``; a non-hamgrav exception
    propagates and fails the test."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            value = read(path)
        except HamgravError as exc:
            assert str(path) in str(exc), f"the error does not name the file: {exc}"
            assert "\n" not in str(exc), f"not one line: {exc!r}"
            return None, False, exc
    warned = any(issubclass(w.category, HamgravWarning) for w in caught)
    return value, warned, None


# ------------------------------------------------------------------------------ mutations
BAD_VALUES = st.sampled_from(
    [
        np.nan,
        np.inf,
        -np.inf,
        1e182,
        -1.0,
        0.0,
        "text",
        True,
        np.arange(7.0),
        np.zeros((2, 2, 2)),
        np.array([b"a", b"b"]),
        np.array([], dtype=float),
        None,  # delete it
    ]
)


@st.composite
def byte_damage(draw, size: int):
    """A truncation, flipped bytes or an overwritten range of a file of ``size`` bytes."""
    kind = draw(st.sampled_from(["truncate", "flip", "overwrite"]))
    if kind == "truncate":
        return kind, draw(st.integers(0, size - 1))
    if kind == "flip":
        flips = st.tuples(st.integers(0, size - 1), st.integers(1, 255))
        return kind, draw(st.lists(flips, min_size=1, max_size=8))
    start = draw(st.integers(0, size - 1))
    return kind, (start, draw(st.binary(min_size=1, max_size=64)))


def _damage(data: bytes, damage) -> bytes:
    kind, arg = damage
    if kind == "truncate":
        return data[:arg]
    out = bytearray(data)
    if kind == "flip":
        for offset, mask in arg:
            out[offset] ^= mask
    else:
        start, chunk = arg
        out[start : start + len(chunk)] = chunk
        out = out[: len(data)]
    return bytes(out)


def _without_checksum(path: Path) -> None:
    """Rewrite a hamgrav HDF5 file as an older hamgrav wrote it: no checksum user block."""
    tmp = path.with_name(path.name + ".old")
    with h5py.File(path, "r") as src, h5py.File(tmp, "w") as dst:
        dst.attrs.update(dict(src.attrs))
        for name in src:
            src.copy(src[name], dst, name=name)
    tmp.replace(path)


def _set_h5(path: Path, name: str, value, keep_checksum: bool) -> None:
    """Replace (or delete, ``value`` None) attribute ``@name`` or dataset ``name``; without
    ``keep_checksum`` the file is first made an old-style file (no checksum), so that the
    reader's value checks are what refuses it."""
    if not keep_checksum:
        _without_checksum(path)
    with h5py.File(path, "a") as f:
        if name.startswith("@"):
            key = name[1:]
            if key in f.attrs:
                del f.attrs[key]
            if value is not None:
                f.attrs[key] = value
        else:
            if name in f:
                old = np.asarray(f[name][()]) if isinstance(f[name], h5py.Dataset) else np.zeros(0)
                del f[name]
                if value is not None and isinstance(value, float) and old.size:
                    old = old.astype(float)
                    old.flat[0] = value
                    value = old
            if value is not None:
                f[name] = value


FOREIGN = st.one_of(
    st.binary(max_size=256).map(lambda b: ("bytes", b)),
    st.just(("hdf5", None)),
    st.just(("folder", None)),
    st.just(("other-kind", None)),
)


def _foreign(path: Path, foreign, originals, other: str) -> None:
    kind, data = foreign
    if kind == "bytes":
        path.write_bytes(data)
    elif kind == "hdf5":
        with h5py.File(path, "w") as f:
            f["x"] = np.arange(3)
            f.attrs["format"] = "something"
    elif kind == "folder":
        path.mkdir()
    else:
        path.write_bytes(originals[other])


def _file_case(originals, kind, names, other, data):
    """Write the case's file into a fresh folder and return its path."""
    folder = Path(_fresh_folder())
    path = folder / f"{kind}.h5"
    mode = data.draw(st.sampled_from(["bytes", "value", "foreign"]), label="mode")
    if mode == "bytes":
        original = originals[kind]
        path.write_bytes(_damage(original, data.draw(byte_damage(len(original)))))
    elif mode == "value":
        path.write_bytes(originals[kind])
        name = data.draw(st.sampled_from(names), label="target")
        value = data.draw(BAD_VALUES, label="value")
        keep = data.draw(st.booleans(), label="keep checksum")
        _set_h5(path, name, value, keep_checksum=keep)
    else:
        _foreign(path, data.draw(FOREIGN, label="foreign"), originals, other)
    return path, mode


ARCS_NAMES = [
    "times",
    "states",
    "true_states",
    "trajectory",
    "truth/positions",
    "truth/masses",
    "trajectory_info",
    "@format",
    "@format_version",
    "@gm_m3_s2",
    "@spin_period_s",
    "@body_origin_m",
    "@sigma_r_m",
    "@sigma_v_m_s",
    "@config",
    "@trajectory_kind",
    "@interior_parameters",
    "@seed",
]


@FUZZ
@given(data=st.data())
def test_fuzz_arcs_reader(data):
    path, mode = _file_case(_originals(), "arcs", ARCS_NAMES, "model", data)
    CASES["arcs files"] += 1
    value, warned, error = _outcome(load_arcs, path)
    if error is None:
        assert _same_arcs(value, ARCS) or (warned and _valid_arcs(value)), (
            f"silently accepted a damaged arcs file ({mode})"
        )


MODEL_NAMES = [
    "params",
    "history",
    "history/cost",
    "@format",
    "@format_version",
    "@model",
    "@structure_key",
    "@gm_m3_s2",
    "@spin_period_s",
    "@body_origin_m",
    "@solver",
    "@stages",
    "@training",
    "@estimate_trajectory_params",
]


@FUZZ
@given(data=st.data())
def test_fuzz_model_reader(data):
    path, mode = _file_case(_originals(), "model", MODEL_NAMES, "arcs", data)
    CASES["model files"] += 1
    value, warned, error = _outcome(load_model, path)
    if error is None:
        assert _same_fitted(value, FITTED) or (warned and _valid_fitted(value)), (
            f"silently accepted a damaged model file ({mode})"
        )


@settings(FUZZ, max_examples=300)
@given(data=st.data())
def test_fuzz_checkpoint_reader(data):
    folder = Path(_fresh_folder())
    path = folder / "c.npz"
    mode = data.draw(st.sampled_from(["bytes", "params", "identity", "foreign"]))
    expect = {"solver": "adam"}
    originals = _originals()
    if mode == "bytes":
        original = originals["checkpoint"]
        path.write_bytes(_damage(original, data.draw(byte_damage(len(original)))))
    elif mode == "params":
        params = FITTED.params.copy()
        params[data.draw(st.integers(0, 4))] = data.draw(st.sampled_from([np.nan, np.inf]))
        save_checkpoint(path, params, {"solver": "adam"}, expect)
    elif mode == "identity":
        other = data.draw(st.sampled_from([{"solver": "lm"}, {"solver": "adam", "steps": 9}]))
        save_checkpoint(path, FITTED.params, {"solver": "adam"}, other)
    else:
        _foreign(path, data.draw(FOREIGN), originals, "model")
    CASES["checkpoints"] += 1
    value, _, error = _outcome(lambda p: load_checkpoint(p, expect=expect), path)
    if error is None:
        params, state = value
        assert mode == "bytes" and np.array_equal(params, FITTED.params), (
            f"silently accepted a damaged checkpoint ({mode})"
        )
        assert state["step"] == 3 and np.array_equal(state["m"], np.ones(5))


# ------------------------------------------------------------------------------ campaigns
ANY_VALUE = st.one_of(
    st.integers(-(10**6), 10**6),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([1.5, 2.7, 45.0, 0.5, 1000.0, -1.0, 0, 1, 2, 16]),
    st.text(max_size=8),
    st.booleans(),
    st.lists(st.floats(-5, 200), max_size=3),
    st.lists(st.lists(st.floats(-5, 200), max_size=3), max_size=3),
    st.dictionaries(st.text(max_size=3), st.integers(), max_size=2),
)
TOP = ["body", "interior", "n_mascons", "seed", "frame", "contrast", "colour"]
ORBITS = ["count", "radius_rb", "inclination_deg", "families"]
TRACKING = [
    "arcs_per_orbit",
    "samples_per_arc",
    "cadence_s",
    "window_spin_periods",
    "sigma_r_m",
    "velocity_noise_ratio",
    "escape_factor",
    "min_radius_rb",
    "max_redraws",
]


@st.composite
def campaigns(draw):
    """A valid campaign with some keys replaced by arbitrary values."""
    data = {"body": "synthetic", "n_mascons": 50, "orbits": {"count": 2}, "tracking": {}}
    for key in draw(st.lists(st.sampled_from(TOP), max_size=3)):
        data[key] = draw(ANY_VALUE)
    for key in draw(st.lists(st.sampled_from(ORBITS), max_size=2)):
        data["orbits"][key] = draw(ANY_VALUE)
    for key in draw(st.lists(st.sampled_from(TRACKING), max_size=3)):
        data["tracking"][key] = draw(ANY_VALUE)
    if draw(st.booleans()):
        data[draw(st.sampled_from(["orbits", "tracking"]))] = draw(ANY_VALUE)
    return data


@settings(FUZZ, max_examples=600)
@given(data=campaigns())
def test_fuzz_campaign_values(data):
    CASES["campaigns"] += 1
    try:
        campaign = Campaign.from_dict(data, source="fuzz.toml")
    except HamgravError as exc:
        assert "fuzz.toml" in str(exc)
        return
    # accepted: every value is meaningful
    assert campaign.body.strip() and 10 <= campaign.n_mascons and campaign.seed >= 0
    assert 0 < campaign.contrast <= 1e3
    for family in campaign.families:
        assert 1 < family.radius_rb <= MAX_ORBIT_RADIUS_RB
        assert 0 <= family.inclination_deg <= 180
    t = campaign.tracking
    assert isinstance(t.arcs_per_orbit, int) and t.arcs_per_orbit >= 1
    assert isinstance(t.samples_per_arc, int) and t.samples_per_arc >= 2
    assert t.cadence_s > 0 and t.window_spin_periods > 0 and t.sigma_r_m >= 0
    assert t.velocity_noise_ratio >= 0 and t.escape_factor > 1 and t.min_radius_rb >= 0
    for v in (t.cadence_s, t.window_spin_periods, t.sigma_r_m, t.velocity_noise_ratio):
        assert math.isfinite(v)


@settings(FUZZ, max_examples=200)
@given(text=st.text(max_size=200), raw=st.binary(max_size=64), as_bytes=st.booleans())
def test_fuzz_campaign_file(text, raw, as_bytes):
    CASES["campaign files"] += 1
    folder = Path(_fresh_folder())
    path = folder / "c.toml"
    if as_bytes:
        path.write_bytes(raw)
    else:
        path.write_text('body = "synthetic"\n[orbits]\ncount = 2\n' + text)
    _, _, error = _outcome(load_campaign, path)
    assert error is None or isinstance(error, HamgravError)


# ------------------------------------------------------------------------------ body data
CUBE = """v -1 -1 -1\nv 1 -1 -1\nv 1 1 -1\nv -1 1 -1\nv -1 -1 1\nv 1 -1 1\nv 1 1 1\nv -1 1 1
f 1 4 3\nf 1 3 2\nf 5 6 7\nf 5 7 8\nf 1 2 6\nf 1 6 5\nf 2 3 7\nf 2 7 6\nf 3 4 8\nf 3 8 7
f 4 1 5\nf 4 5 8
"""


@st.composite
def catalogues(draw):
    entry = {"gm_m3_s2": 2.0, "spin_period_s": 4e4, "files": {"mesh": "mesh.obj"}}
    for key in draw(st.lists(st.sampled_from(["gm_m3_s2", "spin_period_s", "files"]), max_size=2)):
        entry[key] = draw(ANY_VALUE)
    mesh = CUBE
    edit = draw(st.sampled_from(["none", "nan", "index", "truncate", "text"]))
    if edit == "nan":
        mesh = mesh.replace("v 1 1 1", f"v {draw(st.sampled_from(['nan', 'inf', '1e400']))} 1 1")
    elif edit == "index":
        mesh = mesh.replace("f 4 5 8", f"f 4 5 {draw(st.sampled_from([0, 9, -20, 100]))}")
    elif edit == "truncate":
        mesh = mesh[: draw(st.integers(0, len(mesh) - 1))]
    elif edit == "text":
        mesh = draw(st.text(max_size=100))
    return entry, mesh


@settings(FUZZ, max_examples=200)
@given(case=catalogues())
def test_fuzz_catalogue_and_mesh(case):
    CASES["catalogues and meshes"] += 1
    entry, mesh = case
    folder = Path(_fresh_folder())
    (folder / "cube").mkdir()
    (folder / "cube" / "mesh.obj").write_text(mesh)
    (folder / "catalogue.json").write_text(json.dumps({"cube": entry}))
    try:
        body = load_body("cube", folder=folder)
    except HamgravError as exc:
        assert str(folder) in str(exc)
        return
    assert math.isfinite(body.gm_m3_s2) and body.gm_m3_s2 > 0
    assert math.isfinite(body.spin_period_s) and body.spin_period_s > 0
    assert np.all(np.isfinite(body.mesh_m.vertices)) and body.mesh_m.is_watertight


@settings(FUZZ, max_examples=200)
@given(
    rows=st.lists(
        st.lists(st.one_of(st.floats(), st.sampled_from(["x", ""])), min_size=1, max_size=5),
        max_size=4,
    ),
    raw=st.one_of(st.none(), st.binary(max_size=64)),
)
def test_fuzz_mascon_file(rows, raw):
    CASES["mascon files"] += 1
    path = Path(_fresh_folder()) / "mascons.csv.gz"
    if raw is not None:
        path.write_bytes(raw)
    else:
        text = "x_m,y_m,z_m,mass_fraction\n" + "".join(",".join(map(str, r)) + "\n" for r in rows)
        path.write_bytes(gzip.compress(text.encode()))
    try:
        data = _read_mascon_csv(path)
    except HamgravError as exc:
        assert str(path) in str(exc)
        return
    assert data.ndim == 2 and data.shape[1] == 4 and np.all(np.isfinite(data))
    assert np.all(data[:, 3] > 0)


# ------------------------------------------------------------------------------ command line
def _cli_ok(result, needles):
    """A user error (status 2) naming one of ``needles``, never a traceback or a bug."""
    assert result.exit_code == 2, (result.exit_code, result.output, result.exception)
    assert result.exception is None or isinstance(result.exception, SystemExit)
    text = " ".join(result.output.split())
    assert any(n in text for n in needles), text


def _cli_verdict(result, valid, accepted: list[str], option: str) -> None:
    """An accepted value lets the command reach its next check (``accepted``); a refused one
    names the option; ``valid`` None allows either."""
    refused = [option, f"'{option}'"]
    _cli_ok(result, accepted if valid else refused if valid is False else accepted + refused)


NUMBER_TEXT = st.one_of(
    st.sampled_from(
        ["0", "-1", "1", "4.7", "nan", "inf", "-inf", "1e309", "", " ", "abc", "1,2", "3,-4"]
    ),
    st.integers(-(10**12), 10**12).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.text(max_size=6),
)


def _valid_number(
    text: str, low: float, *, integer: bool, open_low=False, lists=False, high=math.inf
):
    """True: the value must be accepted; False: refused; None: either is right (typer
    parses integer options leniently: "3.0" is the integer 3, exactly)."""
    words = [w.strip() for w in text.split(",") if w.strip()] if lists else [text]
    if not words:
        return False
    verdict = True
    for w in words:
        try:
            v = int(w) if integer else float(w)
        except ValueError:
            if not integer or lists:
                return False
            try:
                exact = float(w)
            except ValueError:
                return False
            if not (math.isfinite(exact) and exact.is_integer() and exact >= low):
                return False
            verdict, v = None, exact
        if not math.isfinite(v) or (v <= low if open_low else v < low) or v > high:
            return False
    return verdict


FIT_OPTIONS = {
    "--steps": lambda t: _valid_number(t, 1, integer=True),
    "--seed": lambda t: _valid_number(t, 0, integer=True, high=MAX_SEED),
    "--learning-rate": lambda t: _valid_number(t, 0.0, integer=False, open_low=True),
    "--hidden": lambda t: (
        _valid_number(t, 1, integer=True, lists=True)
        and max(int(w) for w in t.split(",") if w.strip()) <= 1024
    ),
    "--kaula": lambda t: t == "cv" or _valid_number(t, 0.0, integer=False),
    "--harmonic": lambda t: t == "cv" or _valid_number(t, 0.0, integer=False),
    "--folds": lambda t: _valid_number(t, 2, integer=True),
    "--model": lambda t: (
        t in ("network", "network-best", "sh:auto")
        or (t.startswith("sh:") and t[3:].isdecimal() and 2 <= int(t[3:]) <= 40)
        or (t.startswith("sh:auto:") and t[8:].isdecimal() and 3 <= int(t[8:]) <= 40)
    ),
}


@settings(FUZZ, max_examples=500)
@given(
    option=st.sampled_from(sorted(FIT_OPTIONS)),
    value=st.one_of(
        NUMBER_TEXT,
        st.sampled_from(
            ["sh:4", "sh:1", "sh:x", "network", "scan", "cv", "sh:auto", "sh:auto:8", "sh:auto:2"]
        ),
    ),
)
def test_fuzz_fit_options(tmp_path, option, value):
    """Every option value is either refused naming the option, or accepted: then the next
    check (the missing arcs file) is what fails."""
    CASES["fit options"] += 1
    missing = tmp_path / "missing.h5"
    extra = ["--model", "sh:4"] if option == "--kaula" else []
    args = ["fit", str(missing), *extra, f"{option}={value}", "-o", str(tmp_path / "m.h5")]
    result = runner.invoke(COMMAND, args)
    _cli_verdict(result, FIT_OPTIONS[option](value), [f"arcs file not found: {missing}"], option)


EVALUATE_OPTIONS = {
    "--shells": lambda t: _valid_number(t, 1.0, integer=False, lists=True, high=MAX_SHELL_RB),
    "--altitude": lambda t: _valid_number(t, 0.0, integer=False, lists=True),
}


@settings(FUZZ, max_examples=300)
@given(option=st.sampled_from(sorted(EVALUATE_OPTIONS)), value=NUMBER_TEXT)
def test_fuzz_evaluate_options(tmp_path, option, value):
    CASES["evaluate options"] += 1
    missing = tmp_path / "missing.h5"
    result = runner.invoke(COMMAND, ["evaluate", str(missing), f"{option}={value}"])
    _cli_verdict(
        result, EVALUATE_OPTIONS[option](value), [f"model file not found: {missing}"], option
    )


@settings(FUZZ, max_examples=200)
@given(option=st.sampled_from(["--picks", "--seed"]), value=NUMBER_TEXT)
def test_fuzz_select_options(tmp_path, option, value):
    CASES["select options"] += 1
    missing = tmp_path / "missing.h5"
    result = runner.invoke(
        COMMAND, ["select", str(missing), "--pool", "p.toml", f"{option}={value}"]
    )
    high = MAX_SEED if option == "--seed" else math.inf
    valid = _valid_number(value, 1 if option == "--picks" else 0, integer=True, high=high)
    _cli_verdict(result, valid, [f"model file not found: {missing}"], option)


def test_fuzz_reference_files_read_back(tmp_path):
    originals = _originals()
    """The fuzzed readers do accept the untouched files (the oracle is not vacuous)."""
    for name, reader, same in (
        ("arcs", load_arcs, lambda v: _same_arcs(v, ARCS)),
        ("model", load_model, lambda v: _same_fitted(v, FITTED)),
    ):
        path = tmp_path / f"{name}.h5"
        path.write_bytes(originals[name])
        assert same(reader(path))
    path = tmp_path / "c.npz"
    path.write_bytes(originals["checkpoint"])
    params, _ = load_checkpoint(path, expect={"solver": "adam"})
    assert np.array_equal(params, FITTED.params)
    assert _same_arcs(replace(ARCS), ARCS) and not _same_arcs(replace(ARCS, seed=4), ARCS)


# ------------------------------------------------------------------------------ OEM tracking
@pytest.fixture(scope="module")
def oem_original(small_arcs, synthetic, tmp_path_factory):
    """One exported OEM file (the first trajectory of the small campaign) and its body."""
    from hamgrav.io.oem import export_oem_by_trajectory

    paths = export_oem_by_trajectory(small_arcs, tmp_path_factory.mktemp("oem"))
    return paths[0].read_text(), synthetic


def _import_outcome(text_or_bytes, body):
    """Import one damaged OEM file: None (refused with a one-line error naming the file) or
    the arcs, which must then be finite tracking data."""
    from hamgrav.io.oem_import import import_oem

    path = _fresh_folder() / "track.oem"
    if isinstance(text_or_bytes, bytes):
        path.write_bytes(text_or_bytes)
    else:
        path.write_text(text_or_bytes)
    value, _, error = _outcome(lambda p: import_oem([p], body), path)
    if error is not None:
        return None
    assert np.all(np.isfinite(value.times)) and np.all(np.isfinite(value.states))
    assert np.all(np.diff(value.times, axis=1) > 0)
    assert np.max(np.abs(value.states)) <= MAX_STATE
    return value


@settings(FUZZ, max_examples=150)
@given(data=st.data())
def test_fuzz_oem_reader(oem_original, data):
    """Damaged OEM text is refused or read as finite, ordered tracking data. A text format has
    no checksum: a changed digit inside a number reads as another number, which no reader can
    tell from a real one (the data-line checks below are what it can tell)."""
    text, body = oem_original
    raw = text.encode()
    kind = data.draw(st.sampled_from(["bytes", "value", "foreign"]))
    CASES[f"oem {kind}"] += 1
    if kind == "bytes":
        _import_outcome(_damage(raw, data.draw(byte_damage(len(raw)))), body)
        return
    if kind == "foreign":
        foreign = data.draw(st.sampled_from(["", "{}", "CCSDS_OEM_VERS = 2.0\n", "\x00" * 64]))
        assert _import_outcome(foreign, body) is None
        return
    # a number of one data line replaced by a non-finite or absurd value: always refused
    lines = text.splitlines()
    data_rows = [i for i, line in enumerate(lines) if line[:4].isdigit() and "T" in line[:12]]
    row = data.draw(st.sampled_from(data_rows))
    column = data.draw(st.integers(1, 6))
    bad = data.draw(st.sampled_from(["nan", "inf", "-inf", "1e182", "NaN"]))
    fields = lines[row].split()
    fields[column] = bad
    lines[row] = " ".join(fields)
    assert _import_outcome("\n".join(lines) + "\n", body) is None


@pytest.mark.parametrize("kind", ["arcs", "model"])
def test_a_misshapen_origin_is_refused_on_one_line(kind, tmp_path):
    """The case the model-file fuzzer found: an array-valued body origin is named by its
    shape, not printed over several lines."""
    path = tmp_path / f"{kind}.h5"
    path.write_bytes(_originals()[kind])
    _set_h5(path, "@body_origin_m", np.zeros((2, 2, 2)), keep_checksum=False)
    reader = load_arcs if kind == "arcs" else load_model
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", HamgravWarning)  # an old-style file, no checksum
        with pytest.raises(HamgravError) as info:
            reader(path)
    message = str(info.value)
    assert "\n" not in message and "body_origin_m" in message and "shape (2, 2, 2)" in message


# ------------------------------------------------------------------------------ results.json
RESULTS_DIR = Path(__file__).resolve().parents[1] / "results"
#: Committed results of several experiments, each edited by hand in the fuzz cases below.
FUZZED_RESULTS = ("descent-itokawa-extended", "own-body", "selection-itokawa-sh", "swarm-bennu")
JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers(-5, 10**6) | st.floats() | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=4), inner),
    max_leaves=6,
)


def _paths(node, prefix=()):
    """Every key path of a JSON document (dict keys and list indices)."""
    yield prefix
    items = (
        node.items()
        if isinstance(node, dict)
        else enumerate(node)
        if isinstance(node, list)
        else ()
    )
    for key, value in items:
        yield from _paths(value, (*prefix, key))


@settings(FUZZ, max_examples=150)
@given(data=st.data())
def test_fuzz_hand_edited_results_json(data):
    """experiment readme on a hand-edited results.json: a README (status 0) or one line
    naming the problem (status 2) that keeps the old README; never a bug, never a stray
    file."""
    CASES["results.json"] += 1
    name = data.draw(st.sampled_from([n for n in FUZZED_RESULTS if (RESULTS_DIR / n).is_dir()]))
    report = json.loads((RESULTS_DIR / name / "results.json").read_text())
    paths = [p for p in _paths(report) if p]
    path = data.draw(st.sampled_from(paths))
    parent = report
    for key in path[:-1]:
        parent = parent[key]
    if data.draw(st.booleans()) and isinstance(parent, dict):
        del parent[path[-1]]
    else:
        parent[path[-1]] = data.draw(JSON_VALUES)
    folder = _fresh_folder() / name
    folder.mkdir()
    (folder / "results.json").write_text(json.dumps(report))
    (folder / "README.md").write_text("before")
    result = runner.invoke(COMMAND, ["experiment", "readme", str(folder)])
    assert result.exit_code in (0, 2), (path, result.exit_code, result.output, result.exception)
    assert result.exception is None or isinstance(result.exception, SystemExit), path
    if result.exit_code == 2:
        assert result.output.strip().startswith("error:"), result.output
        assert "Traceback" not in result.output and "internal error" not in result.output
        assert (folder / "README.md").read_text() == "before", path
    else:
        assert (folder / "README.md").read_text() != "before", path
    assert sorted(p.name for p in folder.iterdir()) == ["README.md", "results.json"], path
