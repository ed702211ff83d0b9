"""Datasets on disk: ``Arcs`` in HDF5 (never pickle), written atomically.

Layout of an arcs file (all numeric data canonical unless the name says otherwise)::

    /                attrs: format, format_version, body_name, gm_m3_s2, spin_period_s,
                            body_origin_m, sigma_r_m, sigma_v_m_s, interior, seed,
                            interior_parameters (JSON), config (JSON), trajectory_kind (JSON)
    /times           (n_arcs, m)
    /states          (n_arcs, m, 6)   noisy (q, p)
    /true_states     (n_arcs, m, 6)
    /trajectory      (n_arcs,)
    /trajectory_info/<name>           per-trajectory arrays
    /truth/positions (n, 3), /truth/masses (n,)
    /body            the body the arcs were made with (see :mod:`hamgrav.io.body_record`)
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import h5py
import numpy as np

from ..core.arcs import NO_TRUTH, Arcs
from ..core.mascons import MasconSet
from ..errors import DatasetError
from ..files import atomic_path
from .body_record import read_body_record, write_body_record
from .hdf5 import (
    READ_ERRORS,
    attribute,
    body_origin,
    create,
    number_attribute,
    open_for_reading,
    write_array,
)

__all__ = ["save_arcs", "load_arcs", "MAX_STATE"]

ARCS_FORMAT = "hamgrav-arcs"
ARCS_FORMAT_VERSION = 1
#: Largest |q| and |p| an arcs file may hold (canonical). An orbit at the campaign limit of
#: 20 Brillouin radii is below 20 synchronous radii for every catalogued body; a thousand is
#: far beyond any tracking and below where propagation breaks down.
MAX_STATE = 1e3
_FIX = "regenerate it with 'hamgrav simulate' or 'hamgrav import-oem'"


def save_arcs(arcs: Arcs, path: str | os.PathLike) -> Path:
    """Write ``arcs`` to an HDF5 file at ``path`` (atomically, with checksums: see
    :mod:`hamgrav.io.hdf5`)."""
    path = Path(path)
    with atomic_path(path) as tmp:
        _write(arcs, tmp)
    return path


def _write(arcs: Arcs, tmp: Path) -> None:
    with create(tmp) as f:
        f.attrs.update(
            {
                "format": ARCS_FORMAT,
                "format_version": ARCS_FORMAT_VERSION,
                "body_name": arcs.body_name,
                "gm_m3_s2": arcs.gm_m3_s2,
                "spin_period_s": arcs.spin_period_s,
                "body_origin_m": np.asarray(arcs.body_origin_m, dtype=float),
                "sigma_r_m": arcs.sigma_r_m,
                "sigma_v_m_s": arcs.sigma_v_m_s,
                "interior": arcs.interior,
                "seed": int(arcs.seed),
                "interior_parameters": json.dumps(arcs.interior_parameters),
                "config": json.dumps(arcs.config),
                "trajectory_kind": json.dumps(list(arcs.trajectory_kind)),
                "units": "canonical: length = synchronous radius, time = spin period / 2 pi",
                "arcs_sha256": arcs.digest(),
            }
        )
        write_array(f, "times", arcs.times)
        write_array(f, "states", arcs.states)
        write_array(f, "true_states", arcs.true_states)
        write_array(f, "trajectory", arcs.trajectory)
        info = f.create_group("trajectory_info")
        for key, value in arcs.trajectory_info.items():
            write_array(info, key, value)
        truth = f.create_group("truth")
        write_array(truth, "positions", arcs.truth.positions)
        write_array(truth, "masses", arcs.truth.masses)
        if arcs.body is not None:
            write_body_record(f, arcs.body)


def _attr(f, name: str):
    return attribute(f, name, DatasetError)


def _data(f, name, ndim: int, kind: str = "f"):
    """Dataset ``name`` as an array of ``ndim`` dimensions and a numeric ``kind``."""
    try:
        obj = f[name]
    except KeyError:
        raise DatasetError(f"dataset {name!r} is missing") from None
    if not isinstance(obj, h5py.Dataset):
        raise DatasetError(f"{name!r} is not a dataset")
    arr = np.asarray(obj[()])
    if arr.ndim != ndim:
        raise DatasetError(f"dataset {name!r} has shape {arr.shape}, expected {ndim} dimensions")
    if arr.dtype.kind not in ("iu" if kind == "i" else "iuf"):
        want = "integers" if kind == "i" else "real numbers"
        raise DatasetError(f"dataset {name!r} holds {arr.dtype}, expected {want}")
    return arr.astype(np.int64 if kind == "i" else float)


def _number(f, name, low: float, *, open_low: bool) -> float:
    value = number_attribute(f, name, float, DatasetError)
    if not (math.isfinite(value) and (value > low if open_low else value >= low)):
        sign = ">" if open_low else ">="
        raise DatasetError(f"attribute {name!r} must be a finite number {sign} {low}, got {value}")
    return value


def _json(f, name, kind):
    value = json.loads(_attr(f, name))
    if not isinstance(value, kind):
        raise DatasetError(f"attribute {name!r} must hold a JSON {kind.__name__}")
    return value


def _finite(name: str, arr: np.ndarray) -> None:
    bad = ~np.isfinite(arr)
    if bad.any():
        first = tuple(int(i) for i in np.argwhere(bad)[0])
        raise DatasetError(
            f"dataset {name!r} holds {int(bad.sum())} non-finite values (NaN or inf, the "
            f"first at index {first})"
        )


def _read(f, path: Path) -> Arcs:
    fmt = f.attrs.get("format")
    if fmt is None:
        raise DatasetError(
            f"{path} is an HDF5 file but not a hamgrav arcs file (it has no 'format' "
            "attribute); pass a file written by 'hamgrav simulate' or 'hamgrav import-oem'"
        )
    fmt = fmt.decode() if isinstance(fmt, bytes) else str(fmt)
    if fmt != ARCS_FORMAT:
        raise DatasetError(
            f"not a hamgrav arcs file (format {fmt!r}); pass a file written by "
            "'hamgrav simulate' or 'hamgrav import-oem'"
        )
    version = number_attribute(f, "format_version", int, DatasetError)
    if version > ARCS_FORMAT_VERSION:
        raise DatasetError(
            f"format version {version} is newer than this hamgrav reads "
            f"({ARCS_FORMAT_VERSION}); upgrade hamgrav"
        )
    times = _data(f, "times", 2)
    states = _data(f, "states", 3)
    true_states = _data(f, "true_states", 3)
    trajectory = _data(f, "trajectory", 1, "i")
    positions, masses = _data(f, "truth/positions", 2), _data(f, "truth/masses", 1)
    group = f.get("trajectory_info")
    if not isinstance(group, h5py.Group):
        raise DatasetError("group 'trajectory_info' is missing")
    info = {k: np.asarray(v[()]) for k, v in group.items()}
    kinds = _json(f, "trajectory_kind", list)
    if not all(isinstance(k, str) for k in kinds):
        raise DatasetError("attribute 'trajectory_kind' must list trajectory kinds (strings)")
    origin = _attr(f, "body_origin_m")
    metadata = {
        "body_name": str(_attr(f, "body_name")),
        "gm_m3_s2": _number(f, "gm_m3_s2", 0.0, open_low=True),
        "spin_period_s": _number(f, "spin_period_s", 0.0, open_low=True),
        "sigma_r_m": _number(f, "sigma_r_m", 0.0, open_low=False),
        "sigma_v_m_s": _number(f, "sigma_v_m_s", 0.0, open_low=False),
        "interior": str(_attr(f, "interior")),
        "interior_parameters": _json(f, "interior_parameters", dict),
        "seed": number_attribute(f, "seed", int, DatasetError),
        "config": _json(f, "config", dict),
    }
    n, m = times.shape
    if n < 1 or m < 2:
        raise DatasetError(f"holds {n} arcs of {m} samples; an arcs file needs arcs of >= 2")
    if states.shape != (n, m, 6) or true_states.shape != (n, m, 6):
        raise DatasetError(
            f"datasets 'states' {states.shape} and 'true_states' {true_states.shape} must have "
            f"shape {(n, m, 6)} to match 'times' {times.shape}"
        )
    if trajectory.shape != (n,) or trajectory.min() < 0 or trajectory.max() >= len(kinds):
        raise DatasetError(
            "dataset 'trajectory' must hold one index per arc into 'trajectory_kind'"
        )
    # imported tracking has no truth: its true states are NaN and its truth mascons empty
    no_truth = metadata["interior"] == NO_TRUTH
    if no_truth and not np.all(np.isnan(true_states)):
        raise DatasetError(
            f"interior {NO_TRUTH!r} (no truth) but dataset 'true_states' holds numbers"
        )
    checked = [("times", times), ("states", states)]
    checked += [] if no_truth else [("true_states", true_states)]
    for name, arr in checked:
        _finite(name, arr)
    if np.any(np.diff(times, axis=1) <= 0):
        raise DatasetError("dataset 'times' must increase strictly along every arc")
    for name, arr in checked[1:]:
        largest = float(np.max(np.abs(arr)))
        if largest > MAX_STATE:
            raise DatasetError(
                f"dataset {name!r} holds a state component of {largest:.3g} (canonical); "
                f"states beyond {MAX_STATE:g} synchronous radii are not tracking data"
            )
    origin = body_origin(origin, DatasetError)
    if positions.ndim != 2 or positions.shape[1:] != (3,) or masses.shape != positions.shape[:1]:
        raise DatasetError(
            f"truth mascons need positions (n, 3) and masses (n,), got {positions.shape} and "
            f"{masses.shape}"
        )
    _finite("truth/positions", positions)
    _finite("truth/masses", masses)
    if no_truth and len(masses):
        raise DatasetError(f"interior {NO_TRUTH!r} (no truth) but truth mascons are stored")
    if not no_truth and (len(masses) < 1 or not masses.sum() > 0):
        raise DatasetError("the truth mascons must have a positive total mass")
    if np.any(masses < 0):
        # every interior hamgrav builds is a positive density compressed to point masses
        raise DatasetError(
            f"dataset 'truth/masses' holds {int(np.sum(masses < 0))} negative masses "
            f"(the smallest {float(masses.min()):.3g}); truth mascons are >= 0"
        )
    body = read_body_record(f, DatasetError)
    if body is not None:
        if (body.gm_m3_s2, body.spin_period_s) != (
            metadata["gm_m3_s2"],
            metadata["spin_period_s"],
        ):
            raise DatasetError(
                f"the arcs' GM {metadata['gm_m3_s2']} m^3/s^2 and spin period "
                f"{metadata['spin_period_s']} s differ from their body's ({body.gm_m3_s2}, "
                f"{body.spin_period_s})"
            )
        if tuple(body.origin_m) != origin:
            raise DatasetError(
                f"the arcs' frame origin {list(origin)} m differs from their body's "
                f"{list(body.origin_m)}"
            )
    return Arcs(
        times=times,
        states=states,
        true_states=true_states,
        trajectory=trajectory,
        trajectory_kind=tuple(kinds),
        trajectory_info=info,
        body_origin_m=origin,
        truth=MasconSet(positions, masses),
        body=body,
        **metadata,
    )


def load_arcs(path: str | os.PathLike) -> Arcs:
    """Read an arcs file written by :func:`save_arcs`, checking its checksums, shapes and
    values (finite, in range); every problem raises :class:`DatasetError` naming the file
    and the fix."""
    path = Path(path)
    try:
        with open_for_reading(path, "arcs file", _FIX, fmt=ARCS_FORMAT) as f:
            return _read(f, path)
    except DatasetError as exc:
        text = str(exc)
        if ";" not in text:  # what is wrong, then how to fix it
            text = f"{text}; {_FIX}"
        raise DatasetError(text if str(path) in text else f"{path}: {text}") from None
    except READ_ERRORS as exc:
        raise DatasetError(
            f"{path} is truncated, corrupted or not a hamgrav arcs file ({exc}); {_FIX}"
        ) from None
