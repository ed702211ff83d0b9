"""Small bodies: shape, gravitational parameter, spin; the catalogue and the synthetic bodies.

A :class:`Body` holds its closed surface mesh in metres in the body-fixed frame (z along the
spin axis). Everything derived from it that the numerical core uses (canonical mesh, Brillouin
radius, surface-following sets, envelope) is in canonical units about the frame origin, which is
the centre of mass of the body's truth interior (see :meth:`Body.recentred`).

Catalogue bodies are read from the folder named by ``HAMGRAV_BODIES`` (default:
``../shared/bodies`` beside the repository root); synthetic bodies are generated here and need
no data at all; a user's own body comes from its shape file and constants
(:meth:`Body.from_files`) or a body TOML naming them (:mod:`hamgrav.bodies.files`), whose path
is accepted wherever a body's name is.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path

import numpy as np
import trimesh

from ..core.arcs import BodyRecord, mesh_digest
from ..errors import BodyDataError, InputError
from ..units import CanonicalUnits
from .rotation import J2000_TDB, RotationModel
from .shapes import read_shape

__all__ = [
    "Body",
    "BodyDataError",
    "G_SI",
    "SYNTHETIC_BODIES",
    "body_file",
    "bodies_dir",
    "check_body_name",
    "contact_binary",
    "contact_binary_radius",
    "list_bodies",
    "load_body",
    "read_catalogue",
    "resolve_body_spec",
]

#: Newtonian constant of gravitation [m^3 kg^-1 s^-2] (CODATA 2018).
G_SI = 6.67430e-11


@dataclass(frozen=True, eq=False)
class Body:
    """A small body.

    Attributes:
        name: catalogue name.
        gm_m3_s2: gravitational parameter [m^3/s^2].
        spin_period_s: sidereal spin period [s] about +z.
        mesh_m: closed, outward-wound triangle mesh [m], body-fixed frame.
        description: free text (provenance).
        data_files: named data files that came with the body (e.g. reference mascons).
        origin_m: position [m], in the mesh's own frame, of this body's frame origin.
        rotation: the body's rotation model in the ICRF (pole, prime meridian; the spin rate
            is ``spin_period_s``'s), when the catalogue entry has a ``rotation`` object.
        naif_id: the body's NAIF ID (e.g. 2025143 for Itokawa) when known: SPICE kernels and
            OEM CENTER_NAME may name the body by it.
        source: where the body came from, plain data: ``{"kind": "catalogue" | "files" |
            "synthetic", ...}`` with the catalogue folder, the body TOML or shape file, and
            the shape's units (recorded in arcs and model files with :attr:`mesh_sha256`).
    """

    name: str
    gm_m3_s2: float
    spin_period_s: float
    mesh_m: trimesh.Trimesh
    description: str = ""
    data_files: dict[str, Path] = field(default_factory=dict)
    origin_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation: RotationModel | None = None
    naif_id: int | None = None
    source: dict = field(default_factory=dict)

    @classmethod
    def from_files(
        cls,
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
        """A body of the shape model file ``mesh`` [``units``: "m" or "km"], GM [m^3/s^2] and
        spin period [s]; ``pole`` (right ascension, declination) [deg, ICRF] adds a rotation
        model. See :func:`hamgrav.bodies.files.body_from_files`."""
        from .files import body_from_files

        return body_from_files(
            mesh,
            gm_m3_s2=gm_m3_s2,
            spin_period_s=spin_period_s,
            pole=pole,
            prime_meridian_deg=prime_meridian_deg,
            rotation_epoch=rotation_epoch,
            name=name,
            units=units,
            fmt=fmt,
            naif_id=naif_id,
            description=description,
        )

    @cached_property
    def mesh_sha256(self) -> str:
        """SHA-256 (hex) of the mesh [m] in its own frame (:func:`~hamgrav.core.arcs.mesh_digest`):
        equal digests, the same shape, whatever file it came from."""
        return mesh_digest(self.mesh_m.vertices, self.mesh_m.faces)

    def record(self) -> BodyRecord:
        """This body as plain data, to record in arcs and model files."""
        rotation = None
        if self.rotation is not None:
            r = self.rotation
            rotation = {
                "pole_ra_deg": r.pole_ra_deg,
                "pole_dec_deg": r.pole_dec_deg,
                "prime_meridian_deg": r.prime_meridian_deg,
                "epoch_tdb": r.epoch,
            }
        return BodyRecord(
            name=self.name,
            gm_m3_s2=float(self.gm_m3_s2),
            spin_period_s=float(self.spin_period_s),
            origin_m=tuple(float(v) for v in self.origin_m),
            vertices_m=np.asarray(self.mesh_m.vertices, dtype=float),
            faces=np.asarray(self.mesh_m.faces, dtype=np.int64),
            rotation=rotation,
            naif_id=self.naif_id,
            source=dict(self.source),
            description=self.description,
        )

    @classmethod
    def from_record(cls, record: BodyRecord) -> Body:
        """The body a :class:`~hamgrav.core.arcs.BodyRecord` describes (its reference data
        files, such as a catalogue body's mascons, are not part of the record)."""
        rotation = None
        if record.rotation is not None:
            r = record.rotation
            rotation = RotationModel(
                float(r["pole_ra_deg"]),
                float(r["pole_dec_deg"]),
                float(r["prime_meridian_deg"]),
                float(record.spin_period_s),
                str(r.get("epoch_tdb", J2000_TDB)),
            )
        mesh = trimesh.Trimesh(
            np.asarray(record.vertices_m, dtype=float),
            np.asarray(record.faces, dtype=np.int64),
            process=False,
        )
        return cls(
            name=record.name,
            gm_m3_s2=float(record.gm_m3_s2),
            spin_period_s=float(record.spin_period_s),
            mesh_m=mesh,
            description=record.description,
            origin_m=tuple(float(v) for v in record.origin_m),
            rotation=rotation,
            naif_id=record.naif_id,
            source=dict(record.source),
        )

    @cached_property
    def units(self) -> CanonicalUnits:
        """The body's canonical units (length = synchronous radius, time = period / 2 pi)."""
        return CanonicalUnits(self.gm_m3_s2, self.spin_period_s)

    @cached_property
    def mesh(self) -> trimesh.Trimesh:
        """The shape in canonical units, about this body's frame origin."""
        vertices = (np.asarray(self.mesh_m.vertices) - np.asarray(self.origin_m)) / (
            self.units.length_m
        )
        return trimesh.Trimesh(vertices, np.asarray(self.mesh_m.faces), process=False)

    @cached_property
    def volume(self) -> float:
        """Volume in canonical units (length unit cubed)."""
        return float(self.mesh.volume)

    @cached_property
    def constant_density_centre_of_mass(self) -> np.ndarray:
        """Centre of mass of the shape at constant density, canonical, in this frame."""
        return np.asarray(self.mesh.center_mass, dtype=float)

    @cached_property
    def brillouin_radius(self) -> float:
        """Largest distance of the surface from the frame origin (canonical)."""
        return float(np.linalg.norm(self.mesh.vertices, axis=1).max())

    @property
    def brillouin_radius_m(self) -> float:
        """Brillouin radius [m]."""
        return self.brillouin_radius * self.units.length_m

    def recentred(self, origin: np.ndarray) -> Body:
        """The same body with its frame origin moved to ``origin`` (canonical, this frame)."""
        shift_m = np.asarray(origin, dtype=float) * self.units.length_m
        new_origin = tuple(float(v) for v in np.asarray(self.origin_m) + shift_m)
        return replace(self, origin_m=new_origin)

    def surface_points(self, altitude: float) -> np.ndarray:
        """Mesh vertices moved radially outward by ``altitude`` (canonical length), shape (n, 3)."""
        v = np.asarray(self.mesh.vertices, dtype=float)
        r = np.linalg.norm(v, axis=1, keepdims=True)
        return v * (1.0 + altitude / r)

    def envelope_points(self, max_altitude_rb: float = 0.15, levels: int = 15) -> np.ndarray:
        """The close-proximity envelope: every vertex raised radially to ``levels`` altitudes
        evenly spaced in (0, max_altitude_rb * R_B]; canonical, shape (levels * n, 3)."""
        if levels < 1 or max_altitude_rb <= 0:
            raise ValueError("envelope needs levels >= 1 and max_altitude_rb > 0")
        altitudes = np.linspace(max_altitude_rb / levels, max_altitude_rb, levels)
        altitudes = altitudes * self.brillouin_radius
        return np.concatenate([self.surface_points(h) for h in altitudes])

    def envelope_fraction_inside_brillouin(
        self, max_altitude_rb: float = 0.15, levels: int = 15
    ) -> float:
        """Fraction of the envelope points with r < R_B (where an exterior SH series diverges)."""
        pts = self.envelope_points(max_altitude_rb, levels)
        return float(np.mean(np.linalg.norm(pts, axis=1) < self.brillouin_radius))

    def altitude_to_canonical(self, altitude_m: float) -> float:
        """An altitude [m] in canonical length."""
        return float(self.units.to_length(altitude_m))


# --------------------------------------------------------------------------------------------
# Catalogue


def bodies_dir() -> Path:
    """The body data folder: ``$HAMGRAV_BODIES`` or ``../shared/bodies`` beside the repo root."""
    env = os.environ.get("HAMGRAV_BODIES")
    if env:
        return Path(env).expanduser()
    repo_root = Path(__file__).resolve().parents[3]
    return repo_root.parent / "shared" / "bodies"


def read_catalogue(folder: Path) -> dict:
    """The catalogue (``catalogue.json``) of the body data folder ``folder``: one JSON
    object keyed by body name. A missing folder or file, or a malformed one, raises
    :class:`BodyDataError` naming it and the fix."""
    folder = Path(folder)
    source = "HAMGRAV_BODIES" if os.environ.get("HAMGRAV_BODIES") else "the default location"
    if not folder.is_dir():
        raise BodyDataError(
            f"body data folder {folder} ({source}) does not exist. Set HAMGRAV_BODIES to the "
            "folder holding catalogue.json and the body sub-folders, or use the synthetic body."
        )
    path = folder / "catalogue.json"
    if not path.is_file():
        raise BodyDataError(
            f"body catalogue not found: {path}. Set HAMGRAV_BODIES to the folder holding "
            "catalogue.json and the body sub-folders, or use the synthetic body "
            "('hamgrav bodies' lists what can be loaded)."
        )
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError, OSError) as exc:
        raise BodyDataError(
            f"body catalogue {path} is not valid JSON ({exc}); restore the file from the "
            "shared data folder."
        ) from None
    if not isinstance(data, dict) or not all(isinstance(v, dict) for v in data.values()):
        raise BodyDataError(
            f"body catalogue {path} must hold one JSON object keyed by body name, each entry "
            "an object; restore the file from the shared data folder."
        )
    return data


def _load_mesh(path: Path) -> trimesh.Trimesh:
    """A catalogue mesh [m], checked as every shape file is (see :func:`.shapes.check_mesh`)."""
    if not path.is_file():
        raise BodyDataError(
            f"mesh file not found: {path}; restore it or point HAMGRAV_BODIES "
            "at a complete body data folder"
        )
    return read_shape(path, units="m")


def list_bodies(folder: str | os.PathLike | None = None) -> list[str]:
    """Names of the bodies that can be loaded: the synthetic ones, then the catalogue's (in
    ``folder``, default :func:`bodies_dir`)."""
    names = list(SYNTHETIC_BODIES)
    try:
        names += sorted(read_catalogue(Path(folder) if folder else bodies_dir()))
    except BodyDataError:
        pass
    return names


def _catalogue_entry(name: str, folder: Path) -> dict:
    """The catalogue entry of body ``name`` in ``folder``; :class:`BodyDataError` naming the
    known bodies when there is none."""
    try:
        catalogue = read_catalogue(folder)
    except BodyDataError as exc:  # no catalogue to look in: the name is unknown either way
        raise BodyDataError(
            f"unknown body {name!r}: {str(exc).rstrip('.')}, or give a body TOML file (a path "
            "ending in .toml)"
        ) from None
    key = name.strip().lower()
    if key not in catalogue:
        raise BodyDataError(
            f"unknown body {name!r}; known: {', '.join(list_bodies(folder))} "
            f"(catalogue {folder / 'catalogue.json'}), or give a body TOML file (a path "
            "ending in .toml)"
        )
    return catalogue[key]


def body_file(spec: str | os.PathLike) -> Path | None:
    """The body TOML file that ``spec`` names, or None when it is a body's name: a spec names
    a file when it ends in ``.toml`` or holds a path separator (``./rock``, ``data/rock.cfg``).
    A bare name is a synthetic or catalogue body's (an existing file of that name is read
    only when no such body exists; see :func:`load_body`)."""
    text = os.fspath(spec).strip()
    if text.lower().endswith(".toml") or "/" in text or os.sep in text:
        return Path(text).expanduser()
    return None


def resolve_body_spec(spec: str, base: str | os.PathLike) -> str:
    """``spec`` with a relative body-file path made absolute from the folder ``base`` (where
    the file naming it lives, e.g. a campaign TOML's folder); names are returned unchanged."""
    path = body_file(spec)
    if path is None or path.is_absolute():
        return spec
    return str((Path(base) / path).resolve())


def check_body_name(name: str | os.PathLike, folder: str | os.PathLike | None = None) -> None:
    """Raise :class:`BodyDataError` (or :class:`InputError`) unless ``name`` is a synthetic
    body, has an entry in the catalogue of ``folder`` (default :func:`bodies_dir`) or names a
    valid body TOML file: the check made before a long run. A catalogue entry's files are not
    read; a body TOML is read whole, shape included (a few seconds at most), since its
    errors are the user's to fix before anything runs."""
    _body_spec(name, folder)


def _body_spec(name: str | os.PathLike, folder) -> dict | Body | None:
    """What ``name`` names: a body read from its TOML file, the catalogue entry (a dict), or
    None for a synthetic body."""
    from .files import read_body_toml

    path = body_file(name)
    if path is not None:
        return read_body_toml(path)
    name = os.fspath(name)
    if name.strip().lower() in SYNTHETIC_BODIES:
        return None
    try:
        return _catalogue_entry(name, Path(folder) if folder else bodies_dir())
    except BodyDataError:
        if Path(name).is_file():  # a bare file name, not a body's
            return read_body_toml(name)
        raise


def load_body(
    name: str | os.PathLike,
    *,
    low_resolution: bool = False,
    folder: str | os.PathLike | None = None,
) -> Body:
    """Load a body by name: a synthetic one (see :data:`SYNTHETIC_BODIES`), an entry of the
    catalogue in ``folder`` (default :func:`bodies_dir`), or a body TOML file (a path ending in
    ``.toml`` or holding a separator, see :func:`body_file` and
    :func:`hamgrav.bodies.files.read_body_toml`; relative to the working folder). A body file
    has one shape: ``low_resolution`` applies to catalogue bodies only."""
    spec = _body_spec(name, folder)
    if isinstance(spec, Body):
        return spec
    key = os.fspath(name).strip().lower()
    if spec is None:
        return SYNTHETIC_BODIES[key]()
    folder = Path(folder) if folder else bodies_dir()
    entry = spec
    try:
        gm = float(entry["gm_m3_s2"])
        period = float(entry["spin_period_s"])
        files = dict(entry["files"])
        mesh_file = files["mesh_low" if low_resolution else "mesh"]
        if not all(isinstance(v, str) and v for v in files.values()):
            raise ValueError("files must map names to file names")
        rotation = entry.get("rotation")
        if rotation is not None:
            rotation = RotationModel(
                float(rotation["pole_ra_deg"]),
                float(rotation["pole_dec_deg"]),
                float(rotation["prime_meridian_deg"]),
                period,
                str(rotation.get("epoch_tdb", J2000_TDB)),
            )
    except (KeyError, TypeError, ValueError) as exc:
        raise BodyDataError(
            f"catalogue entry {key!r} in {folder / 'catalogue.json'} is malformed (missing or "
            f"bad field {exc}); it needs gm_m3_s2, spin_period_s and files.mesh (and, when "
            "given, rotation.pole_ra_deg, pole_dec_deg and prime_meridian_deg)"
        ) from None
    for field_name, value in (("gm_m3_s2", gm), ("spin_period_s", period)):
        if not (math.isfinite(value) and value > 0):
            raise BodyDataError(
                f"catalogue entry {key!r} in {folder / 'catalogue.json'}: {field_name} must be "
                f"a finite number > 0, got {value}; restore the catalogue"
            )
    body_folder = folder / key
    mesh = _load_mesh(body_folder / mesh_file)
    return Body(
        name=key,
        gm_m3_s2=gm,
        spin_period_s=period,
        mesh_m=mesh,
        description=str(entry.get("description", "")),
        data_files={k: body_folder / v for k, v in files.items()},
        rotation=rotation,
        source={
            "kind": "catalogue",
            "folder": str(folder.resolve()),
            "mesh_file": mesh_file,
            "units": "m",
        },
    )


# --------------------------------------------------------------------------------------------
# Synthetic bodies


def _ray_exit_ellipsoid(directions: np.ndarray, centre, semi_axes) -> np.ndarray:
    """Distance from the origin (inside the ellipsoid) to its surface along unit directions."""
    c = np.asarray(centre, float) / np.asarray(semi_axes, float)
    u = directions / np.asarray(semi_axes, float)
    a = np.sum(u * u, axis=1)
    b = u @ c
    cc = c @ c - 1.0
    if cc >= 0:
        raise ValueError("the ray origin must lie inside every lobe")
    return (b + np.sqrt(b * b - a * cc)) / a


def contact_binary_radius(
    directions: np.ndarray, *, length_m: float = 560.0, head_ratio: float = 0.7
) -> np.ndarray:
    """Distance [m] from the contact point to the surface of :func:`contact_binary`'s shape
    along unit ``directions`` (n, 3): a smooth maximum of two ellipsoidal lobes' radial
    functions, so the shape is star-shaped about the contact point. ``length_m`` is the
    overall length along x, ``head_ratio`` the head lobe's size relative to the main lobe.
    Sample it on any grid (an icosphere, an ICQ cube grid) to mesh the same body."""
    # Lobe geometry in units of the main lobe's long semi-axis; lobes overlap around x = 0.
    main_axes = np.array([1.0, 0.68, 0.56])
    head_axes = head_ratio * np.array([1.0, 0.78, 0.66])
    overlap = 0.18 * head_ratio
    main_centre = np.array([-(1.0 - overlap), 0.0, 0.0])
    head_centre = np.array([head_axes[0] - overlap, 0.0, 0.02])
    u = np.asarray(directions, dtype=float)
    r1 = _ray_exit_ellipsoid(u, main_centre, main_axes)
    r2 = _ray_exit_ellipsoid(u, head_centre, head_axes)
    k = 12.0  # smooth-maximum sharpness: a rounded neck rather than a crease
    r = (r1**k + r2**k) ** (1.0 / k)
    extent = (main_centre[0] - main_axes[0], head_centre[0] + head_axes[0])
    return r * (length_m / (extent[1] - extent[0]))


def contact_binary(
    *,
    name: str = "synthetic",
    length_m: float = 560.0,
    head_ratio: float = 0.7,
    density_kg_m3: float = 1900.0,
    spin_period_s: float = 12.0 * 3600.0,
    subdivisions: int = 4,
) -> Body:
    """A bilobed contact binary: two ellipsoidal lobes joined by a smooth neck.

    The surface is star-shaped about the contact point, built by radially scaling an icosphere
    with a smooth maximum of the two lobes' radial functions, so it is closed and outward-wound
    by construction. ``length_m`` is the overall length along x, ``head_ratio`` the head lobe's
    size relative to the main lobe; GM follows from ``density_kg_m3`` and the mesh volume.
    """
    if not (length_m > 0 and 0.2 <= head_ratio <= 1.0 and density_kg_m3 > 0 and spin_period_s > 0):
        raise InputError(
            "contact_binary needs length_m > 0, 0.2 <= head_ratio <= 1, density_kg_m3 > 0 and "
            "spin_period_s > 0"
        )
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    u = np.asarray(sphere.vertices) / np.linalg.norm(sphere.vertices, axis=1, keepdims=True)
    r = contact_binary_radius(u, length_m=length_m, head_ratio=head_ratio)
    vertices = u * r[:, None]
    mesh = trimesh.Trimesh(vertices, np.asarray(sphere.faces), process=False)
    mesh.apply_translation(-np.asarray(mesh.center_mass))
    gm = G_SI * density_kg_m3 * float(mesh.volume)
    return Body(
        name=name,
        gm_m3_s2=gm,
        spin_period_s=spin_period_s,
        mesh_m=mesh,
        description=(
            f"synthetic contact binary, length {length_m:g} m, head ratio {head_ratio:g}, "
            f"density {density_kg_m3:g} kg/m^3, spin period {spin_period_s:g} s"
        ),
        source={
            "kind": "synthetic",
            "generator": "contact_binary",
            "parameters": {
                "length_m": length_m,
                "head_ratio": head_ratio,
                "density_kg_m3": density_kg_m3,
                "spin_period_s": spin_period_s,
                "subdivisions": subdivisions,
            },
        },
    )


#: Bodies generated by hamgrav itself, available without any data folder.
SYNTHETIC_BODIES = {
    "synthetic": contact_binary,
}
