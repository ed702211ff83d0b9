"""Import tracking from CCSDS Orbit Ephemeris Messages (KVN or XML) into an arcs dataset.

Each file is one trajectory (an OEM describes one object). Its states are converted once,
here, to hamgrav's canonical body-fixed states (q, p):

- Frames. A body-fixed REF_FRAME (``BODY_FIXED``, hamgrav's own export, or ``IAU_<BODY>``)
  holds body-fixed positions and velocities relative to the rotating frame. An inertial
  REF_FRAME (``ICRF``, ``EME2000``, ``J2000``, ``GCRF``) is turned into the body-fixed frame
  with a :class:`~hamgrav.bodies.rotation.RotationModel` (pole, prime meridian at its epoch,
  the body's spin period). EME2000 is treated as the ICRF: the frame bias (about 23 mas, 0.1
  mm per km of range) is neglected. The states must be relative to the body's centre
  (CENTER_NAME names the body: its name as a word, its NAIF ID or a SPICE name of it, see
  :func:`hamgrav.io.naif.centre_is_body`; never a barycentre) and its frame origin
  (``origin_m`` in the mesh frame).
- Time. Every TIME_SYSTEM astropy knows (UTC, TAI, TT, TDB, ...) is read and converted to TDB;
  canonical time is (t - epoch) / (spin_period_s / 2 pi), with ``epoch`` the TDB epoch of
  canonical time 0.
- Arcs. Each segment is split at gaps (a step longer than ``max_gap_s``, default 1.5 times
  the segment's median step), and each run of samples is cut into arcs of ``samples``
  consecutive samples (the remainder of a run is dropped and counted). Without ``samples``
  each run is one arc, and all runs must then have the same length. This part, and the
  checks of the states, are shared with the SPK importer (:mod:`hamgrav.io.tracks`).
- Noise. ``sigma_r_m`` [m] and ``sigma_v_m_s`` [m/s] per component, else from the
  covariance blocks when every file has them: sqrt of the mean of trace(C_rr) / 3 and
  trace(C_vv) / 3 over all blocks (traces do not depend on the covariance frame; the
  frame's rotation, omega x r, is neglected in the velocity part), else from the COMMENT
  lines of hamgrav's own export.
- hamgrav's own KVN export documents its frame in COMMENT lines: when they are present,
  canonical time 0, the frame origin and the noise levels default to theirs, and its GM and
  spin period must match the body's. Its export re-imported gives the same arcs (times to
  the file's 1 microsecond, states to 15 digits).

Imported arcs have no truth: ``true_states`` are NaN, the truth mascon set is empty and
``interior`` is ``"none"`` (:attr:`Arcs.has_truth` is False).
"""

from __future__ import annotations

import math
import os
import re
import warnings
from pathlib import Path

import numpy as np
from astropy.time import Time

from ..bodies.catalogue import Body
from ..bodies.rotation import RotationModel
from ..core.arcs import Arcs
from ..errors import DatasetError, HamgravWarning, InputError
from ..files import same_file
from .naif import centre_is_body
from .oem import REF_FRAME as HAMGRAV_FRAME
from .tracks import (
    Track,
    check_arc_options,
    check_noise,
    epoch_zero,
    rotation_zero,
    tracks_to_arcs,
)
from .tracks import check_positions as _check_positions  # noqa: F401 (its former home)

__all__ = ["import_oem", "BODY_FIXED_FRAMES", "INERTIAL_FRAMES"]

#: REF_FRAME values read as body-fixed (besides ``IAU_<BODY>``).
BODY_FIXED_FRAMES = (HAMGRAV_FRAME,)
#: REF_FRAME values read as inertial (ICRF axes).
INERTIAL_FRAMES = ("ICRF", "ICRF2", "ICRF3", "EME2000", "J2000", "GCRF")

_COMMENTS = {
    "epoch": re.compile(r"canonical time 0 = (\S+) TDB"),
    "origin": re.compile(r"origin at \(([^)]*)\) m in the mesh frame"),
    "gm": re.compile(r"GM (\S+) m\^3/s\^2"),
    "spin": re.compile(r"spin period (\S+) s"),
    "sigmas": re.compile(r"sigma_r (\S+) m, sigma_v (\S+) m/s"),
}


def _hamgrav_comments(path: Path) -> dict:
    """Values from the header COMMENT lines of hamgrav's own KVN export (empty otherwise)."""
    try:
        head = path.read_text(encoding="utf-8", errors="replace")[:20000]
    except OSError as exc:
        raise DatasetError(f"{path}: cannot be read ({exc})") from None
    lines = [ln[8:] for ln in head.splitlines() if ln.startswith("COMMENT ")]
    if not any(ln.startswith("hamgrav arcs of ") for ln in lines):
        return {}
    text = "\n".join(lines)
    found = {}
    for key, pattern in _COMMENTS.items():
        match = pattern.search(text)
        if match:
            found[key] = match.groups()
    out = {}
    try:
        if "epoch" in found:
            out["epoch"] = found["epoch"][0]
        if "origin" in found:
            out["origin_m"] = tuple(float(v) for v in found["origin"][0].split(","))
        if "gm" in found:
            out["gm_m3_s2"] = float(found["gm"][0])
        if "spin" in found:
            out["spin_period_s"] = float(found["spin"][0])
        if "sigmas" in found:
            out["sigmas"] = (float(found["sigmas"][0]), float(found["sigmas"][1]))
    except ValueError as exc:
        raise DatasetError(f"{path}: malformed hamgrav COMMENT line ({exc})") from None
    return out


def _read(path: Path):
    from oem import OrbitEphemerisMessage

    try:
        with warnings.catch_warnings():
            # oem warns, then falls back to datetimes, on a time system astropy does not know
            warnings.filterwarnings("error", message="Unsupported TIME_SYSTEM")
            return OrbitEphemerisMessage.open(path)
    except Exception as exc:  # the oem package raises many kinds on malformed input
        raise DatasetError(
            f"{path} is not a readable CCSDS OEM ({type(exc).__name__}: {exc}); check that it "
            "is an OEM in KVN or XML with a TIME_SYSTEM astropy knows (UTC, TAI, TT, TDB)"
        ) from None


def _frame_kind(frame: str, body_name: str, path: Path) -> str:
    name = frame.strip().upper()
    if name in BODY_FIXED_FRAMES or name == f"IAU_{body_name.upper()}":
        return "body-fixed"
    if name in INERTIAL_FRAMES:
        return "inertial"
    raise InputError(
        f"{path}: REF_FRAME {frame!r} is neither body-fixed ({', '.join(BODY_FIXED_FRAMES)}, "
        f"IAU_{body_name.upper()}) nor inertial ({', '.join(INERTIAL_FRAMES)}); convert the "
        "file to one of these frames"
    )


def _quiet_erfa(call, notes: set):
    """``call()`` with ERFA's "dubious year" warnings (UTC epochs outside the span whose leap
    seconds ERFA knows; multi-line, one per conversion) noted in ``notes`` instead of shown;
    any other warning is shown as usual."""
    from erfa import ErfaWarning

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ErfaWarning)
        result = call()
    for w in caught:
        if issubclass(w.category, ErfaWarning) and "dubious year" in str(w.message):
            notes.add("dubious year")
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return result


def import_oem(
    paths,
    body: Body,
    *,
    samples: int | None = None,
    max_gap_s: float | None = None,
    rotation: RotationModel | None = None,
    epoch: str | None = None,
    sigma_r_m: float | None = None,
    sigma_v_m_s: float | None = None,
    origin_m=None,
) -> Arcs:
    """Read CCSDS OEM files into :class:`Arcs` (canonical units; see the module docstring).

    Args:
        paths: OEM files (KVN or XML), one trajectory each, in the order of the trajectories.
        body: the central body (GM, spin period and name fix the units and the frame).
        samples: samples per arc; None: every gap-free run is one arc (runs of equal length).
        max_gap_s: split a segment where consecutive samples are more than this apart [s]
            (default 1.5 times the segment's median step).
        rotation: the rotation model for inertial REF_FRAMEs (default ``body.rotation``).
        epoch: TDB epoch (ISO) of canonical time 0 (default: hamgrav's COMMENT, else the
            earliest sample).
        sigma_r_m: position noise per component [m]; sigma_v_m_s: rotating-frame velocity
            noise per component [m/s] (defaults: covariance blocks, else hamgrav COMMENTs).
        origin_m: the frame origin (3,) in the body mesh's frame [m] (default: hamgrav's
            COMMENT, else the mesh origin).

    Raises:
        InputError / DatasetError: a missing or unreadable file, an unknown frame or time
            system, another central body, no rotation model for an inertial frame, no noise
            level, arcs of unequal length without ``samples``, or no arc at all.
    """
    paths = [Path(p) for p in ([paths] if isinstance(paths, str | os.PathLike) else paths)]
    if not paths:
        raise InputError("give at least one OEM file")
    check_arc_options(samples, max_gap_s, sigma_r_m, sigma_v_m_s)
    rotation_source = (
        "--rotation-epoch"
        if rotation is not None
        else f"the rotation epoch of body {body.name!r} in the catalogue"
    )
    rotation = rotation if rotation is not None else body.rotation
    name = body.name

    for k, path in enumerate(paths):
        if path.is_dir():
            raise InputError(f"{path} is a folder; give the OEM files in it (e.g. {path}/*.oem)")
        if not path.is_file():
            raise InputError(f"OEM file not found: {path}")
        for other in paths[:k]:
            if same_file(path, other):
                raise InputError(
                    f"OEM file {path} is given twice (also as {other}); each file is one "
                    "trajectory: give it once"
                )
    comments = [_hamgrav_comments(p) for p in paths]
    for path, c in zip(paths, comments, strict=True):
        for key, have in (("gm_m3_s2", body.gm_m3_s2), ("spin_period_s", body.spin_period_s)):
            if key in c and not math.isclose(c[key], have, rel_tol=1e-12):
                raise InputError(
                    f"{path} was written by hamgrav for {key} = {c[key]!r}, but body "
                    f"{name!r} has {have!r}; import it with the body it was simulated for"
                )
    first = next((c for c in comments if c), {})
    check_one_frame(paths, comments)
    erfa_notes: set = set()
    messages = [_quiet_erfa(lambda p=p: _read(p), erfa_notes) for p in paths]

    # every sample: (file, segment) -> epochs (TDB Time), positions, velocities [m, m/s]
    segments = []
    for traj, (path, message) in enumerate(zip(paths, messages, strict=True)):
        for seg in message.segments:
            meta = seg.metadata
            centre = str(meta["CENTER_NAME"])
            if re.search(r"barycent", centre, re.IGNORECASE):
                raise InputError(
                    f"{path}: CENTER_NAME {centre!r} is a barycentre, not the centre of body "
                    f"{name!r}; the states must be relative to the body itself"
                )
            # the name as a word of it ('25143 ITOKAWA', '67P/CHURYUMOV-GERASIMENKO'), or
            # the body's NAIF ID or SPICE name ('2025143', 'CHURYUMOV-GERASIMENKO')
            if not centre_is_body(centre, body):
                raise InputError(
                    f"{path}: CENTER_NAME {centre!r} is not body {name!r}; the states must be "
                    "relative to the body (pass the matching --body)"
                )
            kind = _frame_kind(str(meta["REF_FRAME"]), name, path)
            if kind == "inertial" and rotation is None:
                raise InputError(
                    f"{path}: REF_FRAME {meta['REF_FRAME']} is inertial and body {name!r} has "
                    "no rotation model; give --pole-ra, --pole-dec and --prime-meridian"
                )
            states = list(seg.states)
            epochs = _quiet_erfa(lambda st=states: Time([s.epoch for s in st]).tdb, erfa_notes)
            pos = np.array([s.position for s in states], dtype=float) * 1e3
            vel = np.array([s.velocity for s in states], dtype=float) * 1e3
            if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(vel))):
                raise DatasetError(f"{path}: a state is not finite")
            covs = [c.matrix for c in seg.covariances]
            track = Track(path, traj, kind, epochs, pos, vel)
            segments.append((path, track, covs, [c.epoch for c in seg.covariances]))

    epoch_source = "--epoch" if epoch else "the epoch in the files' hamgrav COMMENT lines"
    epoch = epoch or first.get("epoch")
    t0 = epoch_zero(epoch, epoch_source, [seg[1] for seg in segments])
    rotation_t0 = rotation_zero(rotation, rotation_source)

    # noise levels
    covs = [c for seg in segments for c in seg[2]]
    has_cov = all(seg[2] for seg in segments)
    noise_source = "options"
    if sigma_r_m is None or sigma_v_m_s is None:
        # the one option given, if any: the other level comes from the files
        given = (
            "--sigma-r"
            if sigma_r_m is not None
            else "--sigma-v"
            if sigma_v_m_s is not None
            else None
        )
        if has_cov and covs:
            for seg in segments:
                diagonals = np.diagonal(np.asarray(seg[2], dtype=float), axis1=1, axis2=2)
                if not np.all(np.isfinite(diagonals)) or np.any(diagonals < 0):
                    raise InputError(
                        f"{seg[0]}: a covariance block has a negative or non-finite variance "
                        "on its diagonal; fix the file, or pass --sigma-r [m] and --sigma-v [m/s]"
                    )
                check_covariances(seg[0], seg[2], seg[3])
            mats = np.asarray(covs, dtype=float) * 1e6  # km^2, km^2/s, km^2/s^2 -> SI
            cov_r = math.sqrt(float(np.mean(np.trace(mats[:, :3, :3], axis1=1, axis2=2))) / 3)
            cov_v = math.sqrt(float(np.mean(np.trace(mats[:, 3:, 3:], axis1=1, axis2=2))) / 3)
            sigma_r_m = sigma_r_m if sigma_r_m is not None else cov_r
            sigma_v_m_s = sigma_v_m_s if sigma_v_m_s is not None else cov_v
            noise_source = "covariance" if given is None else f"{given} and covariance"
        elif "sigmas" in first:
            sigma_r_m = sigma_r_m if sigma_r_m is not None else first["sigmas"][0]
            sigma_v_m_s = sigma_v_m_s if sigma_v_m_s is not None else first["sigmas"][1]
            noise_source = "hamgrav comments" if given is None else f"{given} and hamgrav comments"
        else:
            raise InputError(
                "the files give no noise level (no covariance blocks); pass --sigma-r [m] "
                "and --sigma-v [m/s]"
            )

    check_noise(sigma_r_m, sigma_v_m_s, noise_source)
    origin = origin_m if origin_m is not None else first.get("origin_m", (0.0, 0.0, 0.0))
    arcs = tracks_to_arcs(
        [seg[1] for seg in segments],
        body,
        t0=t0,
        samples=samples,
        max_gap_s=max_gap_s,
        rotation=rotation,
        rotation_t0=rotation_t0,
        sigma_r_m=sigma_r_m,
        sigma_v_m_s=sigma_v_m_s,
        origin_m=origin,
        trajectory_kind=[_kind_of(m) for m in messages],
        centre_hint="CENTER_NAME",
        config={
            "source": "ccsds-oem",
            "files": [str(p) for p in paths],
            "noise_from": noise_source,
        },
    )
    if erfa_notes:
        warnings.warn(
            "UTC epochs outside the span whose leap seconds ERFA knows: converted to TDB with "
            "ERFA's extrapolation (no leap seconds beyond it)",
            HamgravWarning,
            stacklevel=2,
        )
    return arcs


#: Most negative eigenvalue of a covariance block's correlation matrix accepted: KVN files
#: print 7 digits or so, and rounding a positive semi-definite matrix to them moves its
#: eigenvalues by about 1e-7; a block more negative than this is not a covariance.
COVARIANCE_TOLERANCE = 1e-6


def check_covariances(path: Path, matrices, epochs) -> None:
    """Refuse covariance blocks that are not symmetric positive (semi-)definite: the noise
    level is read from their diagonals, and a block that is no covariance at all says the
    diagonals are not what the file claims either. Judged on the correlation matrix
    C_ij / sqrt(C_ii C_jj), so that position and velocity blocks of very different sizes
    weigh alike."""
    for k, (matrix, epoch) in enumerate(zip(matrices, epochs, strict=True)):
        c = np.asarray(matrix, dtype=float)
        d = np.sqrt(np.where(np.diagonal(c) > 0, np.diagonal(c), 1.0))
        r = c / np.outer(d, d)
        where = f"{path}: covariance block {k + 1} (EPOCH {epoch})"
        fix = "fix the file, or pass --sigma-r [m] and --sigma-v [m/s]"
        if not np.allclose(r, r.T, rtol=0.0, atol=COVARIANCE_TOLERANCE):
            raise InputError(f"{where} is not symmetric; a covariance is: {fix}")
        lowest = float(np.linalg.eigvalsh(0.5 * (r + r.T))[0])
        if lowest < -COVARIANCE_TOLERANCE:
            raise InputError(
                f"{where} is not positive definite (its correlation matrix has the eigenvalue "
                f"{lowest:.3g}; a correlation beyond +-1 does that): {fix}"
            )


def check_one_frame(paths, comments) -> None:
    """Refuse files of one import whose hamgrav COMMENT lines state different frame origins:
    their positions are about different points (two campaigns of one body, recentred on
    their own truths), and one origin for all would shift some of them without a word."""
    stated = [(p, c["origin_m"]) for p, c in zip(paths, comments, strict=True) if "origin_m" in c]
    if not stated:
        return
    origin = stated[0][1]
    other = [(p, o) for p, o in stated if math.dist(o, origin) > 1e-6]  # round-off: 1 um
    if other:
        same = [str(p) for p, o in stated if math.dist(o, origin) <= 1e-6]
        apart = max(math.dist(o, origin) for _, o in other)
        raise InputError(
            f"the files are in frames of different origins ({apart:.3g} m apart): "
            f"{', '.join(same)} at {_point(origin)} m; "
            + "; ".join(f"{p} at {_point(o)} m" for p, o in other)
            + " (mesh frame); import the files of each frame separately"
        )


def _point(xyz) -> str:
    return "(" + ", ".join(f"{v:.6g}" for v in xyz) + ")"


def _kind_of(message) -> str:
    """The trajectory kind of a file: hamgrav's ``<kind>-<n>`` OBJECT_NAME, else "tracked"."""
    name = str(message.segments[0].metadata["OBJECT_NAME"])
    match = re.fullmatch(r"([a-z]+)-\d+", name)
    return match.group(1) if match else "tracked"
