"""Export tracking arcs to a CCSDS Orbit Ephemeris Message (OEM 2.0, KVN text).

An OEM describes one object, and the ``oem`` package enforces that when it builds or reads a
message: every segment must have the same OBJECT_NAME and OBJECT_ID and the same TIME_SYSTEM,
and the segments must not overlap in time. So one file holds the arcs of one trajectory, one
segment per arc, in time order. :func:`export_oem_by_trajectory` writes one file per
trajectory of a whole campaign.

Conventions of the written file:

- Units: position in km, velocity in km/s (the OEM units); epochs are ISO strings with
  microsecond resolution.
- TIME_SYSTEM ``TDB``. astropy understands it, so ``oem`` reads the epochs back as ``Time``
  objects. TDB has no leap seconds, so the epoch of sample j is exactly
  ``epoch + times[j] * spin_period_s / (2 pi)`` seconds.
- REF_FRAME ``BODY_FIXED`` and CENTER_NAME the upper-cased body name. The arcs' frame is the
  body's own model frame: it rotates with the body about +Z at 2 pi / spin_period_s, and its
  origin is ``body_origin_m`` in the mesh frame. The SANA frame registry has no name for such a
  frame. CCSDS 502.0 asks for other values to be documented by agreement (an ICD), and ``oem``
  takes any string. So the name is descriptive, and COMMENT lines in the header document it.
  Names such as ``IAU_<BODY>`` were not used because they would claim an IAU rotation model
  that these arcs do not follow.
- Velocities are rotating-frame velocities: relative to the rotating body-fixed frame, not
  inertial. They are not the canonical momenta.
- ``oem`` has no COMMENT field, and its reader skips comments. The COMMENT lines are inserted
  into the KVN text where CCSDS allows them: after CCSDS_OEM_VERS in the header, and after
  META_START in each metadata block.
"""

from __future__ import annotations

import datetime as dt
import os
from pathlib import Path

import numpy as np
from oem import CURRENT_VERSION, OrbitEphemerisMessage
from oem.components import EphemerisSegment, HeaderSection, MetaDataSection

from ..core.arcs import Arcs
from ..errors import InputError
from ..files import atomic_path, make_folder, written_together
from ..units import CanonicalUnits

__all__ = ["REF_FRAME", "TIME_SYSTEM", "export_oem", "export_oem_by_trajectory"]

REF_FRAME = "BODY_FIXED"
TIME_SYSTEM = "TDB"


def _fmt(t: dt.datetime) -> str:
    return t.strftime("%Y-%m-%dT%H:%M:%S.%f")


def _one_line(name: str, value: str) -> str:
    if not value or any(c in value for c in "\r\n"):
        raise InputError(f"{name} must be a non-empty single line, got {value!r}")
    return value


def export_oem(
    arcs: Arcs,
    path: str | os.PathLike,
    *,
    epoch: str | dt.datetime = "2030-01-01T00:00:00",
    noisy: bool = True,
    originator: str = "hamgrav",
) -> Path:
    """Write the arcs of one trajectory to an OEM file at ``path``, one segment per arc.

    Args:
        arcs: the arcs. All of them must belong to one trajectory (see the module docstring).
            Use :func:`export_oem_by_trajectory` or ``arcs.subset`` for a whole campaign.
        path: the output file. Its folder must exist. The file is written to a temporary file
            beside it and then moved into place, so a failed export leaves nothing at ``path``
            and does not touch a file that is already there.
        epoch: the TDB epoch of canonical time 0, as an ISO string or a naive datetime.
        noisy: write the noisy ``arcs.states`` (True) or the ``arcs.true_states`` (False).
        originator: the header ORIGINATOR.

    The states are written as body-fixed position [km] and rotating-frame velocity [km/s].
    Canonical time is converted with ``arcs.spin_period_s / (2 pi)`` seconds per unit.

    Returns:
        ``path`` as a Path.

    Raises:
        ValueError: for a missing folder, no arcs or samples, more than one trajectory, states
            or times that are not finite, samples not strictly increasing at microsecond
            resolution, or arcs that overlap in time.
    """
    path = Path(path)
    if not path.parent.is_dir():
        raise InputError(f"output folder {path.parent} does not exist; create it first")
    if arcs.n_arcs < 1 or arcs.samples_per_arc < 1:
        raise InputError("there are no arcs (or no samples) to export")
    trajectories = np.unique(arcs.trajectory)
    if trajectories.size != 1:
        raise InputError(
            f"an OEM describes one object, but these arcs come from {trajectories.size} "
            "trajectories; use export_oem_by_trajectory, or arcs.subset"
        )
    traj = int(trajectories[0])
    kind = arcs.trajectory_kind[traj]
    originator = _one_line("originator", originator)
    body = _one_line("body_name", arcs.body_name).upper()
    t0 = dt.datetime.fromisoformat(epoch) if isinstance(epoch, str) else epoch
    if t0.tzinfo is not None:
        raise InputError(f"epoch must be a TDB date without a time zone, got {epoch!r}")

    units = CanonicalUnits(arcs.gm_m3_s2, arcs.spin_period_s)
    states = arcs.states if noisy else arcs.true_states
    pos_m, vel_m_s = units.state_from_canonical(states)
    seconds = units.from_time(arcs.times)
    if not (np.all(np.isfinite(pos_m)) and np.all(np.isfinite(vel_m_s))):
        raise InputError("states must be finite to be exported")
    if not np.all(np.isfinite(seconds)):
        raise InputError("times must be finite to be exported")
    micro = np.rint(seconds * 1e6).astype(np.int64)
    if np.any(np.diff(micro, axis=1) <= 0):
        raise InputError("the samples of an arc must be strictly increasing (to 1 microsecond)")
    order = np.argsort(micro[:, 0], kind="stable")
    if np.any(micro[order[1:], 0] < micro[order[:-1], -1]):
        raise InputError("arcs overlap in time; OEM segments must not overlap")

    meta = {
        "OBJECT_NAME": f"{kind}-{traj}",
        "OBJECT_ID": f"HAMGRAV-{body}-{arcs.seed}-{kind.upper()}-{traj}",
        "CENTER_NAME": body,
        "REF_FRAME": REF_FRAME,
        "TIME_SYSTEM": TIME_SYSTEM,
    }
    segments = []
    for k in order:
        epochs = [t0 + dt.timedelta(microseconds=int(us)) for us in micro[k]]
        columns = (*(pos_m[k] / 1e3).T.tolist(), *(vel_m_s[k] / 1e3).T.tolist())
        metadata = MetaDataSection(
            {**meta, "START_TIME": _fmt(epochs[0]), "STOP_TIME": _fmt(epochs[-1])}
        )
        segments.append(EphemerisSegment(metadata, (tuple(epochs), *map(tuple, columns))))
    now = dt.datetime.now(dt.UTC).replace(tzinfo=None)
    header = HeaderSection(
        {"CCSDS_OEM_VERS": CURRENT_VERSION, "CREATION_DATE": _fmt(now), "ORIGINATOR": originator}
    )
    message = OrbitEphemerisMessage(header, segments)  # checks the package's constraints

    origin = ", ".join(repr(float(c)) for c in arcs.body_origin_m)
    header_comments = [
        f"hamgrav arcs of {arcs.body_name}, trajectory {kind}-{traj}, seed {arcs.seed}, "
        f"{'noisy' if noisy else 'true'} states, one segment per arc",
        f"REF_FRAME {REF_FRAME}: body-fixed frame rotating with the body about +Z, "
        f"spin period {arcs.spin_period_s:.17g} s, origin at ({origin}) m in the mesh frame",
        "velocities are relative to the rotating body-fixed frame (not inertial)",
        f"GM {arcs.gm_m3_s2:.17g} m^3/s^2; canonical time 0 = {_fmt(t0)} TDB",
    ]
    if noisy:
        header_comments.append(
            f"noise per component: sigma_r {float(arcs.sigma_r_m)!r} m, "
            f"sigma_v {float(arcs.sigma_v_m_s)!r} m/s"
        )
    with atomic_path(path, suffix=".oem") as tmp:
        message.save_as(tmp, file_format="kvn")
        head, *blocks = tmp.read_text(encoding="utf-8").split("META_START\n")
        first, rest = head.split("\n", 1)
        text = "\n".join([first, *(f"COMMENT {c}" for c in header_comments), rest])
        for k, block in zip(order, blocks, strict=True):
            text += f"META_START\nCOMMENT hamgrav arc {k}\n{block}"
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
    return path


def export_oem_by_trajectory(arcs: Arcs, folder: str | os.PathLike, **kwargs) -> list[Path]:
    """Write one OEM file per trajectory to ``folder``, named ``<kind>-<index>.oem``.

    ``kwargs`` are passed on to :func:`export_oem`. The files are written together: a failure
    part-way (a full disk, an interrupt) leaves none of them, nor a folder made for them.
    """
    folder = Path(folder)
    paths = []
    with written_together():
        make_folder(folder)
        for traj in np.unique(arcs.trajectory):
            sub = arcs.subset(np.flatnonzero(arcs.trajectory == traj))
            name = f"{arcs.trajectory_kind[int(traj)]}-{int(traj)}.oem"
            paths.append(export_oem(sub, folder / name, **kwargs))
    return paths
