"""Shape model files: ICQ, PDS tables and trimesh formats read back, and refused when broken."""

import io

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from hamgrav.bodies.catalogue import contact_binary
from hamgrav.bodies.shapes import (
    icq_cube_points,
    read_shape,
    shape_format,
    write_icq,
    write_pds_plates,
)
from hamgrav.errors import BodyDataError, InputError

AXES_M = np.array([300.0, 200.0, 150.0])


def ellipsoid_radius(directions):
    """Distance [m] from the centre to the ellipsoid AXES_M along unit directions."""
    return 1.0 / np.sqrt(np.sum((directions / AXES_M) ** 2, axis=1))


def assert_closed_outward(mesh):
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    # every face's normal points away from the centre of this convex shape
    outward = np.einsum("ij,ij->i", mesh.face_normals, mesh.triangles_center - mesh.centroid)
    assert np.all(outward > 0)


def one_line_error(exc_info, path):
    message = str(exc_info.value)
    assert str(path) in message and "\n" not in message
    return message


# --------------------------------------------------------------------------------------------
# ICQ against the published description

# The twelve edge rules and eight corners of the ICQ format, as printed (faces 1-6) in the
# format's description in the PDS archive of Gaskell's Itokawa shape model
# (HAY_A_AMICA_5_ITOKAWASHAPE_V1_0/document/icqmodel.asc). Each pair: (I, J, F) of both sides
# as functions of I and Q.
EDGE_RULES = [
    (lambda i, q: (i, q, 6), lambda i, q: (q - i, q, 4)),
    (lambda i, q: (i, 0, 6), lambda i, q: (i, q, 2)),
    (lambda i, q: (i, 0, 5), lambda i, q: (q, q - i, 1)),
    (lambda i, q: (i, 0, 4), lambda i, q: (q - i, 0, 1)),
    (lambda i, q: (i, 0, 3), lambda i, q: (0, i, 1)),
    (lambda i, q: (i, 0, 2), lambda i, q: (i, q, 1)),
    (lambda i, q: (q, i, 6), lambda i, q: (i, q, 5)),
    (lambda i, q: (q, i, 5), lambda i, q: (0, i, 4)),
    (lambda i, q: (q, i, 4), lambda i, q: (0, i, 3)),
    (lambda i, q: (q, i, 3), lambda i, q: (0, i, 2)),
    (lambda i, q: (0, i, 6), lambda i, q: (q - i, q, 3)),
    (lambda i, q: (0, i, 5), lambda i, q: (q, i, 2)),
]
CORNERS = [  # "Q" stands for q
    [(0, 0, 1), (0, 0, 3), ("Q", 0, 4)],
    [(0, "Q", 1), (0, 0, 2), ("Q", 0, 3)],
    [("Q", 0, 1), (0, 0, 4), ("Q", 0, 5)],
    [("Q", "Q", 1), (0, 0, 5), ("Q", 0, 2)],
    [(0, 0, 6), (0, "Q", 2), ("Q", "Q", 3)],
    [(0, "Q", 6), (0, "Q", 3), ("Q", "Q", 4)],
    [("Q", 0, 6), (0, "Q", 5), ("Q", "Q", 2)],
    [("Q", "Q", 6), (0, "Q", 4), ("Q", "Q", 5)],
]


@pytest.mark.parametrize("q", [1, 2, 5])
def test_icq_grid_meets_the_published_edge_rules(q):
    points = icq_cube_points(q)

    def at(i, j, f):
        return points[f - 1, j, i]

    for left, right in EDGE_RULES:
        for i in range(q + 1):
            assert np.array_equal(at(*left(i, q)), at(*right(i, q)))
    for corner in CORNERS:
        labels = [tuple(q if v == "Q" else v for v in label) for label in corner]
        assert all(np.array_equal(at(*labels[0]), at(*other)) for other in labels[1:])
    # nothing else coincides: 6 q^2 + 2 distinct vertices
    assert len(np.unique(points.reshape(-1, 3), axis=0)) == 6 * q * q + 2


# A box of half sides 3, 2, 1 km as an ICQ file of Q = 1, written by hand in the order of a
# public ICQ cube generator (face 1 at z = +c with I along -x and J along +y; then +y, +x, -y,
# -x, -z): another placement of the faces on the cube than hamgrav's writer uses.
BOX_Q1 = """1
 3 -2  1
-3 -2  1
 3  2  1
-3  2  1
 3  2  1
-3  2  1
 3  2 -1
-3  2 -1
 3 -2  1
 3  2  1
 3 -2 -1
 3  2 -1
-3 -2  1
 3 -2  1
-3 -2 -1
 3 -2 -1
-3  2  1
-3 -2  1
-3  2 -1
-3 -2 -1
 3  2 -1
-3  2 -1
 3 -2 -1
-3 -2 -1
"""


def _box_icq_text(q, half=(3.0, 2.0, 1.0)):
    """The same generator's loops for any Q."""
    a, b, c = half
    up, down = np.linspace(-1, 1, q + 1), np.linspace(1, -1, q + 1)
    rows = []
    rows += [(x * a, y * b, c) for y in up for x in down]  # face 1: z = +c
    rows += [(x * a, b, z * c) for z in down for x in down]  # face 2: y = +b
    rows += [(a, y * b, z * c) for z in down for y in up]  # face 3: x = +a
    rows += [(x * a, -b, z * c) for z in down for x in up]  # face 4: y = -b
    rows += [(-a, y * b, z * c) for z in down for y in down]  # face 5: x = -a
    rows += [(x * a, y * b, -c) for y in down for x in down]  # face 6: z = -c
    return f"{q}\n" + "".join(f"{x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in rows)


@pytest.mark.parametrize("q", [1, 2, 3])
def test_hand_written_icq_box_is_closed_and_outward(tmp_path, q):
    path = tmp_path / "box.icq"
    path.write_text(BOX_Q1 if q == 1 else _box_icq_text(q))
    if q == 1:  # the hand-written file is the generator's
        assert np.array_equal(
            np.loadtxt(io.StringIO(BOX_Q1), skiprows=1),
            np.loadtxt(io.StringIO(_box_icq_text(1)), skiprows=1),
        )
    mesh = read_shape(path, units="km")
    assert len(mesh.vertices) == 6 * q * q + 2 and len(mesh.faces) == 12 * q * q
    assert mesh.volume == pytest.approx(6e3 * 4e3 * 2e3, rel=1e-12)
    assert_closed_outward(mesh)
    assert np.allclose(mesh.bounds, [[-3e3, -2e3, -1e3], [3e3, 2e3, 1e3]])


def test_mirrored_icq_is_refused_as_inside_out(tmp_path):
    # the box seen in a mirror (every vertex through the origin): the same grid, turned
    # inside out
    rows = -np.loadtxt(io.StringIO(_box_icq_text(2)), skiprows=1)
    path = tmp_path / "mirror.icq"
    path.write_text("2\n" + "".join(f"{x} {y} {z}\n" for x, y, z in rows))
    with pytest.raises(BodyDataError, match="is inside out .*flipped .*grid is mirrored") as exc:
        read_shape(path)
    one_line_error(exc, path)


@pytest.mark.parametrize("q", [16, 32])
def test_icq_ellipsoid_round_trip(tmp_path, q):
    path = write_icq(tmp_path / "e.icq", ellipsoid_radius, q, units="km")
    written = np.loadtxt(path, skiprows=1) * 1000.0
    assert len(written) == 6 * (q + 1) ** 2
    mesh = read_shape(path, units="km")
    assert_closed_outward(mesh)
    assert mesh.volume == pytest.approx(4 / 3 * np.pi * AXES_M.prod(), rel=0.01)
    # the vertices written, each once
    assert len(mesh.vertices) == 6 * q * q + 2
    assert np.array_equal(np.unique(mesh.vertices, axis=0), np.unique(written, axis=0))
    assert np.allclose(
        np.linalg.norm(mesh.vertices, axis=1),
        ellipsoid_radius(mesh.vertices / np.linalg.norm(mesh.vertices, axis=1, keepdims=True)),
        rtol=1e-12,
    )


def test_icq_writer_takes_a_vertex_grid(tmp_path):
    points = icq_cube_points(4).astype(float) * 10.0
    path = write_icq(tmp_path / "cube.txt", points, units="m")
    assert shape_format(path) == "icq"  # a .txt table told from its first lines
    assert read_shape(path).volume == pytest.approx(80.0**3)
    broken = points.copy()
    broken[1, 0, 0] += 5.0  # an edge vertex no longer on its neighbour face's copy
    with pytest.raises(InputError, match="copies of a cube-edge vertex"):
        write_icq(tmp_path / "broken.icq", broken)


def test_km_file_read_as_km_equals_the_m_file(tmp_path):
    in_km = read_shape(write_icq(tmp_path / "km.icq", ellipsoid_radius, 8, units="km"), units="km")
    in_m = read_shape(write_icq(tmp_path / "m.icq", ellipsoid_radius, 8, units="m"), units="m")
    np.testing.assert_allclose(in_km.vertices, in_m.vertices, rtol=1e-12)
    assert np.array_equal(in_km.faces, in_m.faces)
    mesh = contact_binary().mesh_m
    for units in ("km", "m"):
        write_pds_plates(tmp_path / f"{units}.tab", mesh, units=units)
    np.testing.assert_allclose(
        read_shape(tmp_path / "km.tab", units="km").vertices,
        read_shape(tmp_path / "m.tab", units="m").vertices,
        rtol=1e-12,
    )


def test_icq_errors_are_one_line(tmp_path):
    good = write_icq(tmp_path / "good.icq", ellipsoid_radius, 4).read_text().splitlines()
    cases = {
        "truncated": ("\n".join(good[:-7]), "has 150 vertex lines .* this one 143; .* truncated"),
        "text": (
            "\n".join([*good[:9], "0.1 0.2 abc", *good[10:]]),
            r"line 10: '0.1 0.2 abc' is not an ICQ vertex line",
        ),
        "q": ("\n".join(["four", *good[1:]]), "line 1: 'four' is not the ICQ resolution"),
        "order": (
            "\n".join([good[0], *good[:0:-1]]),
            "cube-edge vertex .* not in ICQ order",
        ),
    }
    for name, (text, message) in cases.items():
        path = tmp_path / f"{name}.icq"
        path.write_text(text + "\n")
        with pytest.raises(BodyDataError, match=message) as exc:
            read_shape(path, units="km")
        one_line_error(exc, path)


def test_icq_reads_fortran_exponents(tmp_path):
    text = write_icq(tmp_path / "e.icq", ellipsoid_radius, 4).read_text()
    fortran = tmp_path / "fortran.icq"
    fortran.write_text(text.replace("e", "D"))
    np.testing.assert_array_equal(
        read_shape(fortran, units="km").vertices,
        read_shape(tmp_path / "e.icq", units="km").vertices,
    )


# --------------------------------------------------------------------------------------------
# PDS tables and the trimesh formats


@pytest.mark.parametrize("numbered, suffix", [(True, ".tab"), (False, ".txt"), (True, ".plt")])
def test_pds_tables_round_trip(tmp_path, numbered, suffix):
    mesh = contact_binary().mesh_m
    path = write_pds_plates(tmp_path / f"shape{suffix}", mesh, units="km", numbered=numbered)
    first = path.read_text().split("\n", 1)[0]
    assert (first == str(len(mesh.vertices))) if numbered else first.startswith("v ")
    assert shape_format(path) == "pds"
    back = read_shape(path, units="km")
    np.testing.assert_allclose(back.vertices, mesh.vertices, rtol=1e-12, atol=1e-9)
    assert np.array_equal(back.faces, mesh.faces)
    assert back.volume == pytest.approx(mesh.volume, rel=1e-12)


@pytest.mark.parametrize("fmt", ["obj", "ply", "stl"])
def test_trimesh_formats_round_trip(tmp_path, fmt):
    mesh = contact_binary().mesh_m
    path = tmp_path / f"shape.{fmt}"
    mesh.export(path)
    back = read_shape(path)
    assert back.is_watertight and back.is_winding_consistent
    assert back.volume == pytest.approx(mesh.volume, rel=1e-6)
    # STL repeats every triangle's corners; read back, the shared vertices are merged
    assert len(back.vertices) == len(mesh.vertices) and len(back.faces) == len(mesh.faces)
    # the same vertices, to the float32 precision of PLY and STL
    distance, _ = cKDTree(mesh.vertices).query(back.vertices)
    assert distance.max() < 1e-4


def _tetrahedron_plates(faces):
    vertices = ["1 0 0 0", "2 1 0 0", "3 0 1 0", "4 0 0 1"]
    plates = [f"{k} {a} {b} {c}" for k, (a, b, c) in enumerate(faces, 1)]
    return "\n".join(["4", *vertices, str(len(plates)), *plates]) + "\n"


OUTWARD = [(1, 3, 2), (1, 2, 4), (1, 4, 3), (2, 3, 4)]


@pytest.mark.parametrize(
    "name, text, message",
    [
        ("outward", _tetrahedron_plates(OUTWARD), None),
        (
            "inside-out",
            _tetrahedron_plates([(a, c, b) for a, b, c in OUTWARD]),
            r"is inside out \(volume -0.1667 m\^3.* the faces' winding must be flipped",
        ),
        (
            "truncated",
            _tetrahedron_plates(OUTWARD).rsplit("\n", 3)[0],
            "announces 4 plates but holds 2 lines",
        ),
        (
            "out-of-range",
            _tetrahedron_plates(OUTWARD[:3] + [(2, 3, 5)]),
            "face 4 refers to vertex 5, but there are 4 vertices",
        ),
        (
            "zero-index",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 0 3 4\n",
            "face 4 refers to vertex 0, but there are 4 vertices",
        ),
        (
            "non-numeric",
            _tetrahedron_plates(OUTWARD).replace("2 1 0 0", "2 1 O 0"),
            r"line 3: '2 1 O 0' is not a vertex line 'index x y z'",
        ),
        (
            "wound-inconsistently",
            _tetrahedron_plates(OUTWARD[:3] + [(2, 4, 3)]),
            "is not consistently wound",
        ),
        ("nan", _tetrahedron_plates(OUTWARD).replace("4 0 0 1", "4 0 0 nan"), "vertex 4 has non"),
        (
            # an extra column is a line of another kind, not a triangle with a comment
            "quad-facet",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4 1\n",
            r"line 8: 'f 2 3 4 1' is not a facet line",
        ),
        (
            "extra-plate-column",
            _tetrahedron_plates(OUTWARD).replace("4 0 0 1", "4 0 0 1 7"),
            r"'4 0 0 1 7' is not a vertex line 'index x y z'",
        ),
        ("empty", "\n\n", "is empty"),
    ],
)
def test_pds_errors_are_one_line(tmp_path, name, text, message):
    path = tmp_path / f"{name}.tab"
    path.write_text(text)
    if message is None:
        assert read_shape(path).volume == pytest.approx(1 / 6)
        return
    with pytest.raises(BodyDataError, match=message) as exc:
        read_shape(path)
    one_line_error(exc, path)


def test_open_mesh_is_refused(tmp_path):
    mesh = contact_binary().mesh_m
    path = write_pds_plates(tmp_path / "open.tab", mesh)
    lines = path.read_text().splitlines()
    n = len(mesh.vertices)
    plates = lines[n + 2 :]
    path.write_text("\n".join([*lines[: n + 1], str(len(plates) - 1), *plates[:-1]]) + "\n")
    with pytest.raises(BodyDataError, match=r"not a closed surface \(3 edges belong to one") as exc:
        read_shape(path)
    one_line_error(exc, path)


def test_inside_out_obj_is_refused(tmp_path):
    mesh = contact_binary().mesh_m
    path = tmp_path / "flipped.obj"
    trimesh.Trimesh(mesh.vertices, mesh.faces[:, ::-1], process=False).export(path)
    with pytest.raises(BodyDataError, match="inside out") as exc:
        read_shape(path)
    one_line_error(exc, path)


def test_formats_and_units_are_checked(tmp_path):
    path = tmp_path / "shape.xyz"
    path.write_text("1\n")
    with pytest.raises(InputError, match=r"cannot tell the format .* suffix '.xyz'"):
        read_shape(path)
    with pytest.raises(InputError, match="shape format 'vrml' .* is not one of obj, ply"):
        read_shape(path, fmt="vrml")
    with pytest.raises(InputError, match="units must be 'm' or 'km', got 'cm'"):
        read_shape(path, fmt="obj", units="cm")
    with pytest.raises(BodyDataError, match="shape file not found: .*nowhere.obj; check the path"):
        read_shape(tmp_path / "nowhere.obj")
