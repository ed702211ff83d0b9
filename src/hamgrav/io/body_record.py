"""The ``/body`` group of arcs and model files: the body a file was made with.

Layout::

    /body            attrs: name, gm_m3_s2, spin_period_s, origin_m (3,), mesh_sha256,
                            rotation (JSON object or null), naif_id (JSON integer or null),
                            source (JSON object), description
    /body/vertices_m (n, 3)  mesh vertices [m] in the mesh's own frame
    /body/faces      (k, 3)  outward-wound triangles (vertex indices)

With it, a file names its body by value: ``fit``, ``evaluate``, ``export`` and ``select``
rebuild the body from the file, never by looking its name up in a catalogue. Files written
before hamgrav recorded it have no ``/body`` group.
"""

from __future__ import annotations

import json
import math

import h5py
import numpy as np

from ..core.arcs import BodyRecord, mesh_digest
from .hdf5 import attribute, body_origin, number_attribute, write_array

__all__ = ["read_body_record", "write_body_record"]

GROUP = "body"


def write_body_record(parent: h5py.Group, record: BodyRecord) -> None:
    """Write ``record`` as the ``/body`` group of ``parent`` (an open file)."""
    group = parent.create_group(GROUP)
    group.attrs.update(
        {
            "name": record.name,
            "gm_m3_s2": float(record.gm_m3_s2),
            "spin_period_s": float(record.spin_period_s),
            "origin_m": np.asarray(record.origin_m, dtype=float),
            "mesh_sha256": record.mesh_sha256,
            "rotation": json.dumps(record.rotation),
            "naif_id": json.dumps(record.naif_id),
            "source": json.dumps(record.source),
            "description": record.description,
        }
    )
    write_array(group, "vertices_m", np.asarray(record.vertices_m, dtype=float))
    write_array(group, "faces", np.asarray(record.faces, dtype=np.int64))


def read_body_record(parent: h5py.Group, error: type[Exception]) -> BodyRecord | None:
    """The ``/body`` group of ``parent`` as a :class:`BodyRecord` (None when the file has
    none: written before hamgrav recorded it), every value checked; a problem raises
    ``error`` with a one-line message naming the attribute or dataset."""
    if GROUP not in parent:
        return None
    group = parent[GROUP]
    if not isinstance(group, h5py.Group):
        raise error(f"{GROUP!r} is not a group")
    arrays = {}
    for name, kind in (("vertices_m", "f"), ("faces", "iu")):
        obj = group.get(name)
        if not isinstance(obj, h5py.Dataset):
            raise error(f"dataset '{GROUP}/{name}' is missing")
        arr = np.asarray(obj[()])
        if arr.ndim != 2 or arr.shape[1] != 3 or len(arr) < 4 or arr.dtype.kind not in kind + "i":
            raise error(
                f"dataset '{GROUP}/{name}' must hold (n >= 4, 3) "
                f"{'numbers' if kind == 'f' else 'integers'}, got {arr.dtype} {arr.shape}"
            )
        arrays[name] = arr
    vertices, faces = arrays["vertices_m"].astype(float), arrays["faces"].astype(np.int64)
    if not np.all(np.isfinite(vertices)):
        raise error(f"dataset '{GROUP}/vertices_m' holds non-finite coordinates")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise error(f"dataset '{GROUP}/faces' refers to vertices that are not stored")
    stored = str(attribute(group, "mesh_sha256", error))
    if stored != mesh_digest(vertices, faces):
        raise error(f"the body's mesh does not match its recorded digest {stored[:12]}...")
    values = {}
    for name in ("gm_m3_s2", "spin_period_s"):
        value = number_attribute(group, name, float, error)
        if not (math.isfinite(value) and value > 0):
            raise error(f"attribute '{GROUP}/{name}' must be a finite number > 0, got {value}")
        values[name] = value
    parsed = {}
    for name, kinds in (("rotation", (dict, type(None))), ("naif_id", (int, type(None)))):
        try:
            parsed[name] = json.loads(str(attribute(group, name, error)))
        except json.JSONDecodeError:
            raise error(f"attribute '{GROUP}/{name}' is not JSON") from None
        if isinstance(parsed[name], bool) or not isinstance(parsed[name], kinds):
            raise error(f"attribute '{GROUP}/{name}' has the wrong type")
    try:
        source = json.loads(str(attribute(group, "source", error)))
    except json.JSONDecodeError:
        raise error(f"attribute '{GROUP}/source' is not JSON") from None
    if not isinstance(source, dict):
        raise error(f"attribute '{GROUP}/source' must hold a JSON object")
    rotation = parsed["rotation"]
    if rotation is not None:
        try:
            angles = [float(rotation[k]) for k in ("pole_ra_deg", "pole_dec_deg")]
            angles.append(float(rotation["prime_meridian_deg"]))
        except (KeyError, TypeError, ValueError):
            raise error(
                f"attribute '{GROUP}/rotation' needs pole_ra_deg, pole_dec_deg and "
                "prime_meridian_deg"
            ) from None
        if not all(math.isfinite(a) for a in angles):
            raise error(f"attribute '{GROUP}/rotation' holds non-finite angles")
    return BodyRecord(
        name=str(attribute(group, "name", error)),
        origin_m=body_origin(attribute(group, "origin_m", error), error),
        vertices_m=vertices,
        faces=faces,
        rotation=rotation,
        naif_id=parsed["naif_id"],
        source=source,
        description=str(attribute(group, "description", error)),
        **values,
    )
