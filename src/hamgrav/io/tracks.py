"""From imported tracking (epochs and states per trajectory) to :class:`Arcs`.

The importers (:mod:`hamgrav.io.oem_import` for CCSDS OEM, :mod:`hamgrav.io.spk` for SPICE
SPK kernels) read their files into :class:`Track` pieces: TDB epochs, positions [m] and
velocities [m/s], either body-fixed (rotating-frame velocities) or inertial (ICRF axes,
turned into the body frame here with a :class:`~hamgrav.bodies.rotation.RotationModel`).
Everything after that is shared and done here once:

- Time. Canonical time is (t - epoch) / (spin_period_s / 2 pi), with ``epoch`` the TDB epoch
  of canonical time 0 (default: the earliest sample).
- Arcs. Each piece is split at gaps (a step longer than ``max_gap_s``, default 1.5 times the
  piece's median step), and each run of samples is cut into arcs of ``samples`` consecutive
  samples (the remainder of a run is dropped and counted). Without ``samples`` each run is
  one arc, and all runs must then have the same length.
- Checks. States beyond :data:`~hamgrav.io.arcs.MAX_STATE` synchronous radii, epochs that do
  not increase, samples inside the shape (deeper than :data:`INSIDE_TOLERANCE_RB`) are
  refused; every sample farther than :data:`FAR_RB` Brillouin radii is warned about. The
  velocities of each file must be the rate of change of its positions
  (:func:`check_velocities`): a file with positions in km and velocities in m/s is refused.

Imported arcs have no truth: ``true_states`` are NaN, the truth mascon set is empty and
``interior`` is ``"none"`` (:attr:`Arcs.has_truth` is False).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from astropy.time import Time

from ..bodies.catalogue import Body
from ..bodies.rotation import RotationModel
from ..core.arcs import NO_TRUTH, Arcs
from ..core.geometry import points_inside
from ..core.mascons import MasconSet
from ..errors import DatasetError, HamgravWarning, InputError
from .arcs import MAX_STATE

__all__ = [
    "FAR_RB",
    "INSIDE_TOLERANCE_RB",
    "Track",
    "check_arc_options",
    "check_noise",
    "check_velocities",
    "epoch_zero",
    "rotation_zero",
    "tracks_to_arcs",
]


@dataclass(frozen=True)
class Track:
    """One gap-free-or-not piece of imported tracking of one trajectory.

    Attributes:
        source: the file the piece came from (named in errors).
        trajectory: index of the trajectory it belongs to.
        kind: ``"body-fixed"`` (rotating-frame velocities) or ``"inertial"`` (ICRF axes).
        epochs: TDB epochs (n,), increasing.
        position_m: positions (n, 3) [m] relative to the body's frame origin.
        velocity_m_s: velocities (n, 3) [m/s] (rotating-frame when body-fixed).
    """

    source: Path
    trajectory: int
    kind: str
    epochs: Time
    position_m: np.ndarray
    velocity_m_s: np.ndarray


def check_arc_options(samples, max_gap_s, sigma_r_m, sigma_v_m_s) -> None:
    """Refuse ``--samples`` below 2, a ``--max-gap`` that is not positive and noise levels
    that are not positive finite numbers, before any file is read."""
    if samples is not None and int(samples) < 2:
        raise InputError(f"--samples must be at least 2, got {samples}")
    if max_gap_s is not None and not max_gap_s > 0:
        raise InputError(f"--max-gap must be a positive number of seconds, got {max_gap_s}")
    for name, value in (("--sigma-r", sigma_r_m), ("--sigma-v", sigma_v_m_s)):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise InputError(f"{name} must be a positive number, got {value!r}")


def iso(t: Time) -> str:
    """A Time as a TDB ISO string to the microsecond."""
    t = t.tdb.copy()
    t.precision = 6
    return str(t.isot)


def tdb(text: str, source: str, option: str) -> Time:
    """The TDB Time of an ISO string; :class:`InputError` naming ``source`` (where the string
    came from) and ``option`` (what to pass instead) when it is not a date."""
    try:
        return Time(text, scale="tdb")
    except ValueError:  # astropy's message lists every format it tried
        raise InputError(
            f"{source} ({text!r}) is not an ISO date; give {option} as TDB YYYY-MM-DDTHH:MM:SS"
        ) from None


def epoch_zero(epoch: str | None, source: str, tracks) -> Time:
    """The TDB epoch of canonical time 0: ``epoch`` (ISO, from ``source``), else the earliest
    sample of ``tracks``."""
    if epoch is None:
        return min((tr.epochs[0] for tr in tracks), key=lambda t: t.jd1 + t.jd2)
    return tdb(epoch, source, "--epoch")


def rotation_zero(rotation: RotationModel | None, source: str) -> Time | None:
    """The TDB epoch of ``rotation``'s prime meridian angle (None without a rotation)."""
    if rotation is None:
        return None
    return tdb(rotation.epoch, source, "--rotation-epoch")


def check_noise(sigma_r_m, sigma_v_m_s, source: str) -> None:
    """Refuse noise levels (from ``source``) that are negative or not finite: zero is
    noise-free (hamgrav's export of a noise-free campaign)."""
    levels = (("sigma_r", sigma_r_m, "m"), ("sigma_v", sigma_v_m_s, "m/s"))
    bad = [(k, v, u) for k, v, u in levels if not (math.isfinite(float(v)) and float(v) >= 0)]
    if bad:
        raise InputError(
            f"noise from {source}: "
            + ", ".join(f"{k} is {v!r} {u}" for k, v, u in bad)
            + "; a noise level is a standard deviation >= 0: pass "
            + " and ".join(f"--{k.replace('_', '-')} [{u}]" for k, _, u in bad)
        )


def _runs(seconds: np.ndarray, max_gap_s: float | None) -> list[slice]:
    """Runs of samples without a gap (see the module docstring)."""
    if len(seconds) < 2:
        return [slice(0, len(seconds))]
    steps = np.diff(seconds)
    limit = max_gap_s if max_gap_s is not None else 1.5 * float(np.median(steps))
    cuts = np.flatnonzero(steps > limit) + 1
    edges = [0, *cuts.tolist(), len(seconds)]
    return [slice(a, b) for a, b in zip(edges[:-1], edges[1:], strict=True)]


def tracks_to_arcs(
    tracks,
    body: Body,
    *,
    t0: Time,
    samples: int | None,
    max_gap_s: float | None,
    rotation: RotationModel | None,
    rotation_t0: Time | None,
    sigma_r_m: float,
    sigma_v_m_s: float,
    origin_m,
    trajectory_kind,
    centre_hint: str,
    config: dict,
) -> Arcs:
    """Canonical arcs of the pieces ``tracks`` (see the module docstring).

    Args:
        tracks: :class:`Track` pieces, in the order of their files.
        body: the central body (GM and spin period fix the units).
        t0: TDB epoch of canonical time 0.
        samples: samples per arc; None: every gap-free run is one arc (runs of equal length).
        max_gap_s: split where consecutive samples are more than this apart [s].
        rotation: the rotation model of inertial pieces; rotation_t0: the TDB epoch of its
            prime meridian angle.
        sigma_r_m: position noise per component [m]; sigma_v_m_s: rotating-frame velocity
            noise per component [m/s].
        origin_m: the frame origin (3,) in the body mesh's frame [m].
        trajectory_kind: the kind of each trajectory ("tracked", "orbit", ...).
        centre_hint: what names the centre in the files, for the errors (``CENTER_NAME``).
        config: the importer's description (``source``, ``files``, ``noise_from``...;
            ``frames`` and ``rotation`` when it turned the states into the body frame itself);
            ``epoch_tdb``, ``samples_per_arc``, ``max_gap_s`` and ``dropped_samples`` are
            added.
    """
    units = body.units
    name = body.name
    arcs_t, arcs_x, arc_traj, arc_source, dropped = [], [], [], [], 0
    for track in tracks:
        seconds = (track.epochs - t0).to_value("s")
        if track.kind == "inertial":
            since = (track.epochs - rotation_t0).to_value("s")
            r_body, p_body, _ = rotation.to_body(since, track.position_m, track.velocity_m_s)
            q = units.to_length(r_body)
            state = np.concatenate([q, units.to_velocity(p_body)], axis=1)
        else:
            state = units.state_to_canonical(track.position_m, track.velocity_m_s)
        with np.errstate(invalid="ignore"):
            largest = float(np.max(np.abs(state)))
        if not largest <= MAX_STATE:  # also NaN from an overflow in the conversion
            # velocities in other units than the positions are the likelier cause: name it
            check_velocities([track], t0, max_gap_s)
            raise DatasetError(
                f"{track.source}: a state of {largest:.3g} synchronous radii (canonical) is not "
                f"tracking of body {name!r} (at most {MAX_STATE:g}); check the file's units "
                f"(km, km/s) and {centre_hint}"
            )
        if np.any(np.diff(seconds) <= 0):
            raise DatasetError(
                f"{track.source}: the epochs of a segment do not increase; fix its order"
            )
        for run in _runs(seconds, max_gap_s):
            n = run.stop - run.start
            if n < 2:  # a lone sample between gaps is no arc
                dropped += n
                continue
            m = n if samples is None else int(samples)
            for start in range(run.start, run.stop - m + 1, m):
                arcs_t.append(units.to_time(seconds[start : start + m]))
                arcs_x.append(state[start : start + m])
                arc_traj.append(track.trajectory)
                arc_source.append(track.source)
            dropped += n % m
    if not arcs_t:
        size = "2 or more" if samples is None else str(samples)
        raise InputError(
            f"no arc of {size} samples without a gap in the files (--max-gap "
            f"{'1.5 median steps' if max_gap_s is None else f'{max_gap_s:g} s'}); "
            + ("raise --max-gap" if samples is None else "lower --samples or raise --max-gap")
        )
    lengths = sorted({len(t) for t in arcs_t})
    if len(lengths) > 1:
        raise InputError(
            f"the gap-free runs hold {lengths[0]} to {lengths[-1]} samples; pass --samples M "
            "to cut them into arcs of M samples"
        )
    times = np.asarray(arcs_t)
    states = np.asarray(arcs_x)
    frames = sorted({tr.kind for tr in tracks})
    origin = origin_m
    if np.shape(origin) != (3,) or not np.all(np.isfinite(np.asarray(origin, dtype=float))):
        raise InputError(f"--origin must be three finite numbers [m], got {origin!r}")
    check_positions(
        states[..., :3],
        arc_source,
        body,
        np.asarray(origin, dtype=float),
        float(units.to_length(float(sigma_r_m))),
        centre_hint,
    )
    # after the positions' own checks, which name a unit error of the positions more directly
    check_velocities(tracks, t0, max_gap_s)
    rotated = rotation is not None and "inertial" in frames
    known = ("source", "files", "frames", "rotation")
    config = {
        "source": config.get("source"),
        "files": config.get("files"),
        # the importer's own frames and rotation when it turned the states itself
        "frames": config.get("frames", frames),
        "epoch_tdb": iso(t0),
        "rotation": config.get("rotation", rotation.describe() if rotated else None),
        "samples_per_arc": int(times.shape[1]),
        "max_gap_s": max_gap_s,
        "dropped_samples": int(dropped),
        **{k: v for k, v in config.items() if k not in known},
    }
    return Arcs(
        times=times,
        states=states,
        true_states=np.full_like(states, np.nan),
        trajectory=np.asarray(arc_traj, dtype=int),
        trajectory_kind=tuple(trajectory_kind),
        trajectory_info={},
        body_name=name,
        gm_m3_s2=body.gm_m3_s2,
        spin_period_s=body.spin_period_s,
        body_origin_m=tuple(float(v) for v in origin),
        sigma_r_m=float(sigma_r_m),
        sigma_v_m_s=float(sigma_v_m_s),
        truth=MasconSet(np.zeros((0, 3)), np.zeros(0)),
        interior=NO_TRUTH,
        interior_parameters={},
        seed=0,
        config=config,
        body=replace(body, origin_m=tuple(float(v) for v in origin)).record(),
    )


#: Velocities this many times the positions' rate of change, or less than its inverse, are
#: refused: unit mix-ups are factors of 1000 (km and m) or more (per hour, per day), while
#: on a circular path turning by theta a step, the chord is tan(theta/2) / (theta/2) times
#: the trapezoidal velocity step: 1.10 at 60 degrees a step, 10 only at 172 degrees.
VELOCITY_SCALE_LIMIT = 10.0


def check_velocities(tracks, t0: Time, max_gap_s: float | None) -> None:
    """Refuse a file whose velocities are not the rate of change of its positions (the
    redundant information of a state: a km / m mix-up between them shows here, and nowhere
    else before the fit's residuals).

    Over every step of every gap-free run of a file, the displacement d_j = r_{j+1} - r_j is
    compared with the trapezoidal u_j = (v_j + v_{j+1}) dt_j / 2 by the least-squares scale
    s = sum d.u / sum u.u (d = s u + noise). Position noise enters d with zero mean, so s is
    not biased by it (a ratio of magnitudes would be: noise lengthens every |d|); its
    standard error follows from the residuals d - s u. A file is refused when s lies beyond
    [1 / :data:`VELOCITY_SCALE_LIMIT`, :data:`VELOCITY_SCALE_LIMIT`] by more than 3 standard
    errors: files whose noise drowns the motion pass unjudged. Body-fixed positions and
    rotating-frame velocities, and inertial ones, are each consistent, so the check runs on
    the files' own frames."""
    sums: dict = {}
    for track in tracks:
        seconds = (track.epochs - t0).to_value("s")
        if len(seconds) < 2 or np.any(np.diff(seconds) <= 0):
            continue  # refused with its own message below
        r, v = track.position_m, track.velocity_m_s
        for run in _runs(seconds, max_gap_s):
            if run.stop - run.start < 2:
                continue
            dt = np.diff(seconds[run])[:, None]
            d = np.diff(r[run], axis=0)
            u = 0.5 * (v[run][1:] + v[run][:-1]) * dt
            du, uu, dd, n = sums.get(track.source, (0.0, 0.0, 0.0, 0))
            sums[track.source] = (
                du + float(np.sum(d * u)),
                uu + float(np.sum(u * u)),
                dd + float(np.sum(d * d)),
                n + d.size,
            )
    for source, (du, uu, dd, n) in sums.items():
        if not (uu > 0 and n > 1):
            continue
        scale = du / uu
        residual = max(dd - 2 * scale * du + scale * scale * uu, 0.0)
        error = math.sqrt(residual / (n - 1) / uu)
        low, high = 1.0 / VELOCITY_SCALE_LIMIT, VELOCITY_SCALE_LIMIT
        if scale - 3 * error > high or scale + 3 * error < low:
            ratio = 1.0 / scale if scale != 0 else math.inf
            raise DatasetError(
                f"{source}: its velocities are {ratio:.2g} times the rate of change of its "
                "positions (finite differences of the samples); positions and velocities are "
                "in different units (an OEM holds km and km/s): convert one of them"
            )


#: Closest sample beyond this many Brillouin radii: likely a unit error (metres read as km).
FAR_RB = 100.0
#: Samples deeper inside the shape than this fraction of R_B, or than 5 sigma_r of the
#: tracking noise if more, are refused: the surface itself (a touchdown, an ejection point)
#: is tracking, and its facets only approximate the body.
INSIDE_TOLERANCE_RB = 0.01


def check_positions(q, arc_files, body, origin_m, sigma_r, centre_hint="CENTER_NAME") -> None:
    """Refuse samples inside the body's shape and warn when every sample is far from it:
    both mean the file's units, centre (``centre_hint``) or frame origin are not what it
    says. ``q``: positions (n_arcs, m, 3), canonical, about the frame origin ``origin_m``
    [m, mesh frame]; ``arc_files``: the file of each arc; ``sigma_r``: position noise,
    canonical."""
    import trimesh

    units = body.units
    framed = replace(body, origin_m=tuple(float(v) for v in origin_m))  # the files' frame
    reach = framed.brillouin_radius
    points = np.asarray(q, dtype=float)
    radius = np.linalg.norm(points, axis=-1)
    near = np.argwhere(radius < reach)  # (arc, sample) of the points that can be inside
    if len(near):
        mesh = framed.mesh
        candidates = points[near[:, 0], near[:, 1]]
        inside = points_inside(np.asarray(mesh.triangles), candidates)
        if np.any(inside):
            depth = trimesh.proximity.signed_distance(mesh, candidates[inside])
            tolerance = max(INSIDE_TOLERANCE_RB * reach, 5.0 * sigma_r)
            inside[np.flatnonzero(inside)] = depth > tolerance
        if np.any(inside):
            first = near[np.flatnonzero(inside)[0]]
            files = sorted({str(arc_files[a]) for a in near[inside][:, 0]})
            count = int(inside.sum())
            depth_m = float(np.linalg.norm(points[first[0], first[1]])) * units.length_m
            raise DatasetError(
                f"{', '.join(files)}: {count} sample{'s' if count > 1 else ''} inside the shape "
                f"of {body.name!r} (one {depth_m:.4g} m from the frame origin); check the "
                f"file's units (km, km/s), {centre_hint} and --origin"
            )
    if radius.min() > FAR_RB * reach:
        warnings.warn(
            f"the closest sample is {radius.min() / reach:.3g} Brillouin radii from "
            f"{body.name!r}: check the files' units (km, km/s)",
            HamgravWarning,
            stacklevel=4,
        )
