"""A body from the user's own files: a shape model and constants, or a body TOML naming both.

Example body TOML (paths relative to the TOML's folder)::

    name = "didymos"
    shape = "shape.icq"        # the shape model file
    units = "km"               # of the shape file: "m" or "km" (required)
    format = "icq"             # optional: obj | ply | stl | icq | pds (default: from the suffix)
    gm_m3_s2 = 35.0            # [m^3/s^2]
    spin_period_s = 8136.0     # sidereal [s]
    naif_id = 2065803          # optional
    description = "..."        # optional
    [rotation]                 # optional, IAU convention (see hamgrav.bodies.rotation)
    pole_ra_deg = 310.0
    pole_dec_deg = -84.0
    prime_meridian_deg = 0.0   # optional, W0 at epoch_tdb
    epoch_tdb = "2000-01-01T12:00:00"  # optional

Such a path is accepted wherever a catalogue name is (see
:func:`hamgrav.bodies.catalogue.load_body`). The mesh keeps the file's origin: the body frame's
origin is set later, by the truth's centre of mass, as for catalogue bodies (see
:meth:`Body.recentred`).
"""

from __future__ import annotations

import datetime
import math
import os
from dataclasses import replace
from pathlib import Path

from ..errors import BodyDataError, HamgravError, InputError
from ..files import read_toml
from .catalogue import G_SI, Body
from .rotation import J2000_TDB, RotationModel
from .shapes import FORMATS, UNITS_M, read_shape, shape_format

__all__ = ["DENSITY_BOUNDS_KG_M3", "body_from_files", "read_body_toml"]

#: Bulk densities GM / (G V) [kg/m^3] a body may have. Measured small bodies lie between a few
#: hundred (comet nuclei: 67P 533) and a few thousand (metal-rich asteroids; iron is 7870):
#: these bounds leave a wide margin on both sides and still catch the factor 1e9 of a shape in
#: km read as metres (or metres read as km) and of a GM given in km^3/s^2.
DENSITY_BOUNDS_KG_M3 = (100.0, 20_000.0)

_TOML_KEYS = {
    "name",
    "shape",
    "units",
    "format",
    "gm_m3_s2",
    "spin_period_s",
    "naif_id",
    "description",
    "rotation",
}
_ROTATION_KEYS = {"pole_ra_deg", "pole_dec_deg", "prime_meridian_deg", "epoch_tdb"}


def body_from_files(
    mesh: str | os.PathLike,
    *,
    gm_m3_s2: float,
    spin_period_s: float,
    pole: tuple[float, float] | None = None,
    prime_meridian_deg: float = 0.0,
    rotation_epoch: str = J2000_TDB,
    name: str | None = None,
    units: str = "m",
    fmt: str | None = None,
    naif_id: int | None = None,
    description: str = "",
) -> Body:
    """A body of the shape model file ``mesh`` and the given constants.

    Args:
        mesh: shape model file, read by :func:`hamgrav.bodies.shapes.read_shape`.
        gm_m3_s2: gravitational parameter [m^3/s^2].
        spin_period_s: sidereal spin period [s] about the shape's +z axis.
        pole: (right ascension, declination) [deg, ICRF] of the north pole: the body gets a
            :class:`RotationModel` with ``prime_meridian_deg`` [deg], W0 at
            ``rotation_epoch`` (TDB, ISO). None: no rotation model.
        name: the body's name (default: the shape file's name without its suffix).
        units: the shape file's length unit, ``"m"`` or ``"km"``.
        fmt: the shape file's format (one of :data:`hamgrav.bodies.shapes.FORMATS`;
            default: from its suffix).
        naif_id: the body's NAIF ID, when known.
        description: free text.

    The bulk density GM / (G V) must lie in :data:`DENSITY_BOUNDS_KG_M3`: a shape in the wrong
    units is refused with the density and the fix. Errors: :class:`InputError` (a bad
    argument), :class:`BodyDataError` (a bad shape file, an implausible density).
    """
    path = Path(mesh).expanduser()
    for key, value in (("gm_m3_s2", gm_m3_s2), ("spin_period_s", spin_period_s)):
        if not (_is_number(value) and value > 0):
            raise InputError(f"body from {path}: {key} must be a finite number > 0, got {value!r}")
    if units not in UNITS_M:
        raise InputError(f"body from {path}: units must be 'm' or 'km', got {units!r}")
    if name is None:
        name = path.stem.lower()
    if not isinstance(name, str) or not name.strip():
        raise InputError(f"body from {path}: name must be a non-empty string, got {name!r}")
    if naif_id is not None and (isinstance(naif_id, bool) or not isinstance(naif_id, int)):
        raise InputError(f"body from {path}: naif_id must be an integer, got {naif_id!r}")
    if not isinstance(description, str):
        raise InputError(f"body from {path}: description must be a string, got {description!r}")
    rotation = None
    if pole is not None:
        if not (isinstance(pole, list | tuple) and len(pole) == 2):
            raise InputError(
                f"body from {path}: pole must be (right ascension, declination) [deg], got {pole!r}"
            )
        try:
            rotation = RotationModel(
                float(pole[0]),
                float(pole[1]),
                float(prime_meridian_deg),
                float(spin_period_s),
                str(rotation_epoch),
            )
        except (TypeError, ValueError) as exc:
            raise InputError(f"body from {path}: rotation: {exc}") from None
    elif prime_meridian_deg != 0.0 or rotation_epoch != J2000_TDB:
        raise InputError(
            f"body from {path}: a prime meridian or rotation epoch needs the pole: give pole="
            "(right ascension, declination) [deg] too"
        )
    fmt = shape_format(path, fmt)
    shape = read_shape(path, fmt=fmt, units=units)
    _check_density(path, float(gm_m3_s2), float(shape.volume), units)
    return Body(
        name=name.strip(),
        gm_m3_s2=float(gm_m3_s2),
        spin_period_s=float(spin_period_s),
        mesh_m=shape,
        description=description,
        rotation=rotation,
        naif_id=naif_id,
        source={"kind": "files", "mesh": str(path.resolve()), "format": fmt, "units": units},
    )


def _check_density(path: Path, gm: float, volume_m3: float, units: str) -> None:
    """Refuse a bulk density outside :data:`DENSITY_BOUNDS_KG_M3`, saying which mix-up of
    units would explain it."""
    low, high = DENSITY_BOUNDS_KG_M3
    density = gm / (G_SI * volume_m3)
    if low <= density <= high:
        return
    if density > high and low <= density / 1e9 <= high and units == "m":
        fix = 'the shape file is likely in km read as metres: set units = "km"'
    elif density < low and low <= density * 1e9 <= high and units == "km":
        fix = (
            'the shape file is likely in metres read as km (set units = "m"), or GM in '
            "km^3/s^2 (give gm_m3_s2 in m^3/s^2, 1e9 times larger)"
        )
    elif density < low and low <= density * 1e9 <= high:
        fix = "GM is likely in km^3/s^2: give gm_m3_s2 in m^3/s^2 (1e9 times larger)"
    else:
        fix = f"check gm_m3_s2 [m^3/s^2] and the shape file's units (now {units!r})"
    raise BodyDataError(
        f"body from {path}: bulk density GM / (G V) = {density:.3g} kg/m^3 (GM {gm:.6g} m^3/s^2, "
        f"volume {volume_m3:.4g} m^3) is outside the plausible {low:g}-{high:g} kg/m^3; {fix}"
    )


def read_body_toml(path: str | os.PathLike) -> Body:
    """The body a body TOML file describes (see the module docstring): its shape file
    (relative to the TOML's folder) and constants. Errors name the TOML, the key and the fix
    (:class:`InputError` for the TOML's content, :class:`BodyDataError` for the files)."""
    path = Path(path).expanduser()
    if not path.is_file() and not path.is_dir():
        raise BodyDataError(
            f"body file not found: {path}; give the path of a body TOML (or a catalogue name: "
            "'hamgrav bodies' lists them)"
        )
    data = read_toml(path)

    def fail(msg: str):
        raise InputError(f"body file {path}: {msg}")

    unknown = set(data) - _TOML_KEYS
    if unknown:
        fail(f"unknown key(s) {sorted(unknown)}; allowed: {sorted(_TOML_KEYS)}")
    for key in ("shape", "units", "gm_m3_s2", "spin_period_s"):
        if key not in data:
            hint = {
                "shape": 'the shape model file, e.g. shape = "shape.obj"',
                "units": 'the shape file\'s length unit: units = "m" or "km" (there is no default)',
                "gm_m3_s2": "the gravitational parameter [m^3/s^2], e.g. gm_m3_s2 = 35.0",
                "spin_period_s": "the sidereal spin period [s], e.g. spin_period_s = 8136.0",
            }[key]
            fail(f"'{key}' is required: {hint}")
    for key in ("shape", "name", "description", "units", "format"):
        if key in data and not isinstance(data[key], str):
            fail(f"'{key}' must be a string, got {data[key]!r}")
    for key in ("gm_m3_s2", "spin_period_s"):
        if not (_is_number(data[key]) and data[key] > 0):
            fail(f"'{key}' must be a number > 0, got {data[key]!r}")
    if data["units"] not in UNITS_M:
        fail(f'\'units\' must be "m" or "km" (the shape file\'s unit), got {data["units"]!r}')
    fmt = data.get("format")
    if fmt is not None and fmt not in FORMATS:
        fail(f"'format' must be one of {', '.join(FORMATS)} (or left out), got {fmt!r}")
    naif_id = data.get("naif_id")
    if naif_id is not None and (isinstance(naif_id, bool) or not isinstance(naif_id, int)):
        fail(f"'naif_id' must be an integer, got {naif_id!r}")
    pole, prime_meridian, epoch = None, 0.0, J2000_TDB
    if "rotation" in data:
        rotation = data["rotation"]
        if not isinstance(rotation, dict):
            fail("'rotation' must be a table: [rotation] with pole_ra_deg and pole_dec_deg")
        unknown = set(rotation) - _ROTATION_KEYS
        if unknown:
            fail(
                f"unknown key(s) in [rotation] {sorted(unknown)}; allowed: {sorted(_ROTATION_KEYS)}"
            )
        for key in ("pole_ra_deg", "pole_dec_deg", "prime_meridian_deg"):
            if key in rotation and not _is_number(rotation[key]):
                fail(f"[rotation] {key} must be a number [deg], got {rotation[key]!r}")
        missing = [k for k in ("pole_ra_deg", "pole_dec_deg") if k not in rotation]
        if missing:
            fail(f"[rotation] needs {' and '.join(missing)} [deg, ICRF]")
        pole = (rotation["pole_ra_deg"], rotation["pole_dec_deg"])
        prime_meridian = rotation.get("prime_meridian_deg", 0.0)
        epoch = rotation.get("epoch_tdb", J2000_TDB)
        if isinstance(epoch, datetime.datetime) and epoch.tzinfo is None:
            epoch = epoch.isoformat()  # an unquoted TOML date-time
        if not isinstance(epoch, str):
            fail(f'[rotation] epoch_tdb must be an ISO date-time string, e.g. "{J2000_TDB}"')
    shape = path.parent / data["shape"]
    if not shape.is_file():
        raise BodyDataError(
            f"body file {path}: shape file {shape} not found ('shape' is relative to the TOML's "
            "folder); fix the path"
        )
    try:
        body = body_from_files(
            shape,
            gm_m3_s2=data["gm_m3_s2"],
            spin_period_s=data["spin_period_s"],
            pole=pole,
            prime_meridian_deg=prime_meridian,
            rotation_epoch=epoch,
            name=data.get("name", path.stem.lower()),
            units=data["units"],
            fmt=fmt,
            naif_id=naif_id,
            description=data.get("description", ""),
        )
    except HamgravError as exc:
        raise type(exc)(f"body file {path}: {exc}") from None
    return replace(body, source={**body.source, "toml": str(path.resolve())})


def _is_number(value) -> bool:
    """A finite real number that is not a bool."""
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
