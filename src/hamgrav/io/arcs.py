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
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import h5py
import numpy as np

from ..core.arcs import Arcs
from ..core.mascons import MasconSet
from ..errors import DatasetError
from .files import atomic_path

__all__ = ["save_arcs", "load_arcs"]

ARCS_FORMAT = "hamgrav-arcs"
ARCS_FORMAT_VERSION = 1


def save_arcs(arcs: Arcs, path: str | os.PathLike) -> Path:
    """Write ``arcs`` to an HDF5 file at ``path`` (atomically)."""
    path = Path(path)
    with atomic_path(path) as tmp, h5py.File(tmp, "w") as f:
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
            }
        )
        f["times"] = arcs.times
        f["states"] = arcs.states
        f["true_states"] = arcs.true_states
        f["trajectory"] = arcs.trajectory
        info = f.create_group("trajectory_info")
        for key, value in arcs.trajectory_info.items():
            info[key] = np.asarray(value)
        truth = f.create_group("truth")
        truth["positions"] = arcs.truth.positions
        truth["masses"] = arcs.truth.masses
    return path


def _attr(f, name):
    try:
        value = f.attrs[name]
    except KeyError:
        raise DatasetError(f"attribute {name!r} is missing") from None
    return value.decode() if isinstance(value, bytes) else value


def _data(f, name):
    try:
        return np.asarray(f[name][()])
    except KeyError:
        raise DatasetError(f"dataset {name!r} is missing") from None


def load_arcs(path: str | os.PathLike) -> Arcs:
    """Read an arcs file written by :func:`save_arcs`; errors name the file and the problem."""
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"arcs file not found: {path}")
    try:
        with h5py.File(path, "r") as f:
            if _attr(f, "format") != ARCS_FORMAT:
                raise DatasetError(f"not a hamgrav arcs file (format {_attr(f, 'format')!r})")
            version = int(_attr(f, "format_version"))
            if version > ARCS_FORMAT_VERSION:
                raise DatasetError(
                    f"format version {version} is newer than this hamgrav reads "
                    f"({ARCS_FORMAT_VERSION}); upgrade hamgrav"
                )
            info = {k: np.asarray(v[()]) for k, v in f["trajectory_info"].items()}
            return Arcs(
                times=_data(f, "times"),
                states=_data(f, "states"),
                true_states=_data(f, "true_states"),
                trajectory=_data(f, "trajectory"),
                trajectory_kind=tuple(json.loads(_attr(f, "trajectory_kind"))),
                trajectory_info=info,
                body_name=str(_attr(f, "body_name")),
                gm_m3_s2=float(_attr(f, "gm_m3_s2")),
                spin_period_s=float(_attr(f, "spin_period_s")),
                body_origin_m=tuple(float(v) for v in _attr(f, "body_origin_m")),
                sigma_r_m=float(_attr(f, "sigma_r_m")),
                sigma_v_m_s=float(_attr(f, "sigma_v_m_s")),
                truth=MasconSet(_data(f, "truth/positions"), _data(f, "truth/masses")),
                interior=str(_attr(f, "interior")),
                interior_parameters=json.loads(_attr(f, "interior_parameters")),
                seed=int(_attr(f, "seed")),
                config=json.loads(_attr(f, "config")),
            )
    except DatasetError as exc:
        raise DatasetError(f"{path}: {exc}") from None
    except (OSError, KeyError, ValueError, TypeError, json.JSONDecodeError) as exc:
        raise DatasetError(
            f"{path} is truncated, corrupted or not a hamgrav arcs file ({exc}); regenerate it "
            "with 'hamgrav simulate'"
        ) from None
