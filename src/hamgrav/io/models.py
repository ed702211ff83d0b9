"""Model files (HDF5, never pickle) and checkpoints of interrupted fits (npz, never pickle).

Layout of a model file (all numbers canonical: length = synchronous radius, time = spin
period / 2 pi, unless the name says otherwise)::

    /              attrs: format, format_version, hamgrav_version, body_name, gm_m3_s2,
                          spin_period_s, body_origin_m, estimate_trajectory_params,
                          structure_key, units,
                          model (JSON of Model.describe(), known mascons included),
                          prior, solver, stages (JSON)
    /params        (n,)  learnable parameters, then (estimate_trajectory_params) each
                         trajectory's per-trajectory parameters, trajectory-major
    /history       attrs: names (JSON list, the order of the entries),
                          json (JSON object of the entries that are not arrays of numbers)
    /history/<name>      float array for each numeric entry

A checkpoint is an ``.npz`` archive: ``params``, ``header`` (one JSON string: format, the
plain-data part of the state, and which state entries are numpy arrays or scalars) and one
``state_array/<key>`` entry per numpy value of the state.

JSON fields accept numpy scalars and arrays (written as numbers and lists).
"""

from __future__ import annotations

import json
import os
import zipfile
from pathlib import Path

import h5py
import numpy as np

from .. import __version__
from ..core.model import Model
from ..errors import DatasetError
from ..fit.fitted import FittedModel
from .files import atomic_path

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
_NPZ_ERRORS = (OSError, EOFError, KeyError, IndexError, ValueError, TypeError, zipfile.BadZipFile)


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
            group[name] = arr
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
    }
    with atomic_path(path) as tmp, h5py.File(tmp, "w") as f:
        f.attrs.update(attrs)
        f["params"] = params
        _write_history(f.create_group("history"), fitted.history)
    return path


def _attr(obj, name: str):
    try:
        value = obj.attrs[name]
    except KeyError:
        raise ModelFileError(f"attribute {name!r} is missing") from None
    return value.decode() if isinstance(value, bytes) else value


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


def _read_model(f: h5py.File) -> FittedModel:
    fmt = _attr(f, "format")
    if fmt != MODEL_FORMAT:
        raise ModelFileError(f"not a hamgrav model file (format {fmt!r})")
    version = int(_attr(f, "format_version"))
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
    if "params" not in f:
        raise ModelFileError("dataset 'params' is missing")
    params = np.asarray(f["params"][()], dtype=float)
    per_trajectory = bool(
        _attr(f, "estimate_srp" if version == 1 else "estimate_trajectory_params")
    )
    problem = _params_problem(model, params, per_trajectory)
    if problem:
        raise ModelFileError(f"file inconsistent: {problem}")
    return FittedModel(
        model=model,
        params=params,
        body_name=str(_attr(f, "body_name")),
        gm_m3_s2=float(_attr(f, "gm_m3_s2")),
        spin_period_s=float(_attr(f, "spin_period_s")),
        body_origin_m=tuple(float(v) for v in _attr(f, "body_origin_m")),
        estimate_trajectory_params=per_trajectory,
        prior=json.loads(_attr(f, "prior")),
        solver=json.loads(_attr(f, "solver")),
        history=_read_history(f["history"]),
        stages=json.loads(_attr(f, "stages")),
    )


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
    if not path.is_file():
        raise ModelFileError(f"model file not found: {path}")
    try:
        with h5py.File(path, "r") as f:
            fitted = _read_model(f)
    except ModelFileError as exc:
        raise ModelFileError(f"model file {path}: {exc}") from None
    except (OSError, RuntimeError, KeyError, ValueError, TypeError) as exc:  # JSON: ValueError
        raise ModelFileError(f"{path} {_CORRUPT} model file ({exc}); fit the model again") from None
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


def save_checkpoint(path: str | os.PathLike, params, state: dict) -> Path:
    """Write the parameters and solver ``state`` of an interrupted fit (atomically).

    ``state`` maps string keys to plain JSON-able data or to numpy arrays / scalars (stored
    as separate entries, exactly); :func:`load_checkpoint` returns what was saved.
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
    }
    # json.dumps without a numpy fallback: plain data must come back as it went in
    try:
        entries["header"] = np.array([json.dumps(header)])
    except (TypeError, ValueError) as exc:
        raise TypeError(f"checkpoint state must be plain data or numpy values: {exc}") from None
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, allow_pickle=False, **entries)
    return path


def load_checkpoint(path: str | os.PathLike) -> tuple[np.ndarray, dict]:
    """Read ``(params, state)`` written by :func:`save_checkpoint`."""
    path = Path(path)
    if not path.is_file():
        raise ModelFileError(f"checkpoint file not found: {path}")
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
    except ModelFileError as exc:
        raise ModelFileError(f"checkpoint {path}: {exc}") from None
    except _NPZ_ERRORS as exc:
        raise ModelFileError(
            f"{path} {_CORRUPT} checkpoint ({exc}); restart the fit without it"
        ) from None
    return params, state
