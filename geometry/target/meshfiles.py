"""Mesh files: read OBJ, OFF, PLY (ascii or binary) and STL (ascii or binary) into vertex
and triangle arrays, and merge coincident vertices.  No topology checks are made here
(:mod:`drawstring.geometry.target.surface` checks and repairs what is read)."""

from __future__ import annotations

import logging
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from drawstring.geometry.core.errors import InputError
from drawstring.geometry.core.tolerances import COINCIDENT_VERTEX_REL_DIST
from drawstring.geometry.core.types import FloatArray, IntArray

logger = logging.getLogger(__name__)

__all__ = ["SUPPORTED_EXTENSIONS", "merge_coincident_vertices", "read_mesh"]

#: File name extensions :func:`read_mesh` understands (compared case-insensitively).
SUPPORTED_EXTENSIONS = (".obj", ".off", ".ply", ".stl")


def read_mesh(path: str | os.PathLike[str]) -> tuple[FloatArray, IntArray]:
    """Read a triangle mesh from an OBJ, OFF, PLY (ascii or binary) or STL (ascii or binary).

    Polygons are fan-triangulated. STL corners are merged into shared vertices (distance below
    ``COINCIDENT_VERTEX_REL_DIST`` times the bounding-box diagonal). No other checks are made.

    Parameters
    ----------
    path : str or path
        The file; its extension (any case) picks the format.

    Returns
    -------
    V : (n, 3) float
        Vertex positions as stored (may hold NaN; :func:`validate_disk_mesh` checks).
    F : (m, 3) int
        Triangles; ``m`` may be 0 and indices may be out of range (checked later).

    Raises
    ------
    InputError
        Unknown extension, missing or empty file, or a file that does not parse.
    """
    path = Path(path)
    extension = path.suffix.lower()
    if path.is_dir():
        raise InputError(f"{path} is a folder, not a file; give a mesh file or a built-in name")
    if extension not in SUPPORTED_EXTENSIONS:
        shown = f"'{path.suffix}'" if path.suffix else "(no extension)"
        raise InputError(
            f"unsupported mesh file extension {shown} for {path}; use one of "
            f"{', '.join(SUPPORTED_EXTENSIONS)}"
        )
    if not path.exists():
        raise InputError(f"mesh file {path} does not exist; check the path")
    if not path.is_file():
        raise InputError(f"{path} is not a file; give a mesh file or a built-in target name")
    data = path.read_bytes()
    if not data.strip():
        raise InputError(f"mesh file is empty: {path}; export the surface again")
    readers = {".obj": _read_obj, ".off": _read_off, ".ply": _read_ply, ".stl": _read_stl}
    try:
        vertices, faces = readers[extension](data)
    except InputError as error:
        fix = "" if ";" in str(error) else "; the file is damaged or not a mesh, export it again"
        raise InputError(f"{path}: {error}{fix}") from None
    except (ValueError, IndexError, KeyError, UnicodeDecodeError) as error:
        detail = " ".join(str(error).split())
        raise InputError(
            f"{path}: not a valid {extension[1:].upper()} file ({detail}); re-export the mesh"
        ) from None
    if extension == ".stl" and len(vertices) and np.isfinite(vertices).all():
        vertices, faces, merged = merge_coincident_vertices(vertices, faces)
        logger.debug("%s: merged %d STL corners into shared vertices", path, merged)
    return vertices, faces


def _fan_triangulate(polygons: list[list[int]]) -> IntArray:
    """Triangles ``(p0, p[i], p[i+1])`` of each polygon, shape (m, 3)."""
    if all(len(polygon) == 3 for polygon in polygons):
        return np.array(polygons, dtype=np.int64).reshape(-1, 3)
    triangles = [
        (polygon[0], polygon[i], polygon[i + 1])
        for polygon in polygons
        for i in range(1, len(polygon) - 1)
    ]
    return np.array(triangles, dtype=np.int64).reshape(-1, 3)


def _to_vertex_array(
    rows: list[list[str]], what: str, lines: list[int] | None = None
) -> FloatArray:
    """Convert rows of three coordinate strings to an (n, 3) float array (``lines``: the
    file line of each row, for the message)."""
    try:
        return np.array(rows, dtype=np.float64).reshape(-1, 3)
    except ValueError:
        for index, row in enumerate(rows):
            for token in row:
                try:
                    float(token)
                except ValueError:
                    at = f"line {lines[index]}: " if lines is not None else ""
                    raise InputError(
                        f"{at}{what} coordinate '{token[:20]}' is not a number; fix the file"
                    ) from None
        raise


def _read_obj(data: bytes) -> tuple[FloatArray, IntArray]:
    """Parse Wavefront OBJ text: ``v`` and ``f`` statements; everything else is ignored."""
    text = data.decode("utf-8", errors="replace")
    vertex_rows: list[list[str]] = []
    vertex_lines: list[int] = []
    polygons: list[list[int]] = []
    for line_number, line in enumerate(text.splitlines(), start=1):
        parts = line.split()
        if not parts:
            continue
        keyword = parts[0]
        if keyword == "v":
            if len(parts) < 4:
                raise InputError(f"line {line_number}: a vertex needs three coordinates")
            vertex_rows.append(parts[1:4])
            vertex_lines.append(line_number)
        elif keyword == "f":
            polygon = []
            for token in parts[1:]:
                try:
                    index = int(token.split("/", 1)[0])
                except ValueError:
                    raise InputError(
                        f"line {line_number}: face corner '{token[:20]}' is not a vertex index"
                    ) from None
                if index == 0:
                    raise InputError(f"line {line_number}: OBJ vertex indices start at 1, not 0")
                polygon.append(index - 1 if index > 0 else len(vertex_rows) + index)
            if len(polygon) < 3:
                raise InputError(f"line {line_number}: a face needs at least three vertices")
            polygons.append(polygon)
    return _to_vertex_array(vertex_rows, "vertex", vertex_lines), _fan_triangulate(polygons)


def _read_off(data: bytes) -> tuple[FloatArray, IntArray]:
    """Parse ASCII OFF (also COFF, NOFF, CNOFF, STOFF): one vertex or face per line."""
    text = data.decode("utf-8", errors="replace")
    lines = [line.split("#", 1)[0].split() for line in text.splitlines()]
    lines = [line for line in lines if line]
    header = lines[0]
    keyword = header[0].upper()
    if not keyword.endswith("OFF") or any(c not in "STCN" for c in keyword[:-3]):
        raise InputError(f"first line should be OFF, not '{keyword[:20]}'")
    if len(header) > 1 and header[1].upper() == "BINARY":
        raise InputError("binary OFF is not supported; save it as ASCII OFF, OBJ, PLY or STL")
    counts_line = header[1:] if len(header) >= 3 else lines[1]
    body = lines[1:] if len(header) >= 3 else lines[2:]
    n_vertices, n_faces = int(counts_line[0]), int(counts_line[1])
    if len(body) < n_vertices + n_faces:
        raise InputError(
            f"header promises {n_vertices} vertices and {n_faces} faces but the file is "
            "shorter; it is truncated, re-export it"
        )
    if len(body) > n_vertices + n_faces:
        # counts too small would leave faces (or vertices read as faces) out unnoticed
        raise InputError(
            f"header promises {n_vertices} vertices and {n_faces} faces but the file has "
            f"{len(body) - n_vertices - n_faces} more lines; its counts are wrong, re-export it"
        )
    vertices = _to_vertex_array([row[:3] for row in body[:n_vertices]], "vertex")
    polygons = []
    for row in body[n_vertices : n_vertices + n_faces]:
        corner_count = int(row[0])
        if corner_count < 3 or len(row) < corner_count + 1:
            raise InputError("a face line needs a count of at least 3 and that many indices")
        polygons.append([int(token) for token in row[1 : corner_count + 1]])
    return vertices, _fan_triangulate(polygons)


_PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}


@dataclass(frozen=True)
class _PlyProperty:
    """One PLY property: a scalar (``count_type`` None) or a list."""

    name: str
    value_type: str
    count_type: str | None


@dataclass(frozen=True)
class _PlyElement:
    name: str
    count: int
    properties: tuple[_PlyProperty, ...]


def _parse_ply_header(data: bytes) -> tuple[str, list[_PlyElement], int]:
    """Return (format, elements, offset of the body) of a PLY file."""
    match = re.search(rb"end_header[ \t]*\r?\n", data)
    if not data.startswith(b"ply") or match is None:
        raise InputError("not a PLY file (no 'ply' magic or no 'end_header')")
    elements: list[_PlyElement] = []
    file_format = ""
    pending: list[tuple[str, int, list[_PlyProperty]]] = []
    for raw in data[: match.start()].decode("ascii", errors="replace").splitlines()[1:]:
        words = raw.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            file_format = words[1]
        elif words[0] == "element":
            pending.append((words[1], int(words[2]), []))
        elif words[0] == "property" and pending:
            if words[1] == "list":
                prop = _PlyProperty(words[4], _PLY_TYPES[words[3]], _PLY_TYPES[words[2]])
            else:
                prop = _PlyProperty(words[2], _PLY_TYPES[words[1]], None)
            pending[-1][2].append(prop)
    elements = [_PlyElement(name, count, tuple(props)) for name, count, props in pending]
    if file_format not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise InputError(f"unknown PLY format '{file_format}'")
    return file_format, elements, match.end()


def _read_ply(data: bytes) -> tuple[FloatArray, IntArray]:
    """Parse PLY (ascii, binary little or big endian): vertex x, y, z and face index lists."""
    file_format, elements, offset = _parse_ply_header(data)
    names = [element.name for element in elements]
    if "vertex" not in names:
        raise InputError("PLY file has no vertex element")
    columns: dict[str, dict[str, FloatArray]] = {}
    lists: dict[str, list[list[int]]] = {}
    if file_format == "ascii":
        tokens = data[offset:].split()
        position = 0
        for element in elements:
            position = _read_ply_ascii_element(element, tokens, position, columns, lists)
    else:
        endian = "<" if file_format == "binary_little_endian" else ">"
        for element in elements:
            offset = _read_ply_binary_element(element, data, offset, endian, columns, lists)
    vertex_columns = columns["vertex"]
    if not all(axis in vertex_columns for axis in "xyz"):
        raise InputError("PLY vertex element lacks x, y or z")
    vertices = np.column_stack([vertex_columns[axis] for axis in "xyz"]).astype(np.float64)
    polygons = lists.get("face", [])
    return vertices, _fan_triangulate(polygons)


def _face_list_name(element: _PlyElement) -> str | None:
    """Name of the face element's index list property, if any."""
    list_names = [prop.name for prop in element.properties if prop.count_type is not None]
    for preferred in ("vertex_indices", "vertex_index"):
        if preferred in list_names:
            return preferred
    return list_names[0] if list_names else None


def _read_ply_ascii_element(
    element: _PlyElement,
    tokens: list[bytes],
    position: int,
    columns: dict[str, dict[str, FloatArray]],
    lists: dict[str, list[list[int]]],
) -> int:
    """Consume one ASCII element from the token stream; return the new position."""
    props = element.properties
    if all(prop.count_type is None for prop in props):
        size = element.count * len(props)
        if position + size > len(tokens):
            raise InputError(f"PLY {element.name} data is truncated")
        table = np.array(tokens[position : position + size], dtype=np.float64)
        table = table.reshape(element.count, len(props))
        columns[element.name] = {prop.name: table[:, k] for k, prop in enumerate(props)}
        return position + size
    wanted = _face_list_name(element) if element.name == "face" else None
    rows: list[list[int]] = []
    for _ in range(element.count):
        for prop in props:
            if prop.count_type is None:
                position += 1
                continue
            length = int(tokens[position])
            values = tokens[position + 1 : position + 1 + length]
            if len(values) < length:
                raise InputError(f"PLY {element.name} data is truncated")
            if prop.name == wanted:
                rows.append([int(value) for value in values])
            position += 1 + length
    if wanted is not None:
        lists[element.name] = rows
    return position


def _read_ply_binary_element(
    element: _PlyElement,
    data: bytes,
    offset: int,
    endian: str,
    columns: dict[str, dict[str, FloatArray]],
    lists: dict[str, list[list[int]]],
) -> int:
    """Decode one binary element starting at ``offset``; return the offset after it."""
    props = element.properties
    if all(prop.count_type is None for prop in props):
        dtype = np.dtype([(prop.name, endian + prop.value_type) for prop in props])
        if offset + dtype.itemsize * element.count > len(data):
            raise InputError(f"PLY {element.name} data is truncated")
        table = np.frombuffer(data, dtype=dtype, count=element.count, offset=offset)
        columns[element.name] = {prop.name: table[prop.name].astype(np.float64) for prop in props}
        return offset + dtype.itemsize * element.count
    wanted = _face_list_name(element) if element.name == "face" else None
    fast = _ply_binary_constant_lists(element, data, offset, endian, wanted)
    if fast is not None:
        rows, offset = fast
    else:
        rows, offset = _ply_binary_varying_lists(element, data, offset, endian, wanted)
    if wanted is not None:
        lists[element.name] = rows
    return offset


def _ply_binary_constant_lists(
    element: _PlyElement, data: bytes, offset: int, endian: str, wanted: str | None
) -> tuple[list[list[int]], int] | None:
    """Vectorized decoding when every list of the element has the first row's length.

    Returns None when that guess does not hold (then decode row by row).
    """
    if element.count == 0:
        return [], offset
    fields: list[tuple[str, str] | tuple[str, str, tuple[int]]] = []
    lengths: dict[int, int] = {}
    cursor = offset
    for k, prop in enumerate(element.properties):
        if prop.count_type is None:
            fields.append((f"p{k}", endian + prop.value_type))
            cursor += np.dtype(prop.value_type).itemsize
            continue
        count_dtype = np.dtype(endian + prop.count_type)
        if cursor + count_dtype.itemsize > len(data):
            raise InputError(f"PLY {element.name} data is truncated")
        lengths[k] = int(np.frombuffer(data, dtype=count_dtype, count=1, offset=cursor)[0])
        fields.append((f"n{k}", endian + prop.count_type))
        fields.append((f"p{k}", endian + prop.value_type, (lengths[k],)))
        cursor += count_dtype.itemsize + lengths[k] * np.dtype(prop.value_type).itemsize
    dtype = np.dtype(fields)
    if offset + dtype.itemsize * element.count > len(data):
        return None
    table = np.frombuffer(data, dtype=dtype, count=element.count, offset=offset)
    if any(np.any(table[f"n{k}"] != length) for k, length in lengths.items()):
        return None
    rows: list[list[int]] = []
    for k, prop in enumerate(element.properties):
        if prop.name == wanted and k in lengths:
            values = table[f"p{k}"].reshape(element.count, lengths[k])
            rows = values.astype(np.int64).tolist()
    return rows, offset + dtype.itemsize * element.count


def _ply_binary_varying_lists(
    element: _PlyElement, data: bytes, offset: int, endian: str, wanted: str | None
) -> tuple[list[list[int]], int]:
    """Row-by-row decoding for lists of varying length (e.g. mixed triangles and quads)."""
    rows: list[list[int]] = []
    for _ in range(element.count):
        for prop in element.properties:
            value_dtype = np.dtype(endian + prop.value_type)
            if prop.count_type is None:
                offset += value_dtype.itemsize
                continue
            count_dtype = np.dtype(endian + prop.count_type)
            length = int(np.frombuffer(data, dtype=count_dtype, count=1, offset=offset)[0])
            offset += count_dtype.itemsize
            if offset + length * value_dtype.itemsize > len(data):
                raise InputError(f"PLY {element.name} data is truncated")
            if prop.name == wanted:
                values = np.frombuffer(data, dtype=value_dtype, count=length, offset=offset)
                rows.append(values.astype(np.int64).tolist())
            offset += length * value_dtype.itemsize
    return rows, offset


_STL_BINARY_DTYPE = np.dtype(
    [("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attribute", "<u2")]
)
_STL_VERTEX = re.compile(rb"vertex\s+(\S+)\s+(\S+)\s+(\S+)")


def _read_stl(data: bytes) -> tuple[FloatArray, IntArray]:
    """Parse STL, binary (detected by its exact size) or ASCII; one vertex per corner."""
    if len(data) >= 84:
        n_triangles = int(np.frombuffer(data, dtype="<u4", count=1, offset=80)[0])
        if len(data) == 84 + 50 * n_triangles:
            table = np.frombuffer(data, dtype=_STL_BINARY_DTYPE, count=n_triangles, offset=84)
            vertices = table["corners"].reshape(-1, 3).astype(np.float64)
            return vertices, np.arange(3 * n_triangles, dtype=np.int64).reshape(-1, 3)
    if not data.lstrip().lower().startswith(b"solid"):
        raise InputError(
            "neither binary STL (its size does not match its triangle count: truncated?) nor "
            "ASCII STL (no 'solid' header); export the mesh again"
        )
    coordinates = _STL_VERTEX.findall(data)
    if len(coordinates) % 3:
        raise InputError("ASCII STL facets must have exactly three vertices")
    rows = [[token.decode("ascii", errors="replace") for token in row] for row in coordinates]
    try:
        vertices = _to_vertex_array(rows, "vertex")
    except InputError:
        # again, naming the line (counted only when something is wrong)
        lines, line, seen = [], 1, 0
        for match in _STL_VERTEX.finditer(data):
            line += data.count(b"\n", seen, match.start())
            seen = match.start()
            lines.append(line)
        vertices = _to_vertex_array(rows, "vertex", lines)
    return vertices, np.arange(len(vertices), dtype=np.int64).reshape(-1, 3)


def merge_coincident_vertices(
    vertices: FloatArray,
    faces: IntArray,
    rel_distance: float = COINCIDENT_VERTEX_REL_DIST,
) -> tuple[FloatArray, IntArray, int]:
    """Merge vertices closer than ``rel_distance`` times the bounding-box diagonal.

    Clusters are the connected components of the "closer than" relation; each keeps the
    position of its lowest-index vertex. Surviving vertices keep their relative order.

    Parameters
    ----------
    vertices : (n, 3) float, finite
    faces : (m, 3) int, indices into ``vertices``
    rel_distance : float
        Merge distance as a fraction of the bounding-box diagonal.

    Returns
    -------
    V : (k, 3) float
    F : (m, 3) int
        Re-indexed; faces may now repeat a vertex (degenerate).
    merged : int
        ``n - k``.
    """
    keep, remap = coincident_remap(vertices, rel_distance)
    if remap is None:
        return vertices, faces, 0
    return vertices[keep], remap[faces], len(vertices) - len(keep)


def coincident_remap(
    vertices: FloatArray, rel_distance: float = COINCIDENT_VERTEX_REL_DIST
) -> tuple[IntArray, IntArray | None]:
    """The vertices :func:`merge_coincident_vertices` keeps ``(k,)`` and the new index of
    every vertex ``(n,)`` (None when none merge)."""
    n = len(vertices)
    if n == 0:
        return np.arange(0), None
    diagonal = float(np.linalg.norm(np.ptp(vertices, axis=0)))
    pairs = cKDTree(vertices).query_pairs(rel_distance * diagonal, output_type="ndarray")
    if len(pairs) == 0:
        return np.arange(n), None
    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    # representative = first vertex of each cluster, in order of first appearance
    _, first = np.unique(labels, return_index=True)
    keep = np.sort(first)
    new_index_of_label = np.empty(labels.max() + 1, dtype=np.int64)
    new_index_of_label[labels[keep]] = np.arange(len(keep))
    return keep, new_index_of_label[labels]


#: Largest coordinate magnitudes used as read; outside them the mesh is scaled first.
SAFE_COORDINATE_RANGE = (1e-100, 1e100)


def exact_rescale(vertices: FloatArray) -> tuple[FloatArray, str | None]:
    """Vertices scaled by a power of two when their magnitude lies near the ends of the float
    range, and a note saying so (None when left as read).

    Products and squared distances of coordinates near 1e300 overflow (scipy's k-d tree in
    :func:`coincident_remap` raises on it) and those of
    coordinates near 1e-300 underflow to zero (every face would seem to have zero area).  A
    power of two scales every float exactly, and the mesh is scaled to ``--size`` afterwards
    anyway, so the design is the one of the same mesh at a sensible scale.
    """
    largest = float(np.abs(vertices).max()) if vertices.size else 0.0
    low, high = SAFE_COORDINATE_RANGE
    if largest == 0.0 or low <= largest <= high:
        return vertices, None
    exponent = -math.frexp(largest)[1]  # largest * 2**exponent lies in [0.5, 1)
    return np.ldexp(vertices, exponent), (
        f"coordinates as large as {largest:.3g} scaled by 2^{exponent} before any computation "
        "(exact; the mesh is scaled to --size anyway)"
    )
