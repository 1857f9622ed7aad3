"""Target surfaces: read a mesh file or build a built-in one, check it is a disk, scale it.

The pipeline needs one connected, edge- and vertex-manifold, consistently oriented triangle
mesh with exactly one boundary loop and no handles (a topological disk). Anything else raises
:class:`~drawstring.geometry.errors.InputError` with one line naming the defect and the fix.

Repairs that cannot change the surface are done and recorded in ``Target.notes``: dropping
unreferenced vertices, merging coincident vertices, removing duplicated faces.  A zero-area
(degenerate) face is refused unless the caller asks for repairs (``repair=True``, the CLI's
``--repair``): removing one can change what the surface is (it may be all that joins two parts,
or it may be the trace of a collapsed region of the scan), so the user decides.  Built-in
targets are always repaired.

Orientation policy: inconsistent face orientation is refused, never guessed. Which side of the
surface is "outside" decides the side on which tiles are extruded, so the user has to say it
by fixing the winding (a flipped face is also the usual sign of a broken export).
"""

from __future__ import annotations

import logging
import math
import os
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import igl
import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from drawstring.geometry.builtins import BUILTIN_TARGETS
from drawstring.geometry.errors import InputError
from drawstring.geometry.tolerances import (
    COINCIDENT_VERTEX_REL_DIST,
    DEGENERATE_FACE_REL_AREA,
)

logger = logging.getLogger(__name__)

#: File name extensions :func:`read_mesh` understands (compared case-insensitively).
SUPPORTED_EXTENSIONS = (".obj", ".off", ".ply", ".stl")
#: Triangle counts accepted for built-in targets.
MIN_RESOLUTION = 32
MAX_RESOLUTION = 5_000_000


@dataclass(frozen=True, eq=False)
class Target:
    """A validated, scaled disk-topology target surface.

    Attributes
    ----------
    name : str
        Built-in name or the file's stem.
    vertices : (n, 3) float, mm
        Read-only. Scaled so that the longest bounding-box side is the requested size; x and y
        centred on 0, lowest z at 0; z is up.
    faces : (m, 3) int
        Read-only. Consistently oriented triangles forming a disk (one boundary loop).
    source : str
        ``"builtin"`` or the file path as given.
    notes : tuple of str
        Repairs done while loading, e.g. ``"removed 3 zero-area faces"``.
    vertex_of_input : (n_input,) int or None
        For each vertex as read (the file's order, counting from 0), its index in
        ``vertices``, or -1 where the repairs dropped it (unused by any face, or only by
        removed ones); coincident vertices map to the one they were merged into.
    """

    name: str
    vertices: NDArray[np.float64]
    faces: NDArray[np.int64]
    source: str
    notes: tuple[str, ...]
    vertex_of_input: NDArray[np.int64] | None = None

    @property
    def bbox_diagonal_mm(self) -> float:
        """Length of the bounding-box diagonal, mm."""
        return float(np.linalg.norm(np.ptp(self.vertices, axis=0)))


# --- loading ------------------------------------------------------------------------------


def load_target(
    spec: str | os.PathLike[str], size_mm: float, resolution: int = 10_000, *, repair: bool = False
) -> Target:
    """Load a built-in target or a mesh file, check it is a disk and scale it to size.

    Parameters
    ----------
    spec : str or path
        A built-in name (see :data:`~drawstring.geometry.builtins.BUILTIN_TARGETS`) or a path to
        an .obj, .off, .ply or .stl file.
    size_mm : float
        Longest bounding-box side of the result, mm.
    resolution : int
        Approximate triangle count of a built-in target (ignored for files).
    repair : bool
        Remove the zero-area faces of a mesh file instead of refusing it.

    Returns
    -------
    Target

    Raises
    ------
    InputError
        Bad size or resolution, unreadable file, or a mesh that is not a disk.
    """
    _check_size(size_mm)
    builtin = BUILTIN_TARGETS.get(spec.strip().lower()) if isinstance(spec, str) else None
    if builtin is not None:
        _check_resolution(resolution)
        raw_vertices, raw_faces = builtin.make(int(resolution))
        vertices, faces, notes, vertex_of_input = _clean_disk_mesh(
            raw_vertices, raw_faces, repair=True
        )
        name, source = builtin.name, "builtin"
    else:
        path = Path(spec)
        if path.suffix == "" and not path.exists():
            names = ", ".join(BUILTIN_TARGETS)
            raise InputError(
                f"unknown target '{os.fspath(spec)}': not a built-in ({names}) and not a mesh "
                f"file ({', '.join(SUPPORTED_EXTENSIONS)}); see `drawstring targets`"
            )
        raw_vertices, raw_faces = read_mesh(path)
        try:
            vertices, faces, notes, vertex_of_input = _clean_disk_mesh(
                raw_vertices, raw_faces, repair=repair
            )
        except InputError as error:
            raise InputError(f"{path}: {error}") from None
        name, source = path.stem, os.fspath(spec)
    scaled = scale_to_size(vertices, size_mm)
    for note in notes:
        logger.info("%s: %s", name, note)
    scaled.setflags(write=False)
    faces.setflags(write=False)
    vertex_of_input.setflags(write=False)
    return Target(
        name=name,
        vertices=scaled,
        faces=faces,
        source=source,
        notes=notes,
        vertex_of_input=vertex_of_input,
    )


def _check_size(size_mm: object) -> None:
    """Raise unless ``size_mm`` is a finite positive number."""
    if isinstance(size_mm, bool) or not isinstance(size_mm, int | float | np.integer | np.floating):
        valid = False
    else:
        value = float(size_mm)
        valid = math.isfinite(value) and value > 0.0
    if not valid:
        raise InputError(f"--size must be a positive number of millimetres (got {size_mm!r})")


def _check_resolution(resolution: object) -> None:
    """Raise unless ``resolution`` is an integer triangle count in the accepted range."""
    if isinstance(resolution, bool) or not isinstance(resolution, int | np.integer):
        valid = False
    else:
        valid = MIN_RESOLUTION <= int(resolution) <= MAX_RESOLUTION
    if not valid:
        raise InputError(
            f"resolution must be a whole number of triangles from {MIN_RESOLUTION} to "
            f"{MAX_RESOLUTION} (got {resolution!r})"
        )


def scale_to_size(vertices: NDArray[np.float64], size_mm: float) -> NDArray[np.float64]:
    """Scale uniformly to a longest bounding-box side of ``size_mm`` and place on the ground.

    Parameters
    ----------
    vertices : (n, 3) float
        Any units; the bounding box must not be a single point.
    size_mm : float
        Wanted longest bounding-box side, mm.

    Returns
    -------
    (n, 3) float, mm
        x and y centred on 0, lowest z at 0.
    """
    _check_size(size_mm)
    low = vertices.min(axis=0)
    high = vertices.max(axis=0)
    longest = float((high - low).max())
    if not longest > 0.0:
        raise InputError("mesh has no extent (all vertices coincide); export the real surface")
    anchor = np.array([(low[0] + high[0]) / 2.0, (low[1] + high[1]) / 2.0, low[2]])
    return np.ascontiguousarray((vertices - anchor) * (float(size_mm) / longest))


# --- reading ------------------------------------------------------------------------------


def read_mesh(path: str | os.PathLike[str]) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
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
        raise InputError(f"{path}: {error}") from None
    except (ValueError, IndexError, KeyError, UnicodeDecodeError) as error:
        detail = " ".join(str(error).split())
        raise InputError(
            f"{path}: not a valid {extension[1:].upper()} file ({detail}); re-export the mesh"
        ) from None
    if extension == ".stl" and len(vertices) and np.isfinite(vertices).all():
        vertices, faces, merged = merge_coincident_vertices(vertices, faces)
        logger.debug("%s: merged %d STL corners into shared vertices", path, merged)
    return vertices, faces


def _fan_triangulate(polygons: list[list[int]]) -> NDArray[np.int64]:
    """Triangles ``(p0, p[i], p[i+1])`` of each polygon, shape (m, 3)."""
    if all(len(polygon) == 3 for polygon in polygons):
        return np.array(polygons, dtype=np.int64).reshape(-1, 3)
    triangles = [
        (polygon[0], polygon[i], polygon[i + 1])
        for polygon in polygons
        for i in range(1, len(polygon) - 1)
    ]
    return np.array(triangles, dtype=np.int64).reshape(-1, 3)


def _to_vertex_array(rows: list[list[str]], what: str) -> NDArray[np.float64]:
    """Convert rows of three coordinate strings to an (n, 3) float array."""
    try:
        return np.array(rows, dtype=np.float64).reshape(-1, 3)
    except ValueError:
        for row in rows:
            for token in row:
                try:
                    float(token)
                except ValueError:
                    raise InputError(
                        f"{what} coordinate '{token[:20]}' is not a number; fix the file"
                    ) from None
        raise


def _read_obj(data: bytes) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Parse Wavefront OBJ text: ``v`` and ``f`` statements; everything else is ignored."""
    text = data.decode("utf-8", errors="replace")
    vertex_rows: list[list[str]] = []
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
    return _to_vertex_array(vertex_rows, "vertex"), _fan_triangulate(polygons)


def _read_off(data: bytes) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
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


def _read_ply(data: bytes) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Parse PLY (ascii, binary little or big endian): vertex x, y, z and face index lists."""
    file_format, elements, offset = _parse_ply_header(data)
    names = [element.name for element in elements]
    if "vertex" not in names:
        raise InputError("PLY file has no vertex element")
    columns: dict[str, dict[str, NDArray[np.float64]]] = {}
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
    columns: dict[str, dict[str, NDArray[np.float64]]],
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
    columns: dict[str, dict[str, NDArray[np.float64]]],
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


def _read_stl(data: bytes) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
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
    vertices = _to_vertex_array(rows, "vertex")
    return vertices, np.arange(len(vertices), dtype=np.int64).reshape(-1, 3)


def merge_coincident_vertices(
    vertices: NDArray[np.float64],
    faces: NDArray[np.int64],
    rel_distance: float = COINCIDENT_VERTEX_REL_DIST,
) -> tuple[NDArray[np.float64], NDArray[np.int64], int]:
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
    keep, remap = _coincident_remap(vertices, rel_distance)
    if remap is None:
        return vertices, faces, 0
    return vertices[keep], remap[faces], len(vertices) - len(keep)


def _coincident_remap(
    vertices: NDArray[np.float64], rel_distance: float = COINCIDENT_VERTEX_REL_DIST
) -> tuple[NDArray[np.int64], NDArray[np.int64] | None]:
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


def _count(n: int, singular: str, plural: str | None = None) -> str:
    """``"1 face"``, ``"3 faces"``: a number with its noun in the right number."""
    return f"{n} {singular if n == 1 else (plural or singular + 's')}"


# --- validation ---------------------------------------------------------------------------


def validate_disk_mesh(
    vertices: NDArray[np.float64], faces: NDArray[np.int64], *, repair: bool = False
) -> tuple[NDArray[np.float64], NDArray[np.int64], tuple[str, ...]]:
    """Check that a triangle mesh is a clean topological disk; make safe repairs.

    Repairs (each recorded in the notes): drop unreferenced vertices, merge coincident
    vertices, remove duplicated faces, and with ``repair`` zero-area faces (repeated index or
    area below ``DEGENERATE_FACE_REL_AREA`` times the mean), provided the rest is still a
    disk.  Without ``repair`` a zero-area face is refused.

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (m, 3) int

    Returns
    -------
    V : (k, 3) float
        Only referenced vertices, order kept.
    F : (p, 3) int
        Orientation as given.
    notes : tuple of str
        The repairs made.

    Raises
    ------
    InputError
        One line naming the first defect found and how to fix it.
    """
    V, F, notes, _ = _clean_disk_mesh(vertices, faces, repair=repair)
    return V, F, notes


def _clean_disk_mesh(
    vertices: NDArray[np.float64], faces: NDArray[np.int64], *, repair: bool
) -> tuple[NDArray[np.float64], NDArray[np.int64], tuple[str, ...], NDArray[np.int64]]:
    """:func:`validate_disk_mesh`, and where each input vertex went (``vertex_of_input`` of
    :class:`Target`)."""
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces)
    if V.ndim != 2 or V.shape[1] != 3:
        raise InputError(f"vertices must be an (n, 3) array of coordinates, got {V.shape}")
    if F.size == 0:
        raise InputError(
            "mesh has no faces; export the surface as a triangle mesh, not as points or lines"
        )
    if F.ndim != 2 or F.shape[1] != 3 or not np.issubdtype(F.dtype, np.integer):
        raise InputError(f"faces must be an (m, 3) integer array of triangles, got {F.shape}")
    F = F.astype(np.int64)
    notes: list[str] = []
    where = np.arange(len(V))  # input vertex -> current index, -1 once dropped

    def follow(new_index: NDArray[np.int64]) -> None:
        where[where >= 0] = new_index[where[where >= 0]]

    out_of_range = np.any((F < 0) | (F >= len(V)), axis=1)
    if out_of_range.any():
        raise InputError(
            f"face indices out of range in {_count(int(out_of_range.sum()), 'face')} (the mesh "
            f"has {len(V)} vertices, indices 0..{len(V) - 1}); the file is truncated or corrupt, "
            "re-export it"
        )
    V, F, dropped = _drop_unreferenced(V, F, follow)
    if dropped:
        notes.append(f"dropped {_count(dropped, 'unreferenced vertex', 'unreferenced vertices')}")
    non_finite = ~np.isfinite(V).all(axis=1)
    if non_finite.any():
        raise InputError(
            "non-finite (NaN or infinite) coordinates at "
            f"{_count(int(non_finite.sum()), 'vertex', 'vertices')}; fix or remove them and "
            "export again"
        )
    keep, remap = _coincident_remap(V)
    merged = 0
    if remap is not None:
        V, F, merged = V[keep], remap[F], len(V) - len(keep)
        follow(remap)
    if merged:
        notes.append(f"merged {_count(merged, 'coincident vertex', 'coincident vertices')}")

    degenerate = _degenerate_faces(V, F)
    if degenerate.all():
        raise InputError(
            f"all {len(F)} faces have zero area; the mesh is collapsed, export the real surface"
        )
    n_degenerate = int(degenerate.sum())
    if n_degenerate and _is_closed(F[~_repeats_vertex(F)], len(V)):
        raise InputError(_closed_message())
    if n_degenerate and not repair:
        first = V[F[np.flatnonzero(degenerate)[0]]].mean(axis=0)
        found = (
            f"{_count(n_degenerate, 'degenerate (zero-area) face')}, the first at "
            f"({', '.join(f'{c:.6g}' for c in first)})"
        )
        try:  # offer --repair only where it would give a disk
            _clean_disk_mesh(vertices, faces, repair=True)
        except InputError as error:
            raise InputError(
                f"{found}; {error}: mend the mesh around them in a mesh editor"
            ) from None
        raise InputError(
            f"{found}; delete them in a mesh editor (MeshLab: Filters > Cleaning and Repairing > "
            "Remove Zero Area Faces) or pass --repair to drop them"
        )
    F = F[~degenerate]
    duplicated = _duplicated_faces(F)
    F = F[~duplicated]
    if n_degenerate:
        notes.append(f"removed {_count(n_degenerate, 'zero-area face')}")
    if duplicated.any():
        notes.append(f"removed {_count(int(duplicated.sum()), 'duplicated face')}")
    V, F, dropped = _drop_unreferenced(V, F, follow)
    if dropped and (n_degenerate or duplicated.any()):
        notes.append(f"dropped {_count(dropped, 'vertex', 'vertices')} used only by removed faces")

    try:
        check_disk_topology(F, len(V))
    except InputError as error:
        if n_degenerate:
            removed = _count(n_degenerate, "zero-area face")
            raise InputError(
                f"removing {removed} leaves a surface that is not a disk ({error})"
            ) from None
        raise
    return np.ascontiguousarray(V), np.ascontiguousarray(F), tuple(notes), where


def _drop_unreferenced(
    vertices: NDArray[np.float64],
    faces: NDArray[np.int64],
    follow: Callable[[NDArray[np.int64]], None],
) -> tuple[NDArray[np.float64], NDArray[np.int64], int]:
    """Remove vertices no face uses; keep the order of the rest.  ``follow`` gets each old
    vertex's new index (-1: removed)."""
    used = np.zeros(len(vertices), dtype=bool)
    used[faces.ravel()] = True
    if used.all():
        return vertices, faces, 0
    new_index = np.where(used, np.cumsum(used) - 1, -1)
    follow(new_index)
    return vertices[used], new_index[faces], int((~used).sum())


def _repeats_vertex(faces: NDArray[np.int64]) -> NDArray[np.bool_]:
    """(m,) bool: the face uses some vertex twice."""
    return (
        (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 2] == faces[:, 0])
    )


def _degenerate_faces(vertices: NDArray[np.float64], faces: NDArray[np.int64]) -> NDArray[np.bool_]:
    """(m,) bool: repeated vertex or area at most ``DEGENERATE_FACE_REL_AREA`` of the mean."""
    p0, p1, p2 = (vertices[faces[:, k]] for k in range(3))
    areas = 0.5 * np.linalg.norm(np.cross(p1 - p0, p2 - p0), axis=1)
    threshold = DEGENERATE_FACE_REL_AREA * float(areas.mean())
    return _repeats_vertex(faces) | (areas <= threshold)


def _duplicated_faces(faces: NDArray[np.int64]) -> NDArray[np.bool_]:
    """(m,) bool: the face repeats the vertex set of an earlier face (either orientation)."""
    if len(faces) == 0:
        return np.zeros(0, dtype=bool)
    _, first = np.unique(np.sort(faces, axis=1), axis=0, return_index=True)
    duplicated = np.ones(len(faces), dtype=bool)
    duplicated[first] = False
    return duplicated


@dataclass(frozen=True)
class _Edges:
    """Undirected edges of a triangle mesh, seen from its 3m half-edges.

    Half-edge ``h = 3 f + k`` runs from ``F[f, k]`` to ``F[f, (k + 1) % 3]``; it starts at
    corner ``h`` and ends at corner ``3 f + (k + 1) % 3`` (corner = index into ``F.ravel()``).
    """

    start: NDArray[np.int64]  # (3m,) start vertex of each half-edge
    end: NDArray[np.int64]  # (3m,) end vertex
    edge: NDArray[np.int64]  # (3m,) undirected edge id of each half-edge
    valence: NDArray[np.int64]  # (e,) faces per edge
    pair_first: NDArray[np.int64]  # (i,) one half-edge of each two-face edge
    pair_second: NDArray[np.int64]  # (i,) the other one


def _edges(faces: NDArray[np.int64], n_vertices: int) -> _Edges:
    """Build the half-edge / edge tables (vectorized)."""
    start = faces.ravel()
    end = faces[:, [1, 2, 0]].ravel()
    low = np.minimum(start, end)
    high = np.maximum(start, end)
    _, edge, valence = np.unique(
        low * np.int64(n_vertices) + high, return_inverse=True, return_counts=True
    )
    edge = edge.ravel()
    order = np.argsort(edge, kind="stable")
    first_of_edge = np.cumsum(valence) - valence
    interior = np.flatnonzero(valence == 2)
    return _Edges(
        start=start,
        end=end,
        edge=edge,
        valence=valence,
        pair_first=order[first_of_edge[interior]],
        pair_second=order[first_of_edge[interior] + 1],
    )


def _is_closed(faces: NDArray[np.int64], n_vertices: int) -> bool:
    """True when every edge has exactly two faces."""
    return bool(np.all(_edges(faces, n_vertices).valence == 2))


def _closed_message(genus: int = 0) -> str:
    """InputError text for a surface without boundary."""
    handles = f", genus {genus}" if genus > 0 else ""
    return (
        f"surface is closed (no boundary{handles}); cut it open into a disk-like patch, "
        "e.g. remove the faces of one region"
    )


def check_disk_topology(faces: NDArray[np.int64], n_vertices: int) -> None:
    """Raise InputError unless the faces form an oriented topological disk.

    Checks, in this order: edge-manifold, one connected piece, vertex-manifold, consistent
    orientation (and orientability), a boundary, one boundary loop, genus 0.

    Parameters
    ----------
    faces : (m, 3) int
        Non-degenerate triangles; every vertex ``0..n_vertices-1`` referenced.
    n_vertices : int
    """
    n_faces = len(faces)
    edges = _edges(faces, n_vertices)
    crowded = int((edges.valence > 2).sum())
    if crowded:
        raise InputError(
            f"surface is not edge-manifold: {_count(crowded, 'edge')} shared by more than two "
            "faces; remove the extra faces (fins, duplicated or intersecting sheets)"
        )
    face_a = edges.pair_first // 3
    face_b = edges.pair_second // 3
    adjacency = sp.coo_matrix((np.ones(len(face_a)), (face_a, face_b)), shape=(n_faces, n_faces))
    n_pieces, _ = connected_components(adjacency, directed=False)
    if n_pieces > 1:
        raise InputError(
            f"mesh has {n_pieces} separate pieces (connected components); keep one patch and "
            "delete the others"
        )
    pinched = _count_pinched_vertices(faces, edges, n_vertices)
    if pinched:
        raise InputError(
            f"surface is not vertex-manifold: at {_count(pinched, 'vertex', 'vertices')} "
            "separate fans of faces touch (bow-tie); split or remove the faces meeting there"
        )
    same_direction = edges.start[edges.pair_first] == edges.start[edges.pair_second]
    if same_direction.any():
        raise InputError(_orientation_message(faces, n_vertices))
    boundary = edges.valence[edges.edge] == 1  # per half-edge
    n_edges = len(edges.valence)
    euler = n_vertices - n_edges + n_faces
    if not boundary.any():
        raise InputError(_closed_message((2 - euler) // 2))
    n_loops = _count_boundary_loops(edges.start[boundary], edges.end[boundary], n_vertices)
    genus = (2 - n_loops - euler) // 2
    if n_loops > 1 and genus > 0:
        raise InputError(
            f"surface has {n_loops} boundary loops and genus {genus} (Euler characteristic "
            f"{euler}; a disk has 1 loop and characteristic 1); fill all holes but the outer "
            "boundary and cut the handles open"
        )
    if n_loops > 1:
        holes = n_loops - 1
        raise InputError(
            f"surface has {n_loops} boundary loops ({_count(holes, 'hole')}); "
            "fill all holes but the outer boundary so that one boundary loop remains"
        )
    if genus > 0:
        raise InputError(
            f"surface has genus {genus} (Euler characteristic {euler}, a disk has 1): it has "
            f"{_count(genus, 'handle')}; cut {'them' if genus > 1 else 'it'} open (or cut the "
            "patch smaller) so that it becomes a disk"
        )


def _count_pinched_vertices(faces: NDArray[np.int64], edges: _Edges, n_vertices: int) -> int:
    """Number of vertices whose incident faces form more than one edge-connected fan."""
    n_corners = 3 * len(faces)
    first, second = edges.pair_first, edges.pair_second
    start_a, end_a = first, 3 * (first // 3) + (first % 3 + 1) % 3
    start_b, end_b = second, 3 * (second // 3) + (second % 3 + 1) % 3
    same = edges.start[first] == edges.start[second]
    # join the two corners at each end vertex of every interior edge
    rows = np.concatenate([start_a, end_a])
    cols = np.concatenate([np.where(same, start_b, end_b), np.where(same, end_b, start_b)])
    graph = sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n_corners, n_corners))
    n_labels, labels = connected_components(graph, directed=False)
    corner_vertex = faces.ravel()
    fans = np.unique(corner_vertex * np.int64(n_labels) + labels) // n_labels
    return int((np.bincount(fans, minlength=n_vertices) > 1).sum())


def _orientation_message(faces: NDArray[np.int64], n_vertices: int) -> str:
    """InputError text for inconsistent orientation: how many faces are flipped, or Möbius."""
    oriented, _ = igl.bfs_orient(np.ascontiguousarray(faces, dtype=np.int64))
    reoriented = _edges(oriented, n_vertices)
    still_bad = reoriented.start[reoriented.pair_first] == reoriented.start[reoriented.pair_second]
    if still_bad.any():
        return (
            "surface is not orientable (one-sided, like a Moebius strip); it cannot be "
            "flattened, cut it so that it has two sides"
        )
    kept = (
        np.all(oriented == faces, axis=1)
        | np.all(oriented == faces[:, [1, 2, 0]], axis=1)
        | np.all(oriented == faces[:, [2, 0, 1]], axis=1)
    )
    flipped = int(min((~kept).sum(), kept.sum()))
    return (
        f"faces are inconsistently oriented (inverted triangles): {flipped} of {len(faces)} "
        "faces are flipped relative to their neighbours; re-orient them consistently "
        "(e.g. MeshLab 'Re-Orient all faces coherently') and export again"
    )


def _count_boundary_loops(start: NDArray[np.int64], end: NDArray[np.int64], n_vertices: int) -> int:
    """Number of connected components of the boundary-edge graph."""
    graph = sp.coo_matrix((np.ones(len(start)), (start, end)), shape=(n_vertices, n_vertices))
    _, labels = connected_components(graph, directed=False)
    return len(np.unique(labels[start]))
