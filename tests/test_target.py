"""Target loading: file formats, repairs, and one clear error per mesh defect."""

from __future__ import annotations

import struct
from pathlib import Path

import igl
import numpy as np
import pytest
from numpy.typing import NDArray

from drawstring.geometry.core.errors import InputError, InternalError
from drawstring.geometry.target.meshfiles import merge_coincident_vertices, read_mesh
from drawstring.geometry.target.surface import (
    Target,
    load_target,
    validate_disk_mesh,
)

DATA = Path(__file__).parent / "data"

Mesh = tuple[NDArray[np.float64], NDArray[np.int64]]


# --- small synthetic meshes -------------------------------------------------------------


def grid_disk(n_u: int = 4, n_v: int = 3) -> Mesh:
    """A gently curved grid patch (a disk), faces counter-clockwise seen from +z.

    Coordinates are multiples of 1/64 so that they survive float32 (STL) exactly.
    """
    x, y = np.meshgrid(np.arange(n_u + 1, dtype=float), np.arange(n_v + 1, dtype=float))
    z = np.round(4.0 * np.sin(x / 3.0) * np.cos(y / 4.0)) / 64.0
    vertices = np.column_stack([x.ravel(), y.ravel(), z.ravel()])
    faces = []
    for j in range(n_v):
        for i in range(n_u):
            a = i + j * (n_u + 1)
            b, c, d = a + 1, a + n_u + 2, a + n_u + 1
            faces += [(a, b, c), (a, c, d)]
    return vertices, np.array(faces, dtype=np.int64)


def ring(n_around: int, n_across: int = 1, closed: bool = True) -> Mesh:
    """An annulus (``closed``) or a strip bent into a C (not closed), flat in z = 0."""
    n_cols = n_around if closed else n_around + 1
    angles = np.linspace(0.0, 2.0 * np.pi * (1 if closed else 0.8), n_cols, endpoint=not closed)
    radii = np.linspace(1.0, 2.0, n_across + 1)
    r, t = np.meshgrid(radii, angles, indexing="ij")
    vertices = np.column_stack([(r * np.cos(t)).ravel(), (r * np.sin(t)).ravel(), 0.0 * r.ravel()])
    faces = []
    for j in range(n_across):
        for i in range(n_around):
            a, b = j * n_cols + i, j * n_cols + (i + 1) % n_cols
            c, d = b + n_cols, a + n_cols
            faces += [(a, b, c), (a, c, d)]
    return vertices, np.array(faces, dtype=np.int64)


def torus(n_major: int = 8, n_minor: int = 6) -> Mesh:
    """A closed torus, consistently oriented."""
    u, v = np.meshgrid(
        np.linspace(0, 2 * np.pi, n_major, endpoint=False),
        np.linspace(0, 2 * np.pi, n_minor, endpoint=False),
        indexing="ij",
    )
    x = (2.0 + np.cos(v)) * np.cos(u)
    y = (2.0 + np.cos(v)) * np.sin(u)
    vertices = np.column_stack([x.ravel(), y.ravel(), np.sin(v).ravel()])
    faces = []
    for i in range(n_major):
        for j in range(n_minor):
            a = i * n_minor + j
            b = ((i + 1) % n_major) * n_minor + j
            c = ((i + 1) % n_major) * n_minor + (j + 1) % n_minor
            d = i * n_minor + (j + 1) % n_minor
            faces += [(a, b, c), (a, c, d)]
    return vertices, np.array(faces, dtype=np.int64)


def octahedron() -> Mesh:
    vertices = np.array(
        [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=float
    )
    faces = np.array(
        [[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]]
    )
    return vertices, faces


def mobius(n: int = 12) -> Mesh:
    """A Moebius strip: a band of quads whose ends are glued with a half twist."""
    t = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    vertices = []
    for side in (-0.3, 0.3):
        vertices.append(
            np.column_stack(
                [
                    (1 + side * np.cos(t / 2)) * np.cos(t),
                    (1 + side * np.cos(t / 2)) * np.sin(t),
                    side * np.sin(t / 2),
                ]
            )
        )
    V = np.concatenate(vertices)
    faces = []
    for i in range(n):
        a, d = i, i + n
        if i < n - 1:
            b, c = i + 1, i + 1 + n
        else:  # half twist: the inner edge meets the outer one
            b, c = n, 0
        faces += [(a, b, c), (a, c, d)]
    return V, np.array(faces, dtype=np.int64)


def split_edge_with_sliver(mesh: Mesh) -> Mesh:
    """Put a zero-area face into the interior: split one side of an interior edge at its midpoint.

    The faces on one side of edge (a, b) use the new midpoint m; the sliver (a, b, m) joins
    them to the face on the other side, so removing the sliver opens a slit.
    """
    vertices, faces = mesh
    edge_faces: dict[tuple[int, int], list[int]] = {}
    for f, tri in enumerate(faces.tolist()):
        for k in range(3):
            key = (min(tri[k], tri[(k + 1) % 3]), max(tri[k], tri[(k + 1) % 3]))
            edge_faces.setdefault(key, []).append(f)
    on_boundary = {v for edge, fs in edge_faces.items() if len(fs) == 1 for v in edge}
    (a, b), (f1, _) = next(
        (edge, fs)
        for edge, fs in edge_faces.items()
        if len(fs) == 2 and not on_boundary.intersection(edge)
    )
    tri = list(faces[f1])
    k = next(k for k in range(3) if {tri[k], tri[(k + 1) % 3]} == {a, b})
    start, end, opposite = tri[k], tri[(k + 1) % 3], tri[(k + 2) % 3]
    m = len(vertices)
    new_vertices = np.vstack([vertices, (vertices[start] + vertices[end]) / 2.0])
    replaced = [(start, m, opposite), (m, end, opposite), (start, end, m)]  # last: sliver
    new_faces = np.vstack([np.delete(faces, f1, axis=0), np.array(replaced)])
    return new_vertices, new_faces.astype(np.int64)


# --- writers --------------------------------------------------------------------------------


def write_obj(path: Path, vertices: NDArray[np.float64], polygons: list[list[int]]) -> None:
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in vertices.tolist()]
    lines += ["f " + " ".join(f"{i + 1}//1" for i in polygon) for polygon in polygons]
    path.write_text("# test\nvn 0 0 1\n" + "\n".join(lines) + "\n")


def write_off(path: Path, vertices: NDArray[np.float64], polygons: list[list[int]]) -> None:
    lines = ["OFF", "# comment", f"{len(vertices)} {len(polygons)} 0"]
    lines += [f"{x!r} {y!r} {z!r}" for x, y, z in vertices.tolist()]
    lines += [f"{len(p)} " + " ".join(map(str, p)) for p in polygons]
    path.write_text("\n".join(lines) + "\n")


def write_ply(
    path: Path, vertices: NDArray[np.float64], polygons: list[list[int]], encoding: str
) -> None:
    """PLY with an extra vertex colour and an extra face flag, ascii or binary (< or >)."""
    header = (
        f"ply\nformat {encoding} 1.0\ncomment test\nelement vertex {len(vertices)}\n"
        "property double x\nproperty double y\nproperty double z\nproperty uchar red\n"
        f"element face {len(polygons)}\nproperty list uchar int vertex_indices\n"
        "property uchar flag\nelement edge 1\nproperty int vertex1\nproperty int vertex2\n"
        "end_header\n"
    )
    if encoding == "ascii":
        body = "".join(f"{x!r} {y!r} {z!r} 7\n" for x, y, z in vertices.tolist())
        body += "".join(f"{len(p)} {' '.join(map(str, p))} 1\n" for p in polygons)
        path.write_text(header + body + "0 1\n")
        return
    e = "<" if encoding == "binary_little_endian" else ">"
    data = header.encode()
    data += b"".join(struct.pack(e + "dddB", *row, 7) for row in vertices.tolist())
    data += b"".join(struct.pack(e + f"B{len(p)}iB", len(p), *p, 1) for p in polygons)
    path.write_bytes(data + struct.pack(e + "ii", 0, 1))


def quads_of(n_u: int, n_v: int) -> list[list[int]]:
    """Quads of the grid used by :func:`grid_disk`."""
    return [
        [
            i + j * (n_u + 1),
            i + 1 + j * (n_u + 1),
            i + n_u + 2 + j * (n_u + 1),
            i + n_u + 1 + j * (n_u + 1),
        ]
        for j in range(n_v)
        for i in range(n_u)
    ]


def assert_same_triangles(read: Mesh, original: Mesh) -> None:
    (V, F), (V0, F0) = read, original
    assert F.shape == F0.shape
    np.testing.assert_allclose(V[F], V0[F0], rtol=0, atol=1e-12)


def check_message(error: pytest.ExceptionInfo[InputError], *words: str) -> None:
    message = str(error.value)
    assert "\n" not in message and message.strip() == message, message
    for word in words:
        assert word in message, f"{word!r} not in {message!r}"


# --- reading --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "extension, writer",
    [
        (".obj", lambda p, V, F: igl.writeOBJ(str(p), V, F)),
        (".off", lambda p, V, F: igl.writeOFF(str(p), V, F)),
        (
            ".ply",
            lambda p, V, F: igl.writePLY(str(p), V, F, encoding=igl.FileEncoding.Ascii),
        ),
        (
            ".ply",
            lambda p, V, F: igl.writePLY(str(p), V, F, encoding=igl.FileEncoding.Binary),
        ),
        (".stl", lambda p, V, F: igl.writeSTL(str(p), V, F, False)),
        (".stl", lambda p, V, F: igl.writeSTL(str(p), V, F, True)),
    ],
    ids=["obj", "off", "ply-ascii", "ply-binary", "stl-ascii", "stl-binary"],
)
def test_formats_round_trip_through_igl_writers(tmp_path, extension, writer):
    mesh = grid_disk()
    path = tmp_path / f"mesh{extension}"
    writer(path, *mesh)
    V, F = read_mesh(path)
    assert len(V) == len(mesh[0])  # STL corners merged back into shared vertices
    assert_same_triangles((V, F), mesh)


@pytest.mark.parametrize("encoding", ["ascii", "binary_little_endian", "binary_big_endian"])
def test_ply_with_quads_extra_properties_and_elements(tmp_path, encoding):
    V0, F0 = grid_disk(3, 2)
    quads = quads_of(3, 2)
    polygons = [quads[0][:3], *quads[1:]]  # one triangle, then quads: varying list lengths
    write_ply(tmp_path / "m.ply", V0, polygons, encoding)
    V, F = read_mesh(tmp_path / "m.ply")
    np.testing.assert_array_equal(V, V0)
    assert len(F) == 1 + 2 * (len(quads) - 1)
    write_ply(tmp_path / "q.ply", V0, quads, encoding)  # all quads: the vectorized path
    assert_same_triangles(read_mesh(tmp_path / "q.ply"), (V0, F0))


def test_obj_and_off_polygons_are_triangulated(tmp_path):
    V0, F0 = grid_disk(3, 2)
    write_obj(tmp_path / "q.obj", V0, quads_of(3, 2))
    write_off(tmp_path / "q.off", V0, quads_of(3, 2))
    for name in ("q.obj", "q.off"):
        assert_same_triangles(read_mesh(tmp_path / name), (V0, F0))
    # a hexagon with texture/normal indices and negative (relative) indices
    (tmp_path / "hex.obj").write_text(
        "o hex\n"
        + "".join(f"v {np.cos(a)} {np.sin(a)} 0\nvt 0 0\n" for a in np.linspace(0, 5, 6))
        + "usemtl x\nf -6/1 -5/2 -4/3 -3/4 -2/5 -1/6\n"
    )
    V, F = read_mesh(tmp_path / "hex.obj")
    assert F.tolist() == [[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 5]]


def test_extension_is_case_insensitive(tmp_path):
    mesh = grid_disk()
    igl.writeSTL(str(tmp_path / "MESH.STL"), *mesh, True)
    igl.writeOBJ(str(tmp_path / "Mesh.Obj"), *mesh)
    for name in ("MESH.STL", "Mesh.Obj"):
        target = load_target(tmp_path / name, 50.0)
        assert len(target.faces) == len(mesh[1])
        assert target.name == Path(name).stem


def test_stl_soup_is_merged_into_a_valid_disk(tmp_path):
    V0, F0 = grid_disk(6, 5)
    igl.writeSTL(str(tmp_path / "s.stl"), V0, F0, True)
    target = load_target(tmp_path / "s.stl", 120.0)
    assert len(target.vertices) == len(V0)
    assert target.notes == ()


def test_merge_coincident_vertices_keeps_first_positions():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 0, 1e-12], [0, 0, 0]], dtype=float)
    F = np.array([[0, 1, 2], [4, 3, 2]])
    V2, F2, merged = merge_coincident_vertices(V, F)
    assert merged == 2
    np.testing.assert_array_equal(V2, V[:3])
    assert F2.tolist() == [[0, 1, 2], [0, 1, 2]]


# --- good meshes -------------------------------------------------------------------------


def test_hemisphere_loads_and_is_scaled_and_placed():
    target = load_target(DATA / "hemisphere.obj", 150.0)
    assert isinstance(target, Target)
    assert target.name == "hemisphere"
    assert target.source.endswith("hemisphere.obj")
    assert target.faces.shape == (4000, 3) and target.vertices.shape == (2051, 3)
    low, high = target.vertices.min(axis=0), target.vertices.max(axis=0)
    assert (high - low).max() == pytest.approx(150.0, rel=1e-12)
    assert (low + high)[:2] == pytest.approx([0.0, 0.0], abs=1e-9)
    assert low[2] == pytest.approx(0.0, abs=1e-12)
    assert target.bbox_diagonal_mm == pytest.approx(float(np.linalg.norm(high - low)))
    assert target.notes == ()
    assert not target.vertices.flags.writeable and not target.faces.flags.writeable


def oriented_faces(faces: NDArray[np.int64]) -> NDArray[np.int64]:
    """Faces each turned to start at its smallest vertex (orientation kept), rows sorted."""
    turned = faces[
        np.arange(len(faces))[:, None], (np.argmin(faces, axis=1)[:, None] + np.arange(3)) % 3
    ]
    return turned[np.lexsort(turned.T[::-1])]


def test_file_orientation_is_kept():
    # Loading renumbers the vertices by position; the faces keep the file's orientation.
    V, F = read_mesh(DATA / "hemisphere.obj")
    target = load_target(DATA / "hemisphere.obj", 10.0)
    assert target.vertex_of_input is not None
    np.testing.assert_array_equal(target.faces, oriented_faces(target.vertex_of_input[F]))


@pytest.mark.parametrize("size", [0.5, 1.0, 3e4])
def test_size_is_exact(size):
    target = load_target(DATA / "hemisphere.obj", size)
    assert np.ptp(target.vertices, axis=0).max() == pytest.approx(size, rel=1e-12)


# --- repairs ---------------------------------------------------------------------------------


def test_unreferenced_vertices_are_dropped_with_a_note():
    V, F = grid_disk()
    V2 = np.vstack([[9.0, 9.0, 9.0], V, [np.nan, 0.0, 0.0]])  # a NaN vertex nobody uses is fine
    V3, F3, notes = validate_disk_mesh(V2, F + 1)
    np.testing.assert_array_equal(V3, V)
    np.testing.assert_array_equal(F3, F)
    assert notes == ("dropped 2 unreferenced vertices",)


def test_every_input_vertex_is_followed_through_the_repairs(tmp_path):
    V, F = grid_disk()
    # an unused vertex first, a copy of face 0's first vertex (which face 0 uses instead) last
    v = int(F[0, 0])
    V2 = np.vstack([[9.0, 9.0, 9.0], V, V[v]])
    F2 = F + 1
    copy = len(V2) - 1
    F2[0, 0] = copy
    lines = [f"v {float(x)!r} {float(y)!r} {float(z)!r}" for x, y, z in V2]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in F2]
    (tmp_path / "m.obj").write_text("\n".join(lines) + "\n")
    target = load_target(tmp_path / "m.obj", 100.0)
    where = target.vertex_of_input
    assert where is not None and where.shape == (len(V2),)
    assert where[0] == -1  # dropped
    np.testing.assert_array_equal(np.sort(where[1 : len(V) + 1]), np.arange(len(V)))
    assert where[copy] == where[1 + v]  # merged into the vertex it copies
    np.testing.assert_array_equal(target.faces, oriented_faces(where[F + 1]))


def test_zero_area_faces_on_the_boundary_are_removed():
    V, F = grid_disk()
    # a sliver hanging on boundary edge 0 -> 1: midpoint vertex, opposite orientation
    midpoint = len(V)
    V2 = np.vstack([V, (V[0] + V[1]) / 2.0])
    repeated = [2, 2, 3]
    F2 = np.vstack([F, [[1, 0, midpoint], repeated]])
    V3, F3, notes = validate_disk_mesh(V2, F2, repair=True)
    np.testing.assert_array_equal(F3, F)
    assert len(V3) == len(V)
    assert notes == ("removed 2 zero-area faces", "dropped 1 vertex used only by removed faces")


def test_duplicated_faces_are_removed():
    V, F = grid_disk()
    _, F2, notes = validate_disk_mesh(V, np.vstack([F, F[3:5]]))
    np.testing.assert_array_equal(F2, F)
    assert notes == ("removed 2 duplicated faces",)


def test_zero_area_faces_are_refused_unless_repairs_are_asked_for(tmp_path):
    V, F = grid_disk()
    midpoint = len(V)
    V2 = np.vstack([V, (V[0] + V[1]) / 2.0])
    F2 = np.vstack([F, [[1, 0, midpoint], [2, 2, 3]]])
    with pytest.raises(InputError) as error:
        validate_disk_mesh(V2, F2)
    # the first one is the sliver on edge 0 -> 1; its centre is that edge's midpoint
    centre = ", ".join(f"{c:.6g}" for c in (V[0] + V[1]) / 2.0)
    check_message(error, "2 degenerate (zero-area) faces", f"the first at ({centre})", "--repair")
    lines = [f"v {float(x)!r} {float(y)!r} {float(z)!r}" for x, y, z in V2]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in F2]
    (tmp_path / "m.obj").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError) as error:
        load_target(tmp_path / "m.obj", 100.0)
    check_message(error, "m.obj: 2 degenerate (zero-area) faces", "--repair")
    repaired = load_target(tmp_path / "m.obj", 100.0, repair=True)
    assert repaired.vertex_of_input is not None
    np.testing.assert_array_equal(repaired.faces, oriented_faces(repaired.vertex_of_input[F]))
    assert repaired.notes[0] == "removed 2 zero-area faces"


def test_interior_zero_area_face_is_refused():
    with pytest.raises(InputError) as error:
        validate_disk_mesh(*split_edge_with_sliver(grid_disk()), repair=True)
    check_message(error, "removing 1 zero-area face", "not a disk", "2 boundary loops")
    # without --repair the refusal does not offer a repair that would fail
    with pytest.raises(InputError) as error:
        validate_disk_mesh(*split_edge_with_sliver(grid_disk()))
    check_message(error, "1 degenerate (zero-area) face", "not a disk", "mend the mesh")
    assert "--repair" not in str(error.value)


def test_zero_area_face_in_a_closed_surface_is_refused():
    with pytest.raises(InputError) as error:
        validate_disk_mesh(*split_edge_with_sliver(octahedron()), repair=True)
    check_message(error, "closed", "cut it open")


def test_sliver_construction_is_valid_apart_from_the_sliver():
    V, F = split_edge_with_sliver(grid_disk())
    # moving the midpoint off the edge makes the sliver a real triangle: a valid disk
    V = V.copy()
    V[-1, 2] += 0.5
    _, F2, notes = validate_disk_mesh(V, F)
    assert notes == () and len(F2) == len(F)


# --- defects: one InputError each, one line, naming the defect and the fix ----------------


def test_missing_file(tmp_path):
    with pytest.raises(InputError) as error:
        load_target(tmp_path / "nothing.obj", 100.0)
    check_message(error, "nothing.obj does not exist", "check the path")


def test_unknown_extension(tmp_path):
    (tmp_path / "mesh.xyz").write_text("1 2 3\n")
    with pytest.raises(InputError) as error:
        load_target(tmp_path / "mesh.xyz", 100.0)
    check_message(error, "unsupported mesh file extension '.xyz'", ".obj, .off, .ply, .stl")


def test_unknown_target_name():
    with pytest.raises(InputError) as error:
        load_target("no-such-shape", 100.0)
    check_message(error, "unknown target 'no-such-shape'", "saddle", "drawstring targets")


@pytest.mark.parametrize("extension", [".obj", ".off", ".ply", ".stl"])
def test_empty_file(tmp_path, extension):
    (tmp_path / f"e{extension}").write_bytes(b"")
    with pytest.raises(InputError) as error:
        load_target(tmp_path / f"e{extension}", 100.0)
    check_message(error, "empty")


def test_file_without_faces(tmp_path):
    (tmp_path / "points.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    with pytest.raises(InputError) as error:
        load_target(tmp_path / "points.obj", 100.0)
    check_message(error, "points.obj", "no faces")


@pytest.mark.parametrize(
    "name, text, words",
    [
        ("bad.off", "hello\n", ["first line should be OFF"]),
        ("bad.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n", ["line 4", "not a vertex index"]),
        ("bad.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", ["start at 1"]),
        ("bad.obj", "v 0 0\n", ["line 1", "three coordinates", "export it again"]),
        ("bad.obj", "v 0 zero 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", ["'zero' is not a number"]),
        ("bad.obj", "# c\nv 0 0 0\nv 1 1 zz\nf 1 2 3\n", ["line 3:", "'zz' is not a number"]),
        ("bad.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n", ["truncated"]),
        (
            "bad.off",
            "OFF\n4 1 0\n0 0 0\n1 0 0\n0 1 0\n1 1 0\n3 0 1 2\n3 1 3 2\n",
            ["1 more lines", "counts are wrong"],
        ),
        ("bad.ply", "ply\nformat ascii 1.0\nelement vertex 3\nend\n", ["not a PLY file"]),
        ("bad.stl", "not an stl\n", ["neither binary STL"]),
        (
            "bad.stl",
            "solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n"
            "vertex 0 1 0x\nendloop\nendfacet\nendsolid t\n",
            ["line 6:", "'0x' is not a number"],
        ),
    ],
)
def test_unparsable_files(tmp_path, name, text, words):
    (tmp_path / name).write_text(text)
    with pytest.raises(InputError) as error:
        read_mesh(tmp_path / name)
    check_message(error, name, *words)


def test_nan_vertex(tmp_path):
    (tmp_path / "nan.obj").write_text("v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(InputError) as error:
        load_target(tmp_path / "nan.obj", 100.0)
    check_message(error, "non-finite (NaN or infinite) coordinates at 1 vertex")
    V, F = grid_disk()
    V = V.copy()
    V[[2, 5], 1] = [np.inf, -np.inf]
    with pytest.raises(InputError) as error:
        validate_disk_mesh(V, F)
    check_message(error, "non-finite", "2 vertices")


@pytest.mark.parametrize("exponent", [996, -996, -1040])
def test_coordinates_near_the_ends_of_the_float_range_give_the_same_target(tmp_path, exponent):
    # near 1e300 squared distances overflow and near 1e-300 areas underflow; a power of two
    # scales the mesh exactly before anything is computed (2^-1040 is subnormal)
    V, F = grid_disk(6, 5)
    write_obj(tmp_path / "plain.obj", V, F.tolist())
    write_obj(tmp_path / "far.obj", np.ldexp(V, exponent), F.tolist())
    plain = load_target(tmp_path / "plain.obj", 100.0)
    far = load_target(tmp_path / "far.obj", 100.0)
    np.testing.assert_array_equal(far.vertices, plain.vertices)
    np.testing.assert_array_equal(far.faces, plain.faces)
    assert any("scaled by 2^" in note for note in far.notes) and not plain.notes


def test_face_indices_out_of_range(tmp_path):
    (tmp_path / "oor.off").write_text("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n")
    with pytest.raises(InputError) as error:
        load_target(tmp_path / "oor.off", 100.0)
    check_message(error, "face indices out of range in 1 face", "re-export")
    V, F = grid_disk()
    with pytest.raises(InputError) as error:
        validate_disk_mesh(V, np.vstack([F, [[0, 1, -1]]]))
    check_message(error, "out of range")


def test_two_disjoint_triangles():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 0, 0], [6, 0, 0], [5, 1, 0]], float)
    with pytest.raises(InputError) as error:
        validate_disk_mesh(V, np.array([[0, 1, 2], [3, 4, 5]]))
    check_message(error, "2 separate pieces", "keep one patch")


def test_teapot_has_several_pieces():
    with pytest.raises(InputError) as error:
        load_target(DATA / "teapot.obj", 100.0)
    # four patches by edges, two of them touching at a vertex: three pieces
    check_message(error, "teapot.obj: ", "3 separate pieces", "keep one patch")


def test_two_patches_touching_at_one_vertex_are_a_bow_tie_not_two_pieces():
    # two triangles sharing vertex 0 only: one piece by vertices, two by edges
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [-1, 0, 0], [-1, -1, 0]], float)
    with pytest.raises(InputError) as error:
        validate_disk_mesh(V, np.array([[0, 1, 2], [0, 3, 4]]))
    check_message(error, "not vertex-manifold", "1 vertex", "bow-tie")


def test_a_boundary_of_three_vertices_cannot_take_four_corners():
    # a triangle fan round one inner vertex: a disk whose boundary is a triangle
    V = np.array([[0, 0, 0.1], [1, 0, 0], [-0.5, 0.8, 0], [-0.5, -0.8, 0]], float)
    with pytest.raises(InputError) as error:
        validate_disk_mesh(V, np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1]]))
    check_message(error, "only 3 vertices", "4 corners", "subdivide")
    with pytest.raises(InputError) as error:
        validate_disk_mesh(V[1:], np.array([[0, 1, 2]]))
    check_message(error, "only 3 vertices")


def test_non_manifold_fan():
    V = np.array([[0, 0, 0], [0, 0, 1], [1, 0, 0], [-1, 0, 0], [0, 1, 0]], float)
    faces = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])  # three faces on edge 0-1
    with pytest.raises(InputError) as error:
        validate_disk_mesh(V, faces)
    check_message(error, "not edge-manifold", "1 edge shared by more than two faces")


def test_pinched_vertex():
    # a strip bent round until its two ends share one inner vertex (not merged: distinct ids
    # elsewhere), so the fans at that vertex touch only there
    V, F = ring(6, closed=False)
    n_cols = 7
    F = np.where(F == n_cols - 1, 0, F)  # glue the last inner vertex onto the first
    V, F = _drop_unused(V, F)
    with pytest.raises(InputError) as error:
        validate_disk_mesh(V, F)
    check_message(error, "not vertex-manifold", "1 vertex", "bow-tie")


def _drop_unused(V: NDArray[np.float64], F: NDArray[np.int64]) -> Mesh:
    used = np.unique(F)
    remap = np.full(len(V), -1)
    remap[used] = np.arange(len(used))
    return V[used], remap[F]


def test_closed_octahedron():
    with pytest.raises(InputError) as error:
        validate_disk_mesh(*octahedron())
    check_message(error, "surface is closed (no boundary)", "cut it open into a disk-like patch")


def test_closed_torus_names_the_genus():
    with pytest.raises(InputError) as error:
        validate_disk_mesh(*torus())
    check_message(error, "closed (no boundary, genus 1)")


def test_annulus_has_a_hole():
    with pytest.raises(InputError) as error:
        validate_disk_mesh(*ring(8, 2))
    check_message(error, "2 boundary loops (1 hole)", "fill all holes but the outer boundary")


def test_punctured_torus_has_genus_one():
    V, F = torus()
    with pytest.raises(InputError) as error:
        validate_disk_mesh(V, F[2:])  # remove one quad
    check_message(error, "genus 1", "Euler characteristic -1", "1 handle", "disk")


def test_torus_with_two_holes():
    V, F = torus(10, 6)
    with pytest.raises(InputError) as error:
        validate_disk_mesh(V, np.delete(F, [0, 1, 30, 31], axis=0))
    check_message(error, "2 boundary loops and genus 1", "fill all holes", "cut the handles")


def test_flipped_face_is_refused_not_fixed():
    V, F = grid_disk()
    F = F.copy()
    F[5] = F[5, [0, 2, 1]]
    with pytest.raises(InputError) as error:
        validate_disk_mesh(V, F)
    check_message(error, "inconsistently oriented", f"1 of {len(F)} faces are flipped", "re-orient")


def test_many_flipped_faces_are_reported_before_holes():
    # like bad/inverted_triangles.obj: about 40 % of the faces flipped, and holes as well
    V, F = ring(10, 3)
    F = F.copy()
    flip = np.arange(len(F)) % 5 < 2
    F[flip] = F[flip][:, [0, 2, 1]]
    with pytest.raises(InputError) as error:
        validate_disk_mesh(V, F)
    check_message(error, "inverted triangles", f"{int(flip.sum())} of {len(F)} faces")


def test_mobius_strip_is_not_orientable():
    with pytest.raises(InputError) as error:
        validate_disk_mesh(*mobius())
    check_message(error, "not orientable")


def test_all_faces_degenerate():
    V = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], float)
    with pytest.raises(InputError) as error:
        validate_disk_mesh(V, np.array([[0, 1, 2]]))
    check_message(error, "zero area")


def test_bad_array_shapes():
    # the mesh readers always hand over (n, 3) and (m, 3) arrays: other shapes are a bug
    with pytest.raises(InternalError):
        validate_disk_mesh(np.zeros((3, 2)), np.array([[0, 1, 2]]))
    with pytest.raises(InternalError):
        validate_disk_mesh(np.eye(3), np.array([[0, 1, 2, 0]]))
    with pytest.raises(InputError) as error:
        validate_disk_mesh(np.eye(3), np.zeros((0, 3), dtype=int))
    check_message(error, "no faces")


@pytest.mark.parametrize("size", [0, -5.0, float("nan"), float("inf"), "100", True, None])
def test_bad_size(size):
    with pytest.raises(InputError) as error:
        load_target(DATA / "hemisphere.obj", size)  # type: ignore[arg-type]
    check_message(error, "--size must be a positive number of millimetres")


@pytest.mark.parametrize("resolution", [0, 5, 10**9, 100.5, "many"])
def test_bad_resolution(resolution):
    with pytest.raises(InputError) as error:
        load_target("saddle", 100.0, resolution)  # type: ignore[arg-type]
    check_message(error, "resolution")


def test_directory_is_not_a_mesh(tmp_path):
    (tmp_path / "dir.obj").mkdir()
    with pytest.raises(InputError) as error:
        read_mesh(tmp_path / "dir.obj")
    check_message(error, "not a file")


def test_a_renumbered_mesh_file_loads_to_the_same_arrays(tmp_path: Path) -> None:
    # The same surface with its vertices renumbered, its faces shuffled and each face's
    # vertices rotated (another exporter) loads to identical vertices and faces, so every later
    # step, which sums and breaks ties in that order, sees the same input; each file's own
    # vertex ids still lead to the right loaded vertex (as --corners and target.corners use them).
    vertices, faces = grid_disk(7, 5)
    rng = np.random.default_rng(3)
    new_id = rng.permutation(len(vertices))
    moved = np.empty_like(vertices)
    moved[new_id] = vertices
    shuffled = np.roll(new_id[faces], 1, axis=1)[rng.permutation(len(faces))]
    write_obj(tmp_path / "a.obj", vertices, faces.tolist())
    write_obj(tmp_path / "b.obj", moved, shuffled.tolist())
    a = load_target(tmp_path / "a.obj", size_mm=100.0)
    b = load_target(tmp_path / "b.obj", size_mm=100.0)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)
    assert a.vertex_of_input is not None and b.vertex_of_input is not None
    np.testing.assert_array_equal(b.vertex_of_input[new_id], a.vertex_of_input)
    # orientation kept: the faces' normals still point the way the file's did (+z here)
    e1 = a.vertices[a.faces[:, 1]] - a.vertices[a.faces[:, 0]]
    e2 = a.vertices[a.faces[:, 2]] - a.vertices[a.faces[:, 0]]
    assert np.all(np.cross(e1, e2)[:, 2] > 0)
