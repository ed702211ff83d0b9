"""Shape model files: read OBJ, PLY, STL, Gaskell ICQ and PDS vertex/plate tables; check them.

Every mesh hamgrav uses passes :func:`check_mesh`: finite vertices, faces that refer to
existing vertices, a closed (watertight), consistently wound surface with outward normals
(positive volume). A file that fails is refused with a one-line :class:`BodyDataError`
naming the file and the fix; hamgrav never repairs a user's file silently (an inside-out
mesh is refused, not flipped: which way its faces point is the file's to say).

Formats (``fmt``; by default from the file's suffix):

- ``obj``, ``ply``, ``stl``: read by trimesh (an STL file repeats each triangle's vertices:
  they are merged).
- ``icq``: Gaskell's implicitly connected quadrilateral format (SPC ``SHAPE.TXT``, the
  ``*q.tab`` files of PDS), usually in km. The first line holds Q; then 6 (Q+1)^2 lines
  ``x y z`` (a fourth column, albedo, is ignored): the vertices v(I, J, F) of six (Q+1) x
  (Q+1) grids on the faces of a cube, read as::

      DO F = 1, 6; DO J = 0, Q; DO I = 0, Q; READ x, y, z of v(I, J, F)

  The facet f(I, J, F) has the vertices v(I,J,F), v(I,J+1,F), v(I+1,J+1,F), v(I+1,J,F), in
  that order (outward, counter-clockwise seen from outside); it is split into the triangles
  (v(I,J), v(I,J+1), v(I+1,J)) and (v(I+1,J), v(I,J+1), v(I+1,J+1)). Vertices on the cube's
  edges appear on two or three faces (the last row of face 1 is the first row of face 2,
  ...): they are merged by the format's edge rules, and refused when their coordinates
  differ (a file in another order). Only 6 Q^2 + 2 vertices are independent. This is the
  format's description in the PDS archive of Gaskell's shape models (e.g. the Hayabusa
  Itokawa shape, ``HAY_A_AMICA_5_ITOKAWASHAPE_V1_0/document/icqmodel.asc``, with its
  unfolded-cube figure and the twelve edge rules); :func:`icq_cube_points` places the grids
  on a cube as SPC's own ``SHAPE.TXT`` does (its first vertex at (-, +, +) on face 1 = +z).
- ``pds``: the vertex/facet tables of PDS shape models, 1-based, in one of two flavours:
  lines ``v x y z`` and ``f i j k`` (OBJ-like), or the numbered plate model: a line with
  the vertex count, the lines ``index x y z``, a line with the plate count, the lines
  ``index v1 v2 v3``. Suffixes ``.tab``, ``.txt``, ``.plt`` (and ``.dat``) are read as
  whichever of these two flavours, or ICQ, the file's first lines show.

``units`` is the file's length unit, ``"m"`` or ``"km"``; the mesh returned is in metres.
"""

from __future__ import annotations

import io
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import trimesh

from ..errors import BodyDataError, InputError
from ..files import atomic_path

__all__ = [
    "FORMATS",
    "UNITS_M",
    "check_mesh",
    "icq_cube_points",
    "read_shape",
    "shape_format",
    "write_icq",
    "write_pds_plates",
]

#: Metres per file length unit.
UNITS_M = {"m": 1.0, "km": 1000.0}

#: Shape formats :func:`read_shape` reads.
FORMATS = ("obj", "ply", "stl", "icq", "pds")

_TRIMESH_FORMATS = {"obj", "ply", "stl"}
_SUFFIX_FORMATS = {".obj": "obj", ".ply": "ply", ".stl": "stl", ".icq": "icq"}
#: Suffixes of plain-text tables: PDS vertex/facet or plate tables, or ICQ (sniffed).
_TABLE_SUFFIXES = {".tab", ".txt", ".plt", ".dat"}

#: Largest disagreement, relative to the largest vertex distance from the origin, between the
#: copies of an ICQ vertex on two cube faces. The copies come from one array printed twice,
#: so they agree to the last printed digit (1e-5 km on a 0.3 km body: 3e-5); a file in
#: another order puts them a grid step apart (2 / Q of the size: 4e-3 at Q = 512).
ICQ_EDGE_TOLERANCE = 1e-4


def _units_scale(units: str) -> float:
    if units not in UNITS_M:
        raise InputError(f"shape units must be 'm' or 'km', got {units!r}")
    return UNITS_M[units]


def shape_format(path: str | os.PathLike, fmt: str | None = None) -> str:
    """The format (one of :data:`FORMATS`) :func:`read_shape` reads ``path`` as: ``fmt`` when
    given, else from the suffix, the first lines of a ``.tab`` / ``.txt`` / ``.plt`` / ``.dat``
    table telling PDS from ICQ."""
    path = Path(path)
    if fmt is not None:
        if fmt not in FORMATS:
            raise InputError(
                f"shape format {fmt!r} of {path} is not one of {', '.join(FORMATS)}; give one "
                "of these (or none, to take it from the file's suffix)"
            )
        return fmt
    suffix = path.suffix.lower()
    if suffix in _SUFFIX_FORMATS:
        return _SUFFIX_FORMATS[suffix]
    if suffix in _TABLE_SUFFIXES:
        return "icq" if _table_flavour(path) == "icq" else "pds"
    raise InputError(
        f"cannot tell the format of shape file {path} from its suffix {suffix!r}; name the "
        f"format (one of {', '.join(FORMATS)}) or rename the file"
    )


def _table_flavour(path: Path) -> str:
    """``"vf"`` (v / f lines), ``"plates"`` (numbered plate model) or ``"icq"``, from the
    first two non-blank lines of ``path``."""
    _check_readable(path)
    head = []
    with open(path, errors="replace") as fh:
        for line in fh:
            if line.strip():
                head.append(line.split())
            if len(head) == 2:
                break
    if not head:
        raise BodyDataError(f"shape file {path} is empty; give a shape model file")
    if head[0][0].lower() in ("v", "f"):
        return "vf"
    if len(head) == 2 and len(head[0]) == 1 and len(head[1]) in (3, 4):
        # both start with a count line; an ICQ vertex line is "x y z" (or "x y z albedo"),
        # a plate model's vertex line "index x y z" with an integer index
        if len(head[1]) == 3 or not head[1][0].lstrip("+-").isdigit():
            return "icq"
    return "plates"


def _check_readable(path: Path) -> None:
    if path.is_dir():
        raise BodyDataError(f"shape file {path} is a folder; give the shape model file itself")
    if not path.is_file():
        raise BodyDataError(f"shape file not found: {path}; check the path")
    if not os.access(path, os.R_OK):
        raise BodyDataError(f"shape file {path} cannot be read (permissions); make it readable")


def read_shape(
    path: str | os.PathLike, fmt: str | None = None, units: str = "m"
) -> trimesh.Trimesh:
    """The closed, outward-wound triangle mesh [m] of the shape model file ``path``.

    ``fmt``: one of :data:`FORMATS` (default: from the suffix, see :func:`shape_format`);
    ``units``: the file's length unit, ``"m"`` or ``"km"``. The mesh passes
    :func:`check_mesh`; a missing, unreadable or malformed file raises
    :class:`BodyDataError` naming it and the fix. Vertices keep the file's order (ICQ: the
    first copy of each), faces too; vertices are scaled, never moved.
    """
    path = Path(path)
    scale = _units_scale(units)
    fmt = shape_format(path, fmt)
    _check_readable(path)
    if fmt in _TRIMESH_FORMATS:
        mesh = _read_trimesh(path, fmt)
        vertices, faces = np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces)
    elif fmt == "icq":
        vertices, faces = _read_icq(path)
        return check_mesh(vertices * scale, faces, path, flip_fix=_ICQ_FLIP_FIX)
    else:
        vertices, faces = _read_pds(path)
    return check_mesh(vertices * scale, faces, path)


_FLIP_FIX = "reverse each face's vertex order in the file"
#: An ICQ file's faces are implied by the format: one that comes out inside out is a mirror
#: image of a valid one and cannot be flipped within the format.
_ICQ_FLIP_FIX = (
    "an ICQ file's faces are implied, so this grid is mirrored: convert it to a vertex/facet "
    "table and reverse each face's vertex order there"
)


def _read_trimesh(path: Path, fmt: str) -> trimesh.Trimesh:
    try:
        # process=False: the file's vertices and faces as they are (no merging, no
        # reordering), so that a mesh and its digest do not depend on trimesh's cleaning
        mesh = trimesh.load(path, file_type=fmt, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types on bad input
        raise BodyDataError(
            f"cannot read shape file {path} as {fmt.upper()}: {exc}; the file is malformed "
            "(re-export it, or name its real format)"
        ) from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise BodyDataError(
            f"shape file {path} holds no triangle surface; the file is malformed (re-export it)"
        )
    if fmt == "stl":
        # STL stores every triangle with its own three corners: join the copies (exact
        # coordinates, to trimesh's merge precision) so the surface can be closed
        mesh.merge_vertices(merge_tex=True, merge_norm=True)
    return mesh


def check_mesh(
    vertices, faces, path: str | os.PathLike, *, flip_fix: str = _FLIP_FIX
) -> trimesh.Trimesh:
    """The mesh of ``vertices`` (n, 3) [m] and ``faces`` (m, 3) (0-based vertex indices), if it
    is a closed, consistently wound, outward surface; else :class:`BodyDataError` naming
    ``path`` (the file it came from) and the fix (``flip_fix``: how to flip the faces of an
    inside-out file of this format). Nothing is repaired."""
    vertices = np.asarray(vertices)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) < 4:
        raise BodyDataError(
            f"shape file {path} has {len(vertices)} vertices of 3 coordinates; a closed "
            "surface needs at least 4: the file is malformed or truncated"
        )
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) < 4:
        raise BodyDataError(
            f"shape file {path} has {len(faces)} triangles; a closed surface needs at least "
            "4: the file is malformed or truncated"
        )
    if not np.all(np.isfinite(vertices)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(vertices), axis=1))[0])
        raise BodyDataError(
            f"shape file {path}: vertex {bad + 1} has non-finite coordinates (NaN or inf); "
            "fix or re-export the file"
        )
    if faces.min() < 0 or faces.max() >= len(vertices):
        bad = int(np.flatnonzero((faces < 0).any(axis=1) | (faces >= len(vertices)).any(axis=1))[0])
        raise BodyDataError(
            f"shape file {path}: face {bad + 1} refers to vertex {_one_based(faces[bad], vertices)}"
            f", but there are {len(vertices)} vertices (indices 1-{len(vertices)}); the file is "
            "malformed or truncated"
        )
    mesh = trimesh.Trimesh(vertices.astype(float), faces.astype(np.int64), process=False)
    if not mesh.is_watertight:
        edges = np.sort(mesh.edges, axis=1)
        _, counts = np.unique(edges, axis=0, return_counts=True)
        open_edges = int(np.sum(counts == 1))
        raise BodyDataError(
            f"shape file {path} is not a closed surface ({open_edges} edges belong to one face "
            f"only, {int(np.sum(counts > 2))} to more than two); hamgrav needs a closed mesh: "
            "close its holes, and merge vertices repeated along seams, then save it again"
        )
    if not mesh.is_winding_consistent:
        raise BodyDataError(
            f"shape file {path} is not consistently wound (neighbouring faces list their shared "
            "edge in the same direction); re-export it with every face wound the same way "
            "(e.g. trimesh.repair.fix_winding)"
        )
    # the signed volume alone (trimesh's mesh.volume computes the whole inertia tensor too,
    # most of the time of reading a large ICQ file)
    a, b, c = (mesh.vertices[mesh.faces[:, k]] for k in range(3))
    with np.errstate(all="ignore"):
        volume = float(np.einsum("ij,ij->", a, np.cross(b, c)) / 6.0)
    if not volume > 0:
        if volume < 0:
            raise BodyDataError(
                f"shape file {path} is inside out (volume {volume:.4g} m^3: its faces' normals "
                f"point inward); the faces' winding must be flipped ({flip_fix}): hamgrav does "
                "not flip a file's faces itself"
            )
        raise BodyDataError(
            f"shape file {path} encloses no volume ({volume:.4g} m^3); the file is malformed"
        )
    return mesh


def _one_based(face: np.ndarray, vertices: np.ndarray) -> int:
    """The first out-of-range index of ``face``, 1-based as files number vertices."""
    bad = face[(face < 0) | (face >= len(vertices))]
    return int(bad[0]) + 1


# --------------------------------------------------------------------------------------------
# Text tables


def _bad_line(path: Path, number: int, line: str, expected: str) -> BodyDataError:
    text = line.strip()
    if len(text) > 60:
        text = text[:57] + "..."
    return BodyDataError(
        f"shape file {path}, line {number}: {text!r} is not {expected}; the file is malformed "
        "(fix the line, or name the file's real format)"
    )


def _read_lines(path: Path) -> list[tuple[int, str]]:
    """The non-blank lines of ``path`` with their 1-based numbers."""
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise BodyDataError(
            f"shape file {path} is not a text file; give a text table or name its format"
        ) from None
    except OSError as exc:
        raise BodyDataError(f"shape file {path} cannot be read ({exc.strerror})") from None
    return [(n, line) for n, line in enumerate(text.splitlines(), start=1) if line.strip()]


def _numbers(
    path: Path, rows: list[tuple[int, str]], count: int, kind, what: str, skip: int = 0
) -> np.ndarray:
    """The ``count`` whitespace-separated numbers after the first ``skip`` words of each line
    in ``rows``, as an array (len(rows), count)."""
    # every row must have exactly skip + count words: usecols alone would ignore extra ones
    # (a quad 'f 1 2 3 4' read as a triangle); a split per line, not a string per number
    widths = np.fromiter((len(line.split()) for _, line in rows), dtype=int, count=len(rows))
    if rows and np.all(widths == skip + count):
        text = "\n".join(line for _, line in rows)
        try:
            # numpy's C parser: a Q = 512 ICQ file (1.6 M lines) in seconds and without a
            # Python string per number; it refuses a bad number, and the loop below then
            # finds the line to name
            data = np.loadtxt(
                io.StringIO(text),
                dtype=kind,
                usecols=range(skip, skip + count),
                comments=None,
                ndmin=2,
            )
            if data.shape == (len(rows), count):
                return data
        except ValueError:
            pass
    for n, line in rows:
        tokens = line.split()[skip:]
        if len(tokens) != count:
            raise _bad_line(path, n, line, what)
        try:
            [kind(t) for t in tokens]
        except ValueError:
            raise _bad_line(path, n, line, what) from None
    return np.array([line.split()[skip:] for _, line in rows], dtype=kind).reshape(-1, count)


def _count(path: Path, rows: list[tuple[int, str]], index: int, what: str) -> int:
    if index >= len(rows):
        raise BodyDataError(
            f"shape file {path} ends before the {what} count line; the file is truncated"
        )
    n, line = rows[index]
    tokens = line.split()
    if len(tokens) != 1 or not tokens[0].isdigit():
        raise _bad_line(path, n, line, f"the {what} count (one integer)")
    return int(tokens[0])


def _read_pds(path: Path) -> tuple[np.ndarray, np.ndarray]:
    rows = _read_lines(path)
    if not rows:
        raise BodyDataError(f"shape file {path} is empty; give a shape model file")
    if rows[0][1].split()[0].lower() in ("v", "f"):
        return _read_vf(path, rows)
    return _read_plates(path, rows)


def _read_vf(path: Path, rows: list[tuple[int, str]]) -> tuple[np.ndarray, np.ndarray]:
    """The ``v x y z`` / ``f i j k`` flavour (1-based)."""
    v_rows, f_rows = [], []
    for n, line in rows:
        key = line.split()[0].lower()
        if key not in ("v", "f"):
            raise _bad_line(path, n, line, "a 'v x y z' or 'f i j k' line")
        (v_rows if key == "v" else f_rows).append((n, line))
    vertices = _numbers(path, v_rows, 3, float, "a vertex line 'v x y z'", skip=1)
    faces = _numbers(path, f_rows, 3, int, "a facet line 'f i j k' of 1-based integers", skip=1)
    return vertices, faces - 1


def _read_plates(path: Path, rows: list[tuple[int, str]]) -> tuple[np.ndarray, np.ndarray]:
    """The numbered plate model: vertex count, ``index x y z`` lines, plate count,
    ``index v1 v2 v3`` lines (1-based)."""
    nv = _count(path, rows, 0, "vertex")
    v_rows = rows[1 : 1 + nv]
    if len(v_rows) < nv:
        raise BodyDataError(
            f"shape file {path} announces {nv} vertices but holds {len(v_rows)} lines after the "
            "count; the file is truncated"
        )
    table = _numbers(path, v_rows, 4, float, "a vertex line 'index x y z'")
    nf = _count(path, rows, 1 + nv, "plate")
    f_rows = rows[2 + nv : 2 + nv + nf]
    if len(f_rows) < nf:
        raise BodyDataError(
            f"shape file {path} announces {nf} plates but holds {len(f_rows)} lines after the "
            "count; the file is truncated"
        )
    extra = rows[2 + nv + nf :]
    if extra:
        raise _bad_line(path, extra[0][0], extra[0][1], "expected after the last plate line")
    plates = _numbers(path, f_rows, 4, int, "a plate line 'index v1 v2 v3' of integers")
    for what, index, lines in (("vertex", table[:, 0], v_rows), ("plate", plates[:, 0], f_rows)):
        wrong = np.flatnonzero(index != np.arange(1, len(index) + 1))
        if len(wrong):
            n, line = lines[int(wrong[0])]
            raise _bad_line(
                path, n, line, f"{what} number {int(wrong[0]) + 1} (numbered 1, 2, ...)"
            )
    return table[:, 1:], plates[:, 1:] - 1


# --------------------------------------------------------------------------------------------
# ICQ


def icq_cube_points(q: int) -> np.ndarray:
    """Integer positions (6, q + 1, q + 1, 3), indexed [F - 1, J, I], of the ICQ grid points
    v(I, J, F) on the cube [-q, q]^3: equal positions are one vertex of the format.

    The faces are placed as in SPC's ``SHAPE.TXT`` (face 1 = +z with v(0, 0, 1) at (-, +, +)
    and I along +x; 2 = -y, 3 = -x, 4 = +y, 5 = +x, 6 = -z), which meets the format's twelve
    edge rules (e.g. v(I, 0, 2) = v(I, Q, 1), v(I, Q, 6) = v(Q - I, Q, 4)) and makes each facet
    v(I,J), v(I,J+1), v(I+1,J+1), v(I+1,J) counter-clockwise seen from outside.
    """
    if isinstance(q, bool) or not isinstance(q, int | np.integer) or q < 1:
        raise InputError(f"ICQ resolution q must be an integer >= 1, got {q!r}")
    j, i = np.meshgrid(np.arange(q + 1), np.arange(q + 1), indexing="ij")
    a, b, c = 2 * i - q, q - 2 * j, np.full_like(i, q)  # a: along I, b: against J
    faces = [
        (a, b, c),  # 1: +z
        (a, -c, b),  # 2: -y
        (-c, -a, b),  # 3: -x
        (-a, c, b),  # 4: +y
        (c, a, b),  # 5: +x
        (a, -b, -c),  # 6: -z
    ]
    return np.stack([np.stack(f, axis=-1) for f in faces])


def _icq_topology(q: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For the 6 (q+1)^2 file lines of an ICQ file: the merged vertex of each (n,), the
    file line of each merged vertex's first copy (6 q^2 + 2,) and the triangles (12 q^2, 3)
    as merged vertex indices."""
    points = icq_cube_points(q).reshape(-1, 3)
    _, first, inverse = np.unique(points, axis=0, return_index=True, return_inverse=True)
    # number merged vertices in file order of their first copies
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    merged = rank[inverse.reshape(-1)]
    grid = np.arange(6 * (q + 1) ** 2).reshape(6, q + 1, q + 1)  # [F, J, I]
    v00, v01 = grid[:, :-1, :-1], grid[:, 1:, :-1]  # v(I, J), v(I, J+1)
    v10, v11 = grid[:, :-1, 1:], grid[:, 1:, 1:]  # v(I+1, J), v(I+1, J+1)
    triangles = np.concatenate(
        [np.stack([v00, v01, v10], -1).reshape(-1, 3), np.stack([v10, v01, v11], -1).reshape(-1, 3)]
    )
    return merged, first[order], merged[triangles]


def _read_icq(path: Path) -> tuple[np.ndarray, np.ndarray]:
    rows = _read_lines(path)
    if not rows:
        raise BodyDataError(f"shape file {path} is empty; give a shape model file")
    n, line = rows[0]
    tokens = line.split()
    if len(tokens) != 1 or not tokens[0].isdigit() or int(tokens[0]) < 1:
        raise _bad_line(path, n, line, "the ICQ resolution Q (one integer >= 1) on the first line")
    q = int(tokens[0])
    expected = 6 * (q + 1) ** 2
    lines = rows[1:]
    if len(lines) != expected:
        state = "truncated" if len(lines) < expected else "longer than that (not ICQ?)"
        raise BodyDataError(
            f"shape file {path}: an ICQ file of Q = {q} has {expected} vertex lines after the "
            f"first, this one {len(lines)}; the file is {state}"
        )
    columns = len(lines[0][1].split())
    if columns not in (3, 4):
        raise _bad_line(path, lines[0][0], lines[0][1], "an ICQ vertex line 'x y z'")
    # Fortran writes exponents as D (1.0D+02)
    fortran = [(n, line.replace("D", "E").replace("d", "e")) for n, line in lines]
    vertices = _numbers(path, fortran, columns, float, "an ICQ vertex line 'x y z'")[:, :3]
    finite = np.all(np.isfinite(vertices), axis=1)
    if not finite.all():
        n, line = lines[int(np.argmin(finite))]
        raise _bad_line(path, n, line, "a vertex of finite coordinates")
    merged, first, triangles = _icq_topology(q)
    unique = vertices[first]
    size = float(np.abs(vertices).max()) or 1.0
    gap = np.linalg.norm(vertices - unique[merged], axis=1)
    worst = int(np.argmax(gap))
    if gap[worst] > ICQ_EDGE_TOLERANCE * size:
        n, line = lines[worst]
        raise BodyDataError(
            f"shape file {path}, line {n}: this cube-edge vertex is {gap[worst]:.3g} away from "
            "its copy on the neighbouring face; the file is not in ICQ order (give its real "
            "format)"
        )
    return unique, triangles


def write_icq(
    path: str | os.PathLike,
    shape: Callable[[np.ndarray], np.ndarray] | np.ndarray,
    q: int | None = None,
    units: str = "km",
) -> Path:
    """Write an ICQ shape file (see the module docstring) and return its path.

    ``shape``: either a callable taking unit directions (n, 3) and returning the surface's
    distance [m] from the origin along each (a star-shaped body, sampled on the cube grid
    of resolution ``q``), or the vertices [m] themselves, an array (6, q + 1, q + 1, 3)
    indexed [F - 1, J, I] whose copies of each cube-edge vertex agree. ``units``: the file's
    length unit (``"km"``, as SPC writes them, or ``"m"``). The file is replaced atomically.
    """
    scale = _units_scale(units)
    if callable(shape):
        if q is None:
            raise InputError("write_icq needs the resolution q to sample a radius function")
        points = icq_cube_points(q).astype(float)
        directions = points / np.linalg.norm(points, axis=-1, keepdims=True)
        radius = np.asarray(shape(directions.reshape(-1, 3)), dtype=float)
        vertices = directions * radius.reshape(*directions.shape[:-1], 1)
    else:
        vertices = np.asarray(shape, dtype=float)
        if vertices.ndim != 4 or vertices.shape[0] != 6 or vertices.shape[-1] != 3:
            raise InputError(
                f"write_icq needs vertices of shape (6, q + 1, q + 1, 3), got {vertices.shape}"
            )
        q_given, q = q, vertices.shape[1] - 1
        if vertices.shape[2] != q + 1 or q < 1 or q_given not in (None, q):
            raise InputError(
                f"write_icq: vertices of shape {vertices.shape} do not make an ICQ grid of "
                f"q = {q_given if q_given is not None else q}"
            )
        merged, first, _ = _icq_topology(q)
        flat = vertices.reshape(-1, 3)
        gap = np.linalg.norm(flat - flat[first][merged], axis=1).max()
        if gap > ICQ_EDGE_TOLERANCE * np.abs(flat).max():
            raise InputError(
                f"write_icq: the copies of a cube-edge vertex on neighbouring faces differ by "
                f"{gap:.3g} m; give the grid in ICQ order (see icq_cube_points)"
            )
    if not np.all(np.isfinite(vertices)):
        raise InputError("write_icq: the vertices must be finite")
    flat = vertices.reshape(-1, 3) / scale
    body = "\n".join(f"{x:.12e} {y:.12e} {z:.12e}" for x, y, z in flat)
    return _write_text(path, f"{q}\n{body}\n")


def write_pds_plates(
    path: str | os.PathLike, mesh: trimesh.Trimesh, units: str = "km", *, numbered: bool = True
) -> Path:
    """Write ``mesh`` [m] as a PDS vertex/plate table in ``units`` (``"km"`` or ``"m"``) and
    return its path: the numbered plate model (vertex count, ``index x y z``, plate count,
    ``index v1 v2 v3``) or, with ``numbered=False``, ``v x y z`` / ``f i j k`` lines;
    1-based either way. The file is replaced atomically."""
    scale = _units_scale(units)
    vertices = np.asarray(mesh.vertices, dtype=float) / scale
    faces = np.asarray(mesh.faces, dtype=np.int64) + 1
    if numbered:
        lines = [str(len(vertices))]
        lines += [f"{k} {x:.12e} {y:.12e} {z:.12e}" for k, (x, y, z) in enumerate(vertices, 1)]
        lines.append(str(len(faces)))
        lines += [f"{k} {a} {b} {c}" for k, (a, b, c) in enumerate(faces, 1)]
    else:
        lines = [f"v {x:.12e} {y:.12e} {z:.12e}" for x, y, z in vertices]
        lines += [f"f {a} {b} {c}" for a, b, c in faces]
    return _write_text(path, "\n".join(lines) + "\n")


def _write_text(path: str | os.PathLike, text: str) -> Path:
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return path
