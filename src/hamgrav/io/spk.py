"""SPICE SPK kernels: simulated tracking out (type 13), reconstructed tracking in.

Writing (:func:`write_spk`, ``hamgrav simulate --spk``), conventions of the file:

- Targets and segments. Trajectory k is target ``TARGET_BASE - k`` (-1000, -1001, ...:
  negative, as NAIF numbers spacecraft), one type-13 segment (Hermite interpolation, unequal
  steps) per arc. One segment per trajectory would make SPICE interpolate across the gaps
  between arcs, and one target for all trajectories would let overlapping trajectories mask
  each other (SPICE reads the last segment covering an epoch).
- Centre. The body's NAIF ID (:func:`hamgrav.io.naif.body_naif_id`), else ``centre``, else
  :data:`DEFAULT_CENTRE`, an ID NAIF assigns to no body.
- Frame ``J2000`` (ICRF axes; the frame bias is neglected, as the OEM importer does). The
  canonical body-fixed states are turned inertial with the body's rotation model, else with
  :func:`default_rotation`: the pole on J2000's +Z and the body axes on J2000's axes at
  canonical time 0.
- Time: ephemeris time, TDB seconds past J2000.0; canonical time 0 is ``epoch`` (TDB).
  Units km and km/s.
- The comment area documents the file in text, and repeats it in one ``hamgrav-json`` line
  that the importer reads: body, GM, spin period, frame origin, canonical time 0, rotation
  model, noise levels, and the target and kind of each trajectory. So the file re-imported
  gives the same arcs (to about 1e-11 canonical: ephemeris times near 2030 hold about
  1e-7 s, and the rotation angle follows them).

Reading (:func:`read_spk`, :func:`import_spk`, ``hamgrav import-spk``): the kernels are
loaded into SPICE's kernel pool, which is cleared (``kclear``) before and after, so nothing
is left loaded between calls (kernels loaded by the caller in the same process are unloaded
too). States of the target relative to the body (any SPK chain SPICE can follow) are
sampled at each segment's own epochs (types 8, 9, 12 and 13 hold discrete states), else
every ``step_s`` seconds through each interval of the target's coverage, and turned into the
body frame:

- when the kernels define the body's frame (``cidfrm``: an FK's ``OBJECT_<ID>_FRAME``, or a
  built-in ``IAU_<BODY>`` frame whose PCK constants are loaded), with its rotation matrix;
- else with a rotation model: the one given, else hamgrav's own (the comment area), else the
  body's. Either way r_body = M r_J2000, p = M v_J2000, and the rotating-frame velocity is
  p - omega x r_body at the body's spin rate, as :meth:`RotationModel.to_body` does.

The arcs are then cut as the OEM importer cuts them (:mod:`hamgrav.io.tracks`).
"""

from __future__ import annotations

import json
import math
import os
import re
import warnings
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from astropy.time import Time, TimeDelta

from ..bodies.catalogue import Body
from ..bodies.rotation import J2000_TDB, RotationModel
from ..core.arcs import Arcs
from ..errors import DatasetError, HamgravWarning, InputError
from ..files import atomic_path, same_file
from ..units import CanonicalUnits
from .naif import body_naif_id, naif_code, naif_name
from .tracks import (
    Track,
    check_arc_options,
    check_noise,
    epoch_zero,
    rotation_zero,
    tdb,
    tracks_to_arcs,
)

__all__ = [
    "ALL_TARGETS",
    "DEFAULT_CENTRE",
    "DEFAULT_EPOCH",
    "SpkStates",
    "TARGET_BASE",
    "default_rotation",
    "import_spk",
    "read_spk",
    "targets_about",
    "write_spk",
]

#: Canonical time 0 of simulated arcs written to an SPK (TDB): they carry no epoch of their own.
DEFAULT_EPOCH = "2030-01-01T00:00:00"
#: Target of trajectory k: ``TARGET_BASE - k``.
TARGET_BASE = -1000
#: Centre of a body without a NAIF ID (e.g. the synthetic ones): no body has this ID.
DEFAULT_CENTRE = 9_999_999
#: The frame of the written states.
FRAME = "J2000"
#: Hermite degree of the written segments (4 states per window), lower for shorter arcs.
DEGREE = 7
#: Segment types that hold discrete states, sampled at their own epochs by default.
DISCRETE_TYPES = (8, 9, 12, 13)
#: A kernel frame whose spin differs from the body's by more than this (relative) is warned
#: about; by more than :data:`SPIN_REFUSED`, or about another axis, it is refused.
SPIN_WARNED = 1e-6
SPIN_REFUSED = 1e-3
_JSON = "hamgrav-json "


def _j2000() -> Time:
    return Time(J2000_TDB, scale="tdb")


def _et(t: Time) -> float:
    """Ephemeris time [s, TDB past J2000.0] of a TDB Time."""
    return float((t - _j2000()).to_value("s"))


def _time(et) -> Time:
    """TDB Time of ephemeris times [s]."""
    return _j2000() + TimeDelta(np.asarray(et, dtype=float), format="sec")


def _spice_line(exc) -> str:
    """A SPICE error in one line: its short message and the first sentence of the long."""
    short = getattr(exc, "short", "") or type(exc).__name__
    long = " ".join(str(getattr(exc, "long", "") or "").split())
    first = long.split(". ")[0].rstrip(".")
    return f"{short}: {first}" if first else short


def default_rotation(spin_period_s: float, epoch: str) -> RotationModel:
    """The rotation model of a body without one: the pole on J2000's +Z and the body axes on
    J2000's at ``epoch`` (TDB ISO), spinning at ``spin_period_s`` [s] (M = R3(W + 90 deg)
    with the pole at RA 0, so W0 = 270 deg)."""
    return RotationModel(0.0, 90.0, 270.0, spin_period_s, epoch)


# --------------------------------------------------------------------------------------------
# Writing


def write_spk(
    arcs: Arcs,
    path: str | os.PathLike,
    body: Body,
    *,
    epoch: str | None = None,
    noisy: bool = True,
    centre: int | None = None,
    rotation: RotationModel | None = None,
) -> Path:
    """Write the arcs to a type-13 SPK at ``path`` (see the module docstring).

    Args:
        arcs: the arcs, of any number of trajectories (one target each).
        path: the output file (``.bsp``); its folder must exist. Written to a temporary file
            beside it, checked, then moved into place: a failure leaves nothing at ``path``.
        body: the body the arcs were simulated for (its GM and spin period must be the
            arcs'); its NAIF ID is the centre and its rotation model turns the states.
        epoch: TDB epoch (ISO) of canonical time 0 (default: the arcs' own, which imported
            tracking records, else :data:`DEFAULT_EPOCH`).
        noisy: write the noisy ``arcs.states`` (True) or the ``arcs.true_states``.
        centre: NAIF ID of the centre when the body has none (default :data:`DEFAULT_CENTRE`).
        rotation: the rotation model (default ``body.rotation``, else
            :func:`default_rotation` at ``epoch``).

    Returns:
        ``path`` as a Path.

    Raises:
        InputError: another body, no arcs, states or times that are not finite, samples not
            increasing, arcs of one trajectory that overlap, or a bad epoch or centre.
    """
    import spiceypy

    path = Path(path)
    if arcs.n_arcs < 1 or arcs.samples_per_arc < 2:
        raise InputError("there are no arcs (or fewer than 2 samples per arc) to write to an SPK")
    for key in ("gm_m3_s2", "spin_period_s"):
        if not math.isclose(getattr(arcs, key), getattr(body, key), rel_tol=1e-12):
            raise InputError(
                f"the arcs have {key} = {getattr(arcs, key)!r} and body {body.name!r} has "
                f"{getattr(body, key)!r}; write the SPK with the body they were simulated for"
            )
    known = body_naif_id(body)
    centre = known if known is not None else centre if centre is not None else DEFAULT_CENTRE
    if TARGET_BASE - arcs.n_trajectories < int(centre) <= TARGET_BASE:
        raise InputError(f"centre {centre} is also a target ID; give another NAIF ID")
    epoch = epoch or arcs.config.get("epoch_tdb") or DEFAULT_EPOCH
    t0 = tdb(epoch, "epoch", "--epoch")
    rotation = rotation or body.rotation or default_rotation(body.spin_period_s, epoch)
    rotation_t0 = tdb(rotation.epoch, "the rotation model's epoch", "--rotation-epoch")
    units = CanonicalUnits(arcs.gm_m3_s2, arcs.spin_period_s)
    states = arcs.states if noisy else arcs.true_states
    pos_m, vel_m_s = units.state_from_canonical(states)
    seconds = units.from_time(arcs.times)
    if not (np.all(np.isfinite(pos_m)) and np.all(np.isfinite(vel_m_s))):
        raise InputError("states must be finite to be written to an SPK")
    if not np.all(np.isfinite(seconds)):
        raise InputError("times must be finite to be written to an SPK")
    et = _et(t0) + seconds
    if np.any(np.diff(et, axis=1) <= 0):
        raise InputError("the samples of an arc must be strictly increasing in time")
    since = (t0 - rotation_t0).to_value("s") + seconds  # seconds past the rotation epoch
    segments = []  # (target, first, last, states [km, km/s], ephemeris times, segment id)
    for traj in range(arcs.n_trajectories):
        ks = np.flatnonzero(arcs.trajectory == traj)
        ks = ks[np.argsort(et[ks, 0], kind="stable")]
        if np.any(et[ks[1:], 0] <= et[ks[:-1], -1]):
            raise InputError(
                f"arcs of trajectory {traj} overlap in time; an SPK target's segments must "
                "not overlap (SPICE would read only the last)"
            )
        for k in ks:
            r_i, v_i = rotation.to_inertial(since[k], pos_m[k], vel_m_s[k])
            data = np.concatenate([r_i, v_i], axis=1) / 1e3
            segid = f"hamgrav {arcs.trajectory_kind[traj]}-{traj} arc {k}"[:40]
            segments.append((TARGET_BASE - traj, et[k, 0], et[k, -1], data, et[k], segid))

    kinds = {
        str(TARGET_BASE - t): f"{arcs.trajectory_kind[t]}-{t}" for t in range(arcs.n_trajectories)
    }
    record = {
        "body": arcs.body_name,
        "centre": int(centre),
        "frame": FRAME,
        "gm_m3_s2": float(arcs.gm_m3_s2),
        "spin_period_s": float(arcs.spin_period_s),
        "origin_m": [float(v) for v in arcs.body_origin_m],
        "epoch_tdb": epoch,
        "rotation": rotation.describe(),
        "targets": kinds,
        "noisy": bool(noisy),
        **(
            {"sigma_r_m": float(arcs.sigma_r_m), "sigma_v_m_s": float(arcs.sigma_v_m_s)}
            if noisy
            else {}
        ),
    }
    comments = [
        f"hamgrav arcs of {arcs.body_name}, seed {arcs.seed}, {'noisy' if noisy else 'true'} "
        "states, one type-13 segment per arc",
        "targets: " + ", ".join(f"{t} {name}" for t, name in kinds.items()),
        f"centre {centre}, frame {FRAME}; positions km, velocities km/s (inertial)",
        f"body frame = M(t) J2000 with M = R3(W) R1(90 - dec) R3(90 + ra): pole ra "
        f"{rotation.pole_ra_deg!r} deg, dec {rotation.pole_dec_deg!r} deg, W = "
        f"{rotation.prime_meridian_deg!r} deg at {rotation.epoch} TDB + 360 deg per "
        f"{rotation.spin_period_s!r} s",
        f"body frame origin at ({', '.join(repr(v) for v in record['origin_m'])}) m in the "
        "mesh frame",
        f"GM {arcs.gm_m3_s2!r} m^3/s^2; canonical time 0 = {epoch} TDB",
    ]
    if noisy:
        comments.append(
            f"noise per component: sigma_r {float(arcs.sigma_r_m)!r} m, "
            f"sigma_v {float(arcs.sigma_v_m_s)!r} m/s (body frame)"
        )
    comments.append(_JSON + json.dumps(record, allow_nan=False))

    with atomic_path(path, suffix=".bsp") as tmp:
        tmp.unlink()  # SPICE creates the file itself and refuses an existing one
        try:
            handle = spiceypy.spkopn(str(tmp), "hamgrav tracking", 4096)
            try:
                for target, first, last, data, epochs, segid in segments:
                    degree = min(DEGREE, 2 * len(epochs) - 1)
                    spiceypy.spkw13(
                        handle, target, int(centre), FRAME, first, last, segid, degree,
                        len(epochs), data, epochs,
                    )  # fmt: skip
                spiceypy.dafac(handle, comments)
            finally:
                spiceypy.spkcls(handle)
        except spiceypy.exceptions.SpiceyError:
            size = sum(8 * (data.size + epochs.size) + 1024 for *_, data, epochs, _ in segments)
            refused = _disk_refusal(tmp, size + 1024 * (len(comments) + 8))
            if refused is not None:  # raised as a DiskError naming path by atomic_path
                raise refused from None
            raise
        _check_written(tmp, segments, int(centre))
    return path


def _disk_refusal(tmp: Path, nbytes: int) -> OSError | None:
    """The disk's error when ``nbytes`` more cannot be written to ``tmp``, else None.

    SPICE reports a full disk (or a file-size limit) without the system's error: as a record
    it cannot read back (SPICE(DAFCRNOTFOUND)). Trying to write what the file still needed
    tells a full disk from a real SPICE error; ``tmp`` is removed afterwards either way."""
    try:
        with open(tmp, "ab") as fh:
            fh.write(bytes(nbytes))
            fh.flush()
            os.fsync(fh.fileno())
    except OSError as exc:
        return exc
    return None


def _check_written(path: Path, segments, centre: int) -> None:
    """Read the segments back from the file (not through the kernel pool): same targets,
    centre, frame, type, spans, epochs and states, bit for bit."""
    back = _segments(path)
    if len(back) != len(segments):
        raise DatasetError(f"{path}: {len(back)} segments written, {len(segments)} expected")
    for seg, (target, first, last, data, epochs, _) in zip(back, segments, strict=True):
        got = _segment_data(seg)
        same = (
            (seg.target, seg.centre, seg.frame, seg.type) == (target, centre, 1, 13)
            and (seg.start, seg.stop) == (first, last)
            and np.array_equal(got[0], epochs)
            and np.array_equal(got[1], data)
        )
        if not same:
            raise DatasetError(f"{path}: segment of target {target} did not read back as written")


# --------------------------------------------------------------------------------------------
# Segments and comments, read from the DAF file itself


@dataclass(frozen=True)
class _Segment:
    path: Path
    target: int
    centre: int
    frame: int
    type: int
    start: float
    stop: float
    begin: int
    end: int


def _segments(path: Path) -> list[_Segment]:
    """The segment summaries of an SPK file."""
    import spiceypy

    handle = spiceypy.dafopr(str(path))
    out = []
    try:
        spiceypy.dafbfs(handle)
        while spiceypy.daffna():
            dc, ic = spiceypy.dafus(spiceypy.dafgs(), 2, 6)
            ic = [int(v) for v in ic]
            out.append(_Segment(path, *ic[:4], float(dc[0]), float(dc[1]), ic[4], ic[5]))
    finally:
        spiceypy.dafcls(handle)
    return out


def _segment_data(seg: _Segment):
    """(epochs [s, ET], states (n, 6) [km, km/s]) of a type 8, 9, 12 or 13 segment."""
    import spiceypy

    handle = spiceypy.dafopr(str(seg.path))
    try:
        data = np.asarray(spiceypy.dafgda(handle, seg.begin, seg.end), dtype=float)
    finally:
        spiceypy.dafcls(handle)
    n = int(round(data[-1]))
    states = data[: 6 * n].reshape(n, 6)
    if seg.type in (8, 12):  # states, first epoch, step, window size - 1, n
        epochs = data[-4] + data[-3] * np.arange(n)
    else:  # states, epochs, epoch directory, window size - 1 (or degree), n
        epochs = data[6 * n : 7 * n]
    return epochs, states


def _comments(path: Path) -> dict:
    """hamgrav's record in the comment area of an SPK it wrote (empty otherwise)."""
    import spiceypy

    handle = spiceypy.dafopr(str(path))
    lines = []
    try:
        done = False
        while not done and len(lines) < 10000:
            _, buffer, done = spiceypy.dafec(handle, 100, 1001)
            lines += [ln for ln in buffer if ln]
    finally:
        spiceypy.dafcls(handle)
    for line in lines:
        if line.startswith(_JSON):
            try:
                record = json.loads(line[len(_JSON) :])
            except json.JSONDecodeError as exc:
                raise DatasetError(f"{path}: malformed hamgrav comment line ({exc})") from None
            return record if isinstance(record, dict) else {}
    return {}


# --------------------------------------------------------------------------------------------
# Reading


def _kernel_paths(kernels) -> list[Path]:
    """The kernel files, checked: they exist, are given once, and are kernels."""
    import spiceypy

    paths = [Path(p) for p in ([kernels] if isinstance(kernels, str | os.PathLike) else kernels)]
    if not paths:
        raise InputError("give at least one SPICE kernel (an SPK .bsp file)")
    for k, path in enumerate(paths):
        if path.is_dir():
            raise InputError(f"{path} is a folder; give the kernels in it (e.g. {path}/*.bsp)")
        if not path.is_file():
            raise InputError(f"kernel file not found: {path}")
        for other in paths[:k]:
            if same_file(path, other):
                raise InputError(f"kernel {path} is given twice (also as {other}); give it once")
        try:
            arch, kind = spiceypy.getfat(str(path))
        except spiceypy.exceptions.SpiceyError as exc:
            raise DatasetError(f"{path}: SPICE cannot read it ({_spice_line(exc)})") from None
        if (arch, kind) == ("KPL", "MK"):
            raise InputError(
                f"{path} is a meta-kernel; give the kernels it lists (SPKs, PCKs, FKs) instead"
            )
        if arch not in ("DAF", "KPL") or (arch == "DAF" and kind not in ("SPK", "PCK")):
            raise DatasetError(
                f"{path} is not a SPICE kernel hamgrav reads (SPICE sees architecture {arch!r}, "
                f"type {kind!r}); give SPK files (.bsp) and, for the body's frame, PCK or FK "
                "text kernels"
            )
    if not any(spiceypy.getfat(str(p)) == ("DAF", "SPK") for p in paths):
        raise InputError(
            f"no SPK among the kernels {', '.join(map(str, paths))}; give the SPK (.bsp) "
            "holding the spacecraft's trajectory"
        )
    return paths


@contextmanager
def _loaded(paths):
    """The kernels loaded into SPICE's pool, which is cleared before and after."""
    import spiceypy

    spiceypy.kclear()
    try:
        for path in paths:
            try:
                spiceypy.furnsh(str(path))
            except spiceypy.exceptions.SpiceyError as exc:
                raise DatasetError(f"{path}: SPICE cannot load it ({_spice_line(exc)})") from None
        yield
    finally:
        spiceypy.kclear()


@dataclass(frozen=True)
class SpkStates:
    """States of one SPK target relative to the body, in the body frame.

    Attributes:
        target: the target's NAIF ID.
        files: the SPKs holding the target's segments.
        pieces: one (epochs (n,) TDB Time, positions (n, 3) [m], rotating-frame velocities
            (n, 3) [m/s]) per segment, or per coverage interval when sampled at a step.
        frame: how the body frame was reached (``"IAU_ITOKAWA (kernels)"``,
            ``"J2000 + rotation model"``).
        rotation: the rotation model used (None when the kernels gave the frame).
        record: hamgrav's record from the comment area of the SPK holding the target
            (empty for other SPKs).
    """

    target: int
    files: tuple
    pieces: tuple
    frame: str
    rotation: RotationModel | None
    record: dict


def _spks(paths) -> list[Path]:
    import spiceypy

    return [p for p in paths if spiceypy.getfat(str(p)) == ("DAF", "SPK")]


def _target_id(target, spks, records) -> int:
    """The NAIF ID of ``target``: an integer, a name SPICE knows (built in or from an FK
    among the kernels), or a trajectory name of hamgrav's comment records (``orbit-0``)."""
    text = str(target).strip()
    if re.fullmatch(r"[+-]?\d+", text):
        return int(text)
    code = naif_code(text)
    if code is not None:
        return code
    for record in records:
        for code, name in record.get("targets", {}).items():
            if name.lower() == text.lower():
                return int(code)
    raise InputError(
        f"--target {text!r} is no NAIF ID and no name SPICE or the kernels "
        f"{', '.join(map(str, spks))} know; give the spacecraft's NAIF ID (e.g. -1000)"
    )


def _centre_id(body: Body, centre, records) -> tuple[int, str]:
    """The body's NAIF ID and where it came from."""
    if centre is not None:
        return int(centre), "--center"
    code = body_naif_id(body)
    if code is not None:
        return code, f"the NAIF ID of body {body.name!r}"
    for record in records:
        if record.get("body") == body.name and "centre" in record:
            return int(record["centre"]), "hamgrav's comment in the SPK"
    raise InputError(
        f"body {body.name!r} has no NAIF ID (none set, and SPICE knows none of its names); "
        "pass --center with the NAIF ID the SPK uses for it"
    )


def _describe(code: int) -> str:
    name = naif_name(code)
    return f"{code} ({name})" if name else str(code)


def _window(spks, target: int) -> list[tuple[float, float]]:
    """The target's coverage intervals [ET s] over all the SPKs."""
    import spiceypy

    cover = spiceypy.cell_double(20000)
    for path in spks:
        spiceypy.spkcov(str(path), target, cover)
    return [spiceypy.wnfetd(cover, i) for i in range(spiceypy.wncard(cover))]


def _body_frame(code: int, et0: float):
    """The body-fixed frame the kernels define for body ``code`` and can evaluate at
    ``et0`` (None otherwise)."""
    import spiceypy

    with spiceypy.no_found_check():
        _, name, found = spiceypy.cidfrm(code)
    if not found:
        return None
    try:
        spiceypy.sxform(FRAME, name, et0)
    except spiceypy.exceptions.SpiceyError:
        return None  # e.g. a built-in IAU frame without its PCK constants
    return name


def _check_frame_spin(name: str, et0: float, body: Body) -> None:
    """Refuse a kernel frame that does not spin about its +z at the body's rate (its axes
    are not hamgrav's body frame), warn when the rate differs slightly."""
    import spiceypy

    s = np.asarray(spiceypy.sxform(FRAME, name, et0))
    r, dr = s[:3, :3], s[3:, :3]
    w = -dr @ r.T  # [omega]x in the rotating axes: dR = -[omega]x R
    omega = np.array([w[2, 1], w[0, 2], w[1, 0]])
    want = body.units.omega_rad_s
    off = float(np.linalg.norm(omega - [0.0, 0.0, want])) / want
    if off > SPIN_REFUSED:
        raise InputError(
            f"frame {name} of the kernels spins at ({', '.join(f'{v:.4g}' for v in omega)}) "
            f"rad/s in its axes, not about +z at body {body.name!r}'s {want:.6g} rad/s "
            f"(spin period {body.spin_period_s:g} s); leave its PCK/FK out of the kernels to "
            "use a rotation model (--pole-ra, --pole-dec, --prime-meridian)"
        )
    if off > SPIN_WARNED:
        warnings.warn(
            f"frame {name} of the kernels spins {off:.2g} (relative) off body {body.name!r}'s "
            f"spin period {body.spin_period_s:g} s; its positions are used, and the momenta "
            "are the inertial velocities in its axes",
            HamgravWarning,
            stacklevel=4,
        )


def _sample(spks, target, segs, window, start, stop, step_s):
    """Ephemeris times of the pieces (lists of arrays), see the module docstring."""
    lo = -math.inf if start is None else start
    hi = math.inf if stop is None else stop
    if step_s is None:
        other = sorted({s.type for s in segs if s.type not in DISCRETE_TYPES})
        if other:
            raise InputError(
                f"segments of target {target} in {', '.join(map(str, spks))} are of type "
                f"{', '.join(map(str, other))}, which holds no sample epochs of its own; pass "
                "--step S [s]"
            )
        pieces = []
        spans = sorted((s.start, s.stop) for s in segs)
        for (_, a_stop), (b_start, _) in zip(spans[:-1], spans[1:], strict=True):
            if b_start < a_stop:
                raise InputError(
                    f"segments of target {target} overlap in time (one ends at ET {a_stop:.3f} "
                    f"s, the next starts at {b_start:.3f} s); pass --step S [s] to sample the "
                    "states SPICE gives"
                )
        for seg in sorted(segs, key=lambda s: s.start):
            epochs, _ = _segment_data(seg)
            keep = epochs[(epochs >= max(lo, seg.start)) & (epochs <= min(hi, seg.stop))]
            if len(keep):
                pieces.append(keep)
        return pieces
    pieces = []
    for a, b in window:
        a, b = max(a, lo), min(b, hi)
        if b < a:
            continue
        epochs = a + step_s * np.arange(int(math.floor((b - a) / step_s + 1e-9)) + 1)
        pieces.append(epochs)
    return pieces


def read_spk(
    kernels,
    body: Body,
    target,
    *,
    start: str | None = None,
    stop: str | None = None,
    step_s: float | None = None,
    rotation: RotationModel | None = None,
    centre: int | None = None,
) -> SpkStates:
    """States of ``target`` relative to ``body`` in the body frame (see the module docstring).

    Args:
        kernels: SPICE kernels: SPKs (.bsp) and, for the body's frame, PCK/FK text kernels.
        body: the central body.
        target: the spacecraft's NAIF ID or name (a SPICE name, or hamgrav's ``orbit-0``).
        start, stop: TDB epochs (ISO) of the span to read (default: the whole coverage).
        step_s: sample every this many seconds [s] (default: the segments' own epochs).
        rotation: the rotation model (default: hamgrav's from the comment area, else the
            body's); not used when the kernels define the body's frame.
        centre: the body's NAIF ID (default: :func:`~hamgrav.io.naif.body_naif_id`).

    Raises:
        InputError / DatasetError: a missing file or one that is not a kernel, a target the
            SPKs do not hold, no states relative to the body, a span the kernels do not
            cover, a frame hamgrav cannot reach.
    """
    paths = _kernel_paths(kernels)
    if step_s is not None and not (math.isfinite(step_s) and step_s > 0):
        raise InputError(f"--step must be a positive number of seconds, got {step_s!r}")
    with _loaded(paths):
        return _read_target(paths, body, target, start, stop, step_s, rotation, centre)


def _read_target(paths, body, target, start, stop, step_s, rotation, centre) -> SpkStates:
    import spiceypy

    spks = _spks(paths)
    records = {p: _comments(p) for p in spks}
    code = _target_id(target, spks, list(records.values()))
    body_code, body_source = _centre_id(body, centre, list(records.values()))
    kernel_list = ", ".join(map(str, paths))
    segs, holders = [], {}
    for path in spks:
        for seg in _segments(path):
            if seg.target == code:
                segs.append(seg)
                holders[path] = records[path]
    if not segs:
        objects = sorted({int(o) for p in spks for o in spiceypy.spkobj(str(p))})
        raise InputError(
            f"the SPKs {', '.join(map(str, spks))} hold no trajectory of target "
            f"{_describe(code)} (they hold {', '.join(map(_describe, objects))}); give the "
            "SPK of that spacecraft, or its NAIF ID as --target"
        )
    centres = sorted({s.centre for s in segs})
    objects = {int(o) for p in spks for o in spiceypy.spkobj(str(p))}
    if body_code not in centres and body_code not in objects:
        raise InputError(
            f"the SPKs give target {_describe(code)} relative to "
            f"{', '.join(map(_describe, centres))}, not to body {body.name!r} ({body_source}: "
            f"{_describe(body_code)}), and hold no ephemeris of the body; add the body's SPK "
            "to the kernels, or pass the matching --body (or --center)"
        )
    window = _window(spks, code)
    lo = _et(tdb(start, "--start", "--start")) if start is not None else None
    hi = _et(tdb(stop, "--stop", "--stop")) if stop is not None else None
    if lo is not None and hi is not None and not lo < hi:
        raise InputError(f"--start {start} is not before --stop {stop}; swap them")
    covered = f"{_iso_et(window[0][0])} to {_iso_et(window[-1][1])} TDB" + (
        f", in {len(window)} intervals" if len(window) > 1 else ""
    )
    for value, text, name in ((lo, start, "--start"), (hi, stop, "--stop")):
        if value is not None and not window[0][0] <= value <= window[-1][1]:
            raise InputError(
                f"{name} {text} TDB is outside the coverage of target {_describe(code)} in "
                f"{', '.join(map(str, spks))} ({covered}); give a span the kernels cover"
            )
    # gaps of the coverage inside the span are gaps of the tracking, cut as OEM gaps are
    pieces_et = _sample(spks, code, segs, window, lo, hi, step_s)
    if not pieces_et:
        raise InputError(
            f"no sample of target {_describe(code)} between --start and --stop (coverage "
            f"{covered}); widen the span"
        )
    record = next(iter(holders.values()), {})
    et0 = float(pieces_et[0][0])
    frame = _body_frame(body_code, et0)
    if frame is not None:
        _check_frame_spin(frame, et0, body)
        rotation_used, rotation_source = None, None
    else:
        rotation_source = "--rotation-epoch"
        if rotation is None and record.get("rotation"):
            r = record["rotation"]
            rotation = RotationModel(
                r["pole_ra_deg"],
                r["pole_dec_deg"],
                r["prime_meridian_deg"],
                body.spin_period_s,
                r["epoch_tdb"],
            )
            rotation_source = "the rotation epoch in hamgrav's comment in the SPK"
        elif rotation is None and body.rotation is not None:
            rotation = body.rotation
            rotation_source = f"the rotation epoch of body {body.name!r} in the catalogue"
        if rotation is None:
            raise InputError(
                f"the kernels {kernel_list} define no body-fixed frame of {_describe(body_code)}"
                f" (no PCK or FK for it) and body {body.name!r} has no rotation model; give "
                "--pole-ra, --pole-dec and --prime-meridian, or add the body's PCK"
            )
        rotation_used = rotation
    rotation_t0 = rotation_zero(rotation_used, rotation_source)
    pieces = []
    for ets in pieces_et:
        try:
            states, _ = spiceypy.spkezr(str(code), list(ets), FRAME, "NONE", str(body_code))
        except spiceypy.exceptions.SpiceyError as exc:
            raise InputError(
                f"the kernels {kernel_list} do not give target {_describe(code)} relative to "
                f"body {body.name!r} ({_describe(body_code)}) from {_iso_et(ets[0])} to "
                f"{_iso_et(ets[-1])} TDB ({_spice_line(exc)}); add the SPKs linking them"
            ) from None
        states = np.asarray(states, dtype=float).reshape(len(ets), 6) * 1e3
        if frame is not None:
            try:
                m = np.asarray([spiceypy.pxform(FRAME, frame, t) for t in ets])
            except spiceypy.exceptions.SpiceyError as exc:
                raise InputError(
                    f"the kernels {kernel_list} do not orient frame {frame} from "
                    f"{_iso_et(ets[0])} to {_iso_et(ets[-1])} TDB ({_spice_line(exc)}); add "
                    "the PCK covering the span"
                ) from None
            r = np.einsum("nij,nj->ni", m, states[:, :3])
            p = np.einsum("nij,nj->ni", m, states[:, 3:])
            w = body.units.omega_rad_s
            v = p + w * np.stack([r[:, 1], -r[:, 0], np.zeros(len(r))], axis=1)
        else:
            since = (_time(ets) - rotation_t0).to_value("s")
            r, _, v = rotation_used.to_body(since, states[:, :3], states[:, 3:])
        pieces.append((_time(ets), r, v))
    return SpkStates(
        target=code,
        files=tuple(holders),
        pieces=tuple(pieces),
        frame=f"{frame} (kernels)" if frame is not None else f"{FRAME} + rotation model",
        rotation=rotation_used,
        record=record,
    )


def _iso_et(et: float) -> str:
    t = _time(float(et))
    t.precision = 3
    return str(t.isot)


#: The ``--target`` that takes every target of the SPKs whose segments are relative to the body.
ALL_TARGETS = "all"


def targets_about(kernels, body: Body, centre: int | None = None) -> list[int]:
    """NAIF IDs of every target whose SPK segments among ``kernels`` are given relative to
    ``body`` (its NAIF ID, or ``centre``, or hamgrav's comment), sorted by decreasing ID
    (hamgrav's own SPKs: -1000, -1001, ...); :class:`InputError` naming the kernels when
    there is none."""
    paths = _kernel_paths(kernels)
    spks = _spks(paths)
    records = [_comments(p) for p in spks]
    body_code, body_source = _centre_id(body, centre, records)
    found = sorted(
        {seg.target for p in spks for seg in _segments(p) if seg.centre == body_code},
        reverse=True,
    )
    if not found:
        raise InputError(
            f"the SPKs {', '.join(map(str, spks))} hold no trajectory relative to body "
            f"{body.name!r} ({body_source}: {_describe(body_code)}); give --target and the "
            "kernels that relate it to the body, or the matching --body (or --center)"
        )
    return found


def import_spk(
    kernels,
    body: Body,
    targets,
    *,
    start: str | None = None,
    stop: str | None = None,
    step_s: float | None = None,
    samples: int | None = None,
    max_gap_s: float | None = None,
    rotation: RotationModel | None = None,
    epoch: str | None = None,
    sigma_r_m: float | None = None,
    sigma_v_m_s: float | None = None,
    origin_m=None,
    centre: int | None = None,
) -> Arcs:
    """Read the trajectories of SPK targets into :class:`Arcs` (canonical units; see the
    module docstring and :func:`read_spk`).

    Args:
        kernels: SPICE kernels: SPKs (.bsp) and, for the body's frame, PCK/FK text kernels.
        body: the central body (GM, spin period and NAIF ID fix the units, frame and centre).
        targets: the spacecraft, one trajectory each: NAIF IDs or names (one or a list).
        start, stop: TDB epochs (ISO) of the span to read (default: the whole coverage).
        step_s: sample every this many seconds [s] (default: the segments' own epochs).
        samples: samples per arc; None: every gap-free run is one arc (runs of equal length).
        max_gap_s: split where samples are more than this apart [s] (default 1.5 times the
            median step of each segment or coverage interval).
        rotation: the rotation model when the kernels do not define the body's frame
            (default: hamgrav's from the comment area, else ``body.rotation``).
        epoch: TDB epoch (ISO) of canonical time 0 (default: hamgrav's comment, else the
            earliest sample).
        sigma_r_m: position noise per component [m]; sigma_v_m_s: rotating-frame velocity
            noise per component [m/s] (default: hamgrav's comment; SPKs hold no covariance).
        origin_m: the frame origin (3,) in the body mesh's frame [m] (default: hamgrav's
            comment, else the mesh origin).
        centre: the body's NAIF ID in the SPKs (default: the body's, else hamgrav's comment).

    Raises:
        InputError / DatasetError: as :func:`read_spk`, and no noise level, a target given
            twice, arcs of unequal length without ``samples``, or no arc at all.
    """
    check_arc_options(samples, max_gap_s, sigma_r_m, sigma_v_m_s)
    if step_s is not None and not (math.isfinite(step_s) and step_s > 0):
        raise InputError(f"--step must be a positive number of seconds, got {step_s!r}")
    targets = [targets] if isinstance(targets, str | int) else list(targets)
    if not targets:
        raise InputError("give at least one --target (the spacecraft's NAIF ID or name)")
    paths = _kernel_paths(kernels)
    if any(str(t).strip().lower() == ALL_TARGETS for t in targets):
        if len(targets) > 1:
            raise InputError(f"--target {ALL_TARGETS} takes every target; give it alone")
        targets = targets_about(paths, body, centre)
    with _loaded(paths):
        read = [
            _read_target(paths, body, t, start, stop, step_s, rotation, centre) for t in targets
        ]
    codes = [r.target for r in read]
    for k, code in enumerate(codes):
        if code in codes[:k]:
            raise InputError(f"target {code} is given twice as --target; give it once")
    record = next((r.record for r in read if r.record), {})
    for key, have in (("gm_m3_s2", body.gm_m3_s2), ("spin_period_s", body.spin_period_s)):
        if key in record and not math.isclose(record[key], have, rel_tol=1e-12):
            raise InputError(
                f"{read[0].files[0]} was written by hamgrav for {key} = {record[key]!r}, but "
                f"body {body.name!r} has {have!r}; import it with the body it was simulated for"
            )
    tracks = [
        Track(f"{', '.join(map(str, r.files))} (target {r.target})", k, "body-fixed", *piece)
        for k, r in enumerate(read)
        for piece in r.pieces
    ]
    epoch_source = "--epoch" if epoch else "the epoch in hamgrav's comment in the SPK"
    t0 = epoch_zero(epoch or record.get("epoch_tdb"), epoch_source, tracks)

    noise_source = "options"
    if sigma_r_m is None or sigma_v_m_s is None:
        if "sigma_r_m" not in record:
            raise InputError(
                "SPK kernels give no noise level (hamgrav's own SPKs of noisy states do); pass "
                "--sigma-r [m] and --sigma-v [m/s]"
            )
        given = (
            "--sigma-r"
            if sigma_r_m is not None
            else "--sigma-v"
            if sigma_v_m_s is not None
            else None
        )
        sigma_r_m = sigma_r_m if sigma_r_m is not None else record["sigma_r_m"]
        sigma_v_m_s = sigma_v_m_s if sigma_v_m_s is not None else record["sigma_v_m_s"]
        noise_source = "hamgrav comment" if given is None else f"{given} and hamgrav comment"
    check_noise(sigma_r_m, sigma_v_m_s, noise_source)
    origin = origin_m if origin_m is not None else tuple(record.get("origin_m", (0.0, 0.0, 0.0)))
    names = record.get("targets", {})
    kinds = []
    for r in read:
        match = re.fullmatch(r"([a-z]+)-\d+", str(names.get(str(r.target), "")))
        kinds.append(match.group(1) if match else "tracked")
    rotations = [r.rotation.describe() for r in read if r.rotation is not None]
    return tracks_to_arcs(
        tracks,
        body,
        t0=t0,
        samples=samples,
        max_gap_s=max_gap_s,
        rotation=None,
        rotation_t0=None,
        sigma_r_m=sigma_r_m,
        sigma_v_m_s=sigma_v_m_s,
        origin_m=origin,
        trajectory_kind=kinds,
        centre_hint="the SPK's centre (--center)",
        config={
            "source": "spice-spk",
            "files": [str(p) for p in paths],
            "targets": codes,
            "frames": sorted({r.frame for r in read}),
            "rotation": rotations[0] if rotations else None,
            "noise_from": noise_source,
        },
    )
