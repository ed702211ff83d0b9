"""Model files (HDF5, never pickle) and checkpoints of interrupted fits (npz, never pickle).

Layout of a model file (all numbers canonical: length = synchronous radius, time = spin
period / 2 pi, unless the name says otherwise)::

    /              attrs: format, format_version, hamgrav_version, body_name, gm_m3_s2,
                          spin_period_s, body_origin_m, estimate_trajectory_params,
                          structure_key, units,
                          model (JSON of Model.describe(), known mascons included),
                          prior, solver, stages, training (JSON: arcs_file, arcs_sha256,
                          truth_sha256 of the arcs fitted to)
    /params        (n,)  learnable parameters, then (estimate_trajectory_params) each
                         trajectory's per-trajectory parameters, trajectory-major
    /history       attrs: names (JSON list, the order of the entries),
                          json (JSON object of the entries that are not arrays of numbers)
    /history/<name>      float array for each numeric entry
    /body          the body the model was fitted for (see :mod:`hamgrav.io.body_record`)

The file's checksum is in its HDF5 user block and datasets carry fletcher32 checksums (see
:mod:`hamgrav.io.hdf5`). ``training`` is absent in files written before hamgrav 0.2.1.

A checkpoint is an ``.npz`` archive: ``params``, ``header`` (one JSON string: format, the
plain-data part of the state, which state entries are numpy arrays or scalars, and the
``identity`` of the fit that wrote it) and one ``state_array/<key>`` entry per numpy value
of the state. The zip format checks every entry's CRC-32 on reading.

JSON fields accept numpy scalars and arrays (written as numbers and lists).
"""

from __future__ import annotations

import json
import math
import os
import warnings
import zipfile
from pathlib import Path

import h5py
import numpy as np

from .. import __version__
from ..core.model import Model
from ..errors import DatasetError, HamgravWarning
from ..files import atomic_path
from ..fit.fitted import FittedModel
from . import hdf5
from .body_record import read_body_record, write_body_record

__all__ = [
    "ModelFileError",
    "save_model",
    "load_model",
    "save_checkpoint",
    "load_checkpoint",
    "checkpoint_path_for",
]

MODEL_FORMAT = "hamgrav-model"
MODEL_FORMAT_VERSION = 2  # 2: generic per-trajectory terms (1: one SRP slot)
CHECKPOINT_FORMAT = "hamgrav-checkpoint"
CHECKPOINT_FORMAT_VERSION = 1
UNITS = "canonical: length = synchronous radius, time = spin period / 2 pi"
_ARRAY_PREFIX = "state_array/"
_CORRUPT = "is truncated, corrupted or not a hamgrav"
_NPZ_ERRORS = (*hdf5.READ_ERRORS, EOFError, zipfile.BadZipFile)
_FIX = "fit the model again"


class ModelFileError(DatasetError):
    """A model or checkpoint file is missing, corrupted, of another kind or of another
    body or structure than expected."""


def _plain(value):
    """JSON fallback for numpy values inside plain data."""
    if isinstance(value, np.ndarray | np.generic):
        return value.tolist()
    raise TypeError(f"object of type {type(value).__name__} is not plain data")


def _dumps(name: str, value) -> str:
    try:
        return json.dumps(value, default=_plain)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be plain (JSON-able) data: {exc}") from None


def _params_problem(model: Model, params: np.ndarray, per_trajectory: bool) -> str | None:
    """Why ``params`` does not fit ``model`` (None when it does)."""
    n, n_learn, n_tp = params.size, model.n_learn, model.n_trajectory_params
    if params.ndim != 1:
        return f"params must be a vector, got shape {params.shape}"
    if per_trajectory and n_tp == 0:
        return "per-trajectory parameters are flagged but the model has no per-trajectory term"
    if per_trajectory and (n < n_learn or (n - n_learn) % n_tp):
        return f"{n} params are not {n_learn} learnable plus whole trajectories of {n_tp}"
    if not per_trajectory and n != n_learn:
        return f"{n} params but the model has {n_learn} learnable parameters"
    return None


def _numeric_array(value) -> np.ndarray | None:
    """``value`` as a float array when it is a number or a (nested) list of real numbers."""
    try:
        arr = np.asarray(value)
    except ValueError:  # ragged lists
        return None
    return arr.astype(float) if arr.dtype.kind in "iuf" else None


def _write_history(group: h5py.Group, history: dict) -> None:
    other = {}
    for name, value in history.items():
        if not isinstance(name, str):
            raise TypeError(f"history keys must be strings, got {name!r}")
        arr = _numeric_array(value)
        if arr is not None and name not in ("", ".") and "/" not in name:
            hdf5.write_array(group, name, arr)
        else:
            other[name] = value
    group.attrs["names"] = json.dumps(list(history))
    group.attrs["json"] = _dumps("history", other)


def save_model(fitted: FittedModel, path: str | os.PathLike) -> Path:
    """Write ``fitted`` to an HDF5 model file at ``path`` (atomically) and return the path.

    History entries that are arrays of numbers are stored as float datasets (and read back
    as lists of floats); any other entry is stored as JSON.
    """
    path = Path(path)
    params = np.asarray(fitted.params, dtype=float)
    problem = _params_problem(fitted.model, params, fitted.estimate_trajectory_params)
    if problem:
        raise ValueError(f"cannot save the model: {problem}")
    attrs = {
        "format": MODEL_FORMAT,
        "format_version": MODEL_FORMAT_VERSION,
        "hamgrav_version": __version__,
        "body_name": fitted.body_name,
        "gm_m3_s2": float(fitted.gm_m3_s2),
        "spin_period_s": float(fitted.spin_period_s),
        "body_origin_m": np.asarray(fitted.body_origin_m, dtype=float),
        "estimate_trajectory_params": bool(fitted.estimate_trajectory_params),
        "structure_key": fitted.model.key(),
        "units": UNITS,
        "model": _dumps("model description", fitted.model.describe()),
        "prior": _dumps("prior", fitted.prior),
        "solver": _dumps("solver", fitted.solver),
        "stages": _dumps("stages", fitted.stages),
        "training": _dumps("training", fitted.training),
    }
    if not np.all(np.isfinite(params)):
        raise ValueError("cannot save the model: its parameters are not all finite")
    with atomic_path(path) as tmp:
        with hdf5.create(tmp) as f:
            f.attrs.update(attrs)
            hdf5.write_array(f, "params", params)
            _write_history(f.create_group("history"), fitted.history)
            if fitted.body is not None:
                write_body_record(f, fitted.body)
    return path


def _attr(obj, name: str):
    return hdf5.attribute(obj, name, ModelFileError)


def _read_history(group: h5py.Group) -> dict:
    other = json.loads(_attr(group, "json"))
    history = {}
    for name in json.loads(_attr(group, "names")):
        if name in other:
            history[name] = other[name]
        elif name in group:
            history[name] = np.asarray(group[name][()], dtype=float).tolist()
        else:
            raise ModelFileError(f"history entry {name!r} is missing")
    return history


def _positive(f: h5py.File, name: str) -> float:
    value = hdf5.number_attribute(f, name, float, ModelFileError)
    if not (math.isfinite(value) and value > 0):
        raise ModelFileError(f"attribute {name!r} must be a finite number > 0, got {value}")
    return value


def _read_model(f: h5py.File, path: Path) -> FittedModel:
    if "format" not in f.attrs:
        raise ModelFileError(
            f"{path} is an HDF5 file but not a hamgrav model file (it has no 'format' "
            "attribute); pass a file written by 'hamgrav fit'"
        )
    fmt = _attr(f, "format")
    if fmt != MODEL_FORMAT:
        hint = " (an arcs file? pass it with --arcs)" if fmt == "hamgrav-arcs" else ""
        raise ModelFileError(f"not a hamgrav model file (format {fmt!r}){hint}")
    version = hdf5.number_attribute(f, "format_version", int, ModelFileError)
    if version > MODEL_FORMAT_VERSION:
        raise ModelFileError(
            f"format version {version} (written by hamgrav {_attr(f, 'hamgrav_version')}) is "
            f"newer than this hamgrav reads ({MODEL_FORMAT_VERSION}); upgrade hamgrav"
        )
    description = json.loads(_attr(f, "model"))
    stored_key = str(_attr(f, "structure_key"))
    if version == 1:  # one SRP slot: now the first kind of per-trajectory term
        srp = description.pop("srp", None)
        description["per_trajectory"] = [srp] if srp else []
        stored_key = stored_key.replace("|srp:", "|traj:")
    model = Model.from_description(description)
    if model.key() != stored_key:
        raise ModelFileError(
            f"file inconsistent: the stored model rebuilds to structure {model.key()!r}, "
            f"but the file records {stored_key!r}"
        )
    if not isinstance(f.get("params"), h5py.Dataset):
        raise ModelFileError("dataset 'params' is missing")
    raw = np.asarray(f["params"][()])
    if raw.dtype.kind not in "iuf":
        raise ModelFileError(f"dataset 'params' holds {raw.dtype}, expected real numbers")
    params = raw.astype(float)
    per_trajectory = bool(
        _attr(f, "estimate_srp" if version == 1 else "estimate_trajectory_params")
    )
    problem = _params_problem(model, params, per_trajectory)
    if problem:
        raise ModelFileError(f"file inconsistent: {problem}")
    origin = hdf5.body_origin(_attr(f, "body_origin_m"), ModelFileError)
    training = json.loads(_attr(f, "training")) if "training" in f.attrs else {}
    dicts = {k: json.loads(_attr(f, k)) for k in ("prior", "solver")}
    stages = json.loads(_attr(f, "stages"))
    if not (all(isinstance(v, dict) for v in (*dicts.values(), training))):
        raise ModelFileError("attributes 'prior', 'solver' and 'training' must hold JSON objects")
    if not isinstance(stages, list):
        raise ModelFileError("attribute 'stages' must hold a JSON list")
    if not isinstance(f.get("history"), h5py.Group):
        raise ModelFileError("group 'history' is missing")
    fitted = FittedModel(
        model=model,
        params=params,
        body_name=str(_attr(f, "body_name")),
        gm_m3_s2=_positive(f, "gm_m3_s2"),
        spin_period_s=_positive(f, "spin_period_s"),
        body_origin_m=origin,
        estimate_trajectory_params=per_trajectory,
        history=_read_history(f["history"]),
        stages=stages,
        training=training,
        body=read_body_record(f, ModelFileError),
        **dicts,
    )
    body = fitted.body
    if body is not None and (
        (body.gm_m3_s2, body.spin_period_s) != (fitted.gm_m3_s2, fitted.spin_period_s)
        or tuple(body.origin_m) != tuple(origin)
    ):
        raise ModelFileError(
            "file inconsistent: the model's GM, spin period or frame origin differ from its "
            f"recorded body's; {_FIX}"
        )
    bad = ~np.isfinite(params)
    if bad.any():
        raise ModelFileError(
            f"dataset 'params' holds {int(bad.sum())} non-finite values (NaN or inf, the "
            f"first at index {int(np.flatnonzero(bad)[0])}); {_FIX}"
        )
    return fitted


def load_model(
    path: str | os.PathLike,
    *,
    expect_body: str | None = None,
    expect_structure: str | None = None,
) -> FittedModel:
    """Read a model file written by :func:`save_model`.

    ``expect_body`` / ``expect_structure`` (a :meth:`Model.key`) refuse a model fitted for
    another body or with another structure. Every problem raises :class:`ModelFileError`
    naming the file.
    """
    path = Path(path)
    try:
        with hdf5.open_for_reading(path, "model file", _FIX, ModelFileError, MODEL_FORMAT) as f:
            fitted = _read_model(f, path)
    except DatasetError as exc:
        text = str(exc)
        if ";" not in text:  # what is wrong, then how to fix it
            text = f"{text}; {_FIX}"
        raise ModelFileError(text if str(path) in text else f"model file {path}: {text}") from None
    except hdf5.READ_ERRORS as exc:  # JSON: ValueError
        raise ModelFileError(f"{path} {_CORRUPT} model file ({exc}); {_FIX}") from None
    if expect_body is not None and fitted.body_name != expect_body:
        raise ModelFileError(
            f"model file {path} was fitted for body {fitted.body_name!r}, not "
            f"{expect_body!r}; fit a model for this body"
        )
    key = fitted.model.key()
    if expect_structure is not None and key != expect_structure:
        raise ModelFileError(
            f"model file {path} has model structure {key!r}, not the expected "
            f"{expect_structure!r}; fit a model with this structure"
        )
    return fitted


def checkpoint_path_for(model_path: str | os.PathLike) -> Path:
    """The checkpoint beside a model file: ``<name>.checkpoint.npz`` (``name`` with suffix)."""
    model_path = Path(model_path)
    return model_path.with_name(model_path.name + ".checkpoint.npz")


def save_checkpoint(
    path: str | os.PathLike, params, state: dict, identity: dict | None = None
) -> Path:
    """Write the parameters and solver ``state`` of an interrupted fit (atomically).

    ``state`` maps string keys to plain JSON-able data or to numpy arrays / scalars (stored
    as separate entries, exactly); :func:`load_checkpoint` returns what was saved.
    ``identity`` (plain data) describes the fit that writes it (its arcs' digest, model,
    solver and settings): :func:`load_checkpoint` refuses to resume another fit from it.
    """
    path = Path(path)
    entries = {"params": np.asarray(params)}
    plain, arrays, scalars = {}, [], []
    for key, value in state.items():
        if not isinstance(key, str):
            raise TypeError(f"checkpoint state keys must be strings, got {key!r}")
        if isinstance(value, np.ndarray | np.generic):
            arr = np.asarray(value)
            if arr.dtype.hasobject:
                raise TypeError(f"checkpoint state {key!r} is an object array (would pickle)")
            entries[_ARRAY_PREFIX + key] = arr
            (scalars if isinstance(value, np.generic) else arrays).append(key)
        else:
            plain[key] = value
    if entries["params"].dtype.hasobject:
        raise TypeError("checkpoint params must be numeric")
    header = {
        "format": CHECKPOINT_FORMAT,
        "format_version": CHECKPOINT_FORMAT_VERSION,
        "hamgrav_version": __version__,
        "keys": list(state),
        "arrays": arrays,
        "scalars": scalars,
        "state": plain,
        "identity": identity,
    }
    # json.dumps without a numpy fallback: plain data must come back as it went in
    try:
        entries["header"] = np.array([json.dumps(header)])
    except (TypeError, ValueError) as exc:
        raise TypeError(f"checkpoint state must be plain data or numpy values: {exc}") from None
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, allow_pickle=False, **entries)
    return path


def _plain_json(value):
    """``value`` as it reads back from JSON (tuples become lists)."""
    return json.loads(json.dumps(value))


def _check_identity(path: Path, stored: dict | None, state: dict, expect: dict) -> None:
    """Refuse a checkpoint written by another fit than ``expect`` describes."""
    fix = f"resume with the command that wrote it, or delete {path} to start the fit afresh"
    if stored is None:  # written before checkpoints recorded their fit
        solver = state.get("solver")
        if solver is not None and expect.get("solver") not in (None, solver):
            raise ModelFileError(
                f"checkpoint {path} was written by the {solver!r} solver, this fit runs "
                f"{expect['solver']!r}; {fix}"
            )
        warnings.warn(
            f"checkpoint {path} does not record which fit wrote it (older hamgrav): resuming "
            "it on trust; it must come from the same command",
            HamgravWarning,
            stacklevel=3,
        )
        return
    have, want = _flat(stored), _flat(_plain_json(expect))
    differ = [k for k in sorted(set(have) | set(want)) if have.get(k) != want.get(k)]
    if have.get("solver") != want.get("solver"):  # then every setting differs: name the solver
        differ = [k for k in differ if not k.startswith("solver_settings.")]
    if differ:
        what = "; ".join(f"{k} {have.get(k)!r} (this command: {want.get(k)!r})" for k in differ)
        raise ModelFileError(f"checkpoint {path} belongs to another fit: {what}; {fix}")


def _flat(identity: dict) -> dict:
    """Nested settings as dotted keys, so that a mismatch names the one setting that differs."""
    out = {}
    for key, value in identity.items():
        if isinstance(value, dict):
            out.update({f"{key}.{k}": v for k, v in _flat(value).items()})
        else:
            out[key] = value
    return out


def load_checkpoint(path: str | os.PathLike, expect: dict | None = None) -> tuple[np.ndarray, dict]:
    """Read ``(params, state)`` written by :func:`save_checkpoint`; with ``expect`` (the
    ``identity`` of the fit that resumes), refuse a checkpoint of another fit."""
    path = Path(path)
    if path.is_dir():
        raise ModelFileError(f"checkpoint {path} is a folder; delete it or choose another -o")
    if not path.is_file():
        raise ModelFileError(f"checkpoint file not found: {path}")
    if h5py.is_hdf5(path):  # e.g. a model file (np.load would speak of pickled data)
        raise ModelFileError(
            f"checkpoint {path} is an HDF5 file, not a hamgrav checkpoint (npz); remove it and "
            "fit again without --resume"
        )
    try:
        with np.load(path, allow_pickle=False) as data:
            header = json.loads(str(data["header"][0]))
            if header.get("format") != CHECKPOINT_FORMAT:
                raise ModelFileError(f"not a hamgrav checkpoint (format {header.get('format')!r})")
            if int(header["format_version"]) > CHECKPOINT_FORMAT_VERSION:
                raise ModelFileError(
                    f"format version {header['format_version']} is newer than this hamgrav "
                    f"reads ({CHECKPOINT_FORMAT_VERSION}); upgrade hamgrav"
                )
            params = data["params"]
            stored = {k: data[_ARRAY_PREFIX + k] for k in header["arrays"]}
            stored.update({k: data[_ARRAY_PREFIX + k][()] for k in header["scalars"]})
            stored.update(header["state"])
            state = {k: stored[k] for k in header["keys"]}
            identity = header.get("identity")
        if params.ndim != 1 or params.dtype.kind not in "iuf":
            raise ModelFileError(f"params must be a vector of numbers, got {params.dtype}")
        if not np.all(np.isfinite(params)):
            raise ModelFileError("params are not all finite (NaN or inf)")
        if expect is not None:
            _check_identity(path, identity, state, expect)
    except ModelFileError as exc:
        if str(path) in str(exc):
            raise
        raise ModelFileError(f"checkpoint {path}: {exc}") from None
        raise ModelFileError(f"checkpoint {path}: {exc}") from None
    except _NPZ_ERRORS as exc:
        raise ModelFileError(
            f"{path} {_CORRUPT} checkpoint ({exc}); restart the fit without it"
        ) from None
    return params, state
