"""The STEP files of the fabrication folder: assemblies with a named, coloured part per tile and
hinge part, written deterministically (a fixed header timestamp, colour entities in an order of
their own rather than OCCT's, which follows memory addresses), in forked processes beside the
rest of the exports (:mod:`.beside`), since OCCT's STEP writer is serial and the slowest export.
"""

from __future__ import annotations

import itertools
import re
import tempfile
from collections.abc import Sequence
from pathlib import Path

import build123d as bd
import numpy as np
from numpy.typing import NDArray

from drawstring.cad.tiles import move_solid
from drawstring.fabrication.beside import Beside

#: Fixed timestamp written into STEP headers.
STEP_TIMESTAMP = "2000-01-01T00:00:00"

_COLOURS = {
    "PLA": (0.91, 0.64, 0.24),
    "TPU": (0.16, 0.36, 0.69),
    "EPDM": (0.12, 0.12, 0.12),
    "rubber": (0.2, 0.2, 0.2),
    "plywood": (0.85, 0.70, 0.47),
}


#: A part of a STEP assembly: name, shape and material (None: no colour).
StepPart = tuple[str, bd.Shape, str | None]


def _colour(material: str) -> bd.Color:
    for key, rgb in _COLOURS.items():
        if key.lower() in material.lower():
            return bd.Color(*rgb)
    return bd.Color(0.7, 0.7, 0.7)


def write_step(
    path: Path,
    parts: Sequence[StepPart],
    label: str,
    motions: NDArray[np.float64] | None = None,
) -> None:
    """An assembly of named, coloured parts; the same bytes for the same parts in any process.

    The header timestamp is fixed, assembly usages are numbered in file order, the colour
    section is laid out by :func:`canonical_style_tail` and equal geometry is written once
    (:func:`share_geometry`).

    parts : (name, shape, material) per part; a part without material has no colour.
    motions : (len(parts), 4, 4) rigid motions to move the parts by first, or None.
    """
    children = []
    for index, (name, solid, material) in enumerate(parts):
        shape = solid if motions is None else move_solid(solid, motions[index])
        child = type(shape)(shape.wrapped)
        child.label = name
        if material is not None:
            child.color = _colour(material)
        children.append(child)
    assembly = bd.Compound(children=children, label=label)
    with tempfile.TemporaryDirectory(prefix="drawstring-step-") as folder:
        scratch = Path(folder) / "out.step"
        # No PCURVEs (each edge's curve again in the parameter space of both its faces):
        # readers rebuild them, and they were half of the file.
        bd.export_step(assembly, scratch, write_pcurves=False)
        text = scratch.read_text(encoding="utf-8", errors="replace")
    text = re.sub(
        r"(FILE_NAME\('(?:[^']|'')*',)'[^']*'",
        lambda m: f"{m.group(1)}'{STEP_TIMESTAMP}'",
        text,
        count=1,
    )
    # OCCT numbers assembly usages with a counter that lives as long as the process; number
    # them from 1 in file order instead.
    counter = itertools.count(1)
    text = re.sub(
        r"NEXT_ASSEMBLY_USAGE_OCCURRENCE\('\d+'(.*?)\);",
        lambda m: (
            f"NEXT_ASSEMBLY_USAGE_OCCURRENCE('{next(counter)}'"
            + re.sub(r"\n\s*", "", m.group(1))
            + ");"
        ),
        text,
        flags=re.S,
    )
    text = share_geometry(canonical_style_tail(text))
    path.write_bytes(text.encode("utf-8"))


#: One DATA entity ``#n = body;`` (the body may span lines; quotes inside strings are doubled).
_STEP_ENTITY = re.compile(r"#(\d+)\s*=\s*((?:'(?:[^']|'')*'|[^';])*);")
#: A string literal (kept whole), a reference ``#n`` or a run of white space, in an entity body.
_STEP_TOKEN = re.compile(r"'(?:[^']|'')*'|#(\d+)|\s+")
_STYLE_ROOT = "MECHANICAL_DESIGN_GEOMETRIC_PRESENTATION_REPRESENTATION"
#: Longest line written for a re-laid style entity (OCCT wraps near 80 characters too).
_STEP_LINE = 78


def canonical_style_tail(text: str) -> str:
    """STEP text whose colour section is laid out in an order fixed by the model's content.

    OCCT's ``STEPCAFControl_Writer`` registers the presentation (colour) graph of every styled
    part last, from a map keyed by shape whose hash is the shape's memory address
    (``myMapCompMDGPR``, ``TopTools_ShapeMapHasher``).  The entities are the same every run,
    but their order and numbers follow the heap layout, which differs between processes.  This
    re-lays that tail: the ``MECHANICAL_DESIGN_GEOMETRIC_PRESENTATION_REPRESENTATION`` roots
    sorted by what they style (references into the stable part of the file, then their full
    content), each followed by the entities it alone brings in, depth first in field order;
    the tail is numbered on from its first entity.  Nothing before the tail refers into it
    (checked).  Text without styles is returned unchanged.
    """
    root = text.find(f" = {_STYLE_ROOT}(")  # a plain search: the file may be 100 MB
    if root < 0:
        return text
    start = re.compile(r"#(\d+)").match(text, text.rfind("\n", 0, root) + 1, root)
    if start is None or start.end() != root:
        raise RuntimeError("STEP style section does not start on a line of its own")
    end = text.index("ENDSEC;", root)
    first = int(start.group(1))
    bodies: dict[int, str] = {}
    order: list[int] = []
    for match in _STEP_ENTITY.finditer(text, start.start(), end):
        number = int(match.group(1))
        bodies[number] = match.group(2)
        order.append(number)
    if order != list(range(first, first + len(order))):
        raise RuntimeError("STEP style section is not numbered consecutively to its end")
    refs = {n: [int(r) for r in _STEP_TOKEN.findall(body) if r] for n, body in bodies.items()}
    # Every reference into the tail must come from the tail (OCCT adds the styles last).  A
    # quick scan for a large enough number first; strings are told apart only on a hit.
    if re.search(_at_least(first), text[: start.start()]):
        for match in _STEP_TOKEN.finditer(text, 0, start.start()):
            if match.group(1) and int(match.group(1)) >= first:
                raise RuntimeError(f"STEP entity outside the styles refers to #{match[1]}")

    def content(number: int, depth: int = 0) -> str:
        """The entity with its tail references replaced by their content (for sorting)."""
        if depth > 64:
            raise RuntimeError("STEP style section is nested too deep")
        return re.sub(
            r"'(?:[^']|'')*'|#(\d+)",
            lambda m: (
                "(" + content(int(m[1]), depth + 1) + ")" if m[1] and int(m[1]) in bodies else m[0]
            ),
            bodies[number],
        )

    def stable_refs(number: int, seen: set[int]) -> list[int]:
        found: list[int] = []
        for ref in refs[number]:
            if ref not in bodies:
                found.append(ref)
            elif ref not in seen:
                seen.add(ref)
                found += stable_refs(ref, seen)
        return found

    roots = [n for n in order if bodies[n].lstrip().startswith(_STYLE_ROOT + "(")]
    roots.sort(key=lambda n: (stable_refs(n, {n}), content(n)))
    laid: list[int] = []
    placed: set[int] = set()

    def lay(number: int) -> None:
        stack = [number]
        while stack:
            current = stack.pop()
            if current in placed:
                continue
            placed.add(current)
            laid.append(current)
            stack += [r for r in reversed(refs[current]) if r in bodies and r not in placed]

    for root in roots:
        lay(root)
    for number in order:  # anything no style root reaches keeps its relative order
        lay(number)
    renumber = {old: first + k for k, old in enumerate(laid)}

    def rewrite(body: str) -> str:
        """The body on one line, tail references renumbered."""
        out: list[str] = []
        last = 0
        for match in _STEP_TOKEN.finditer(body):
            out.append(body[last : match.start()])
            last = match.end()
            token = match.group(0)
            if match.group(1):
                token = f"#{renumber.get(int(match.group(1)), int(match.group(1)))}"
            elif token.isspace():  # a line break or indent: drop it next to punctuation
                joined = body[: match.start()].rstrip()[-1:] in ",(" or body[last:][:1] in ",)"
                token = "" if joined else " "
            out.append(token)
        out.append(body[last:])
        return "".join(out).strip()

    lines = [_wrap_step(f"#{renumber[n]} = {rewrite(bodies[n])};") for n in laid]
    return text[: start.start()] + "\n".join(lines) + "\n" + text[end:]


#: Geometry entities written once per distinct content (:func:`share_geometry`).
_SHARED_GEOMETRY = frozenset(
    {
        "CARTESIAN_POINT",
        "DIRECTION",
        "VECTOR",
        "LINE",
        "CIRCLE",
        "ELLIPSE",
        "AXIS2_PLACEMENT_3D",
        "PLANE",
        "CYLINDRICAL_SURFACE",
        "CONICAL_SURFACE",
        "TOROIDAL_SURFACE",
        "SPHERICAL_SURFACE",
    }
)
#: Of those, the ones shared only where geometry refers to them: an axis placement may also
#: place a representation or an assembly component, which keeps its own.
_PLACEMENTS = frozenset({"AXIS2_PLACEMENT_3D"})
#: One DATA entity ``#n = TYPE(...);`` (TYPE empty for a complex entity ``( ... )``): number,
#: type and the rest; runs of plain characters are taken whole (the files are tens of MB).
_STEP_RECORD = re.compile(r"#(\d+)\s*=\s*([A-Z_0-9]*)((?:[^';]+|'[^']*(?:''[^']*)*')*);")
_STEP_REF = re.compile(r"#(\d+)")
#: Splits an entity body into text, then string literals or references ``#n``, alternating.
_STEP_STRING_OR_REF_SPLIT = re.compile(r"('[^']*(?:''[^']*)*'|#\d+)")


def share_geometry(text: str) -> str:
    """STEP text with equal geometry written once.

    OCCT writes a point, direction, line, axis placement or surface afresh for every edge,
    vertex and face that uses it: the corners two faces of a tile share, the hundreds of
    faces in one plane of a flat layout, the unit directions.  Entities of the types in
    ``_SHARED_GEOMETRY`` whose content is the same (after their own references are shared)
    become one entity that all users refer to; topology (vertices, edges, faces, shells),
    representations and styles are left as they are, so every solid keeps its own B-rep.
    The entities left are numbered from 1 in file order.
    """
    # the section keywords on lines of their own (a name in the header or in DATA may hold
    # the same words)
    opened = re.search(r"^DATA;[ \t]*$", text, re.M)
    if opened is None:
        return text
    data = opened.end()
    closed = re.search(r"^ENDSEC;[ \t]*$", text[data:], re.M)
    if closed is None:
        return text
    end = data + closed.start()
    bodies: dict[int, str] = {}
    kinds: dict[int, str] = {}
    fixed: set[int] = set()  # placements something other than geometry refers to
    for digits, kind, body in _STEP_RECORD.findall(text, data, end):
        number = int(digits)
        bodies[number], kinds[number] = body, kind
        if kind not in _SHARED_GEOMETRY:
            fixed.update(map(int, _STEP_REF.findall(body)))
    same: dict[int, int] = {}  # entity -> the first entity of its content
    first: dict[str, int] = {}

    def canonical(number: int) -> int:
        known = same.get(number)
        if known is not None:
            return known
        kind = kinds.get(number, "")
        if kind not in _SHARED_GEOMETRY or (kind in _PLACEMENTS and number in fixed):
            same[number] = number
            return number
        body = bodies[number]
        if "#" not in body and (body.count("'") == 2 and "''" in body or "'" not in body):
            key = kind + "".join(body.split())  # no reference, no string but the empty name
        else:
            # strings whole, references shared, white space outside strings dropped
            parts = _STEP_STRING_OR_REF_SPLIT.split(body)
            for index in range(0, len(parts), 2):
                parts[index] = "".join(parts[index].split())
            for index in range(1, len(parts), 2):
                if parts[index][0] == "#":
                    parts[index] = f"#{canonical(int(parts[index][1:]))}"
            key = kind + "".join(parts)
        same[number] = first.setdefault(key, number)
        return same[number]

    order = list(bodies)
    for number in reversed(order):  # OCCT writes an entity before what it refers to
        canonical(number)
    renumber: dict[int, int] = {}
    for number in order:
        if same[number] == number:
            renumber[number] = len(renumber) + 1
    for number, first_number in same.items():
        renumber[number] = renumber[first_number]

    def renumbered(body: str) -> str:
        if "#" not in body:
            return body
        parts = _STEP_STRING_OR_REF_SPLIT.split(body)
        for index in range(1, len(parts), 2):
            if parts[index][0] == "#":
                parts[index] = f"#{renumber[int(parts[index][1:])]}"
        return "".join(parts)

    lines = [f"#{renumber[n]} = {kinds[n]}{renumbered(bodies[n])};" for n in order if same[n] == n]
    return text[:data] + "\n" + "\n".join(lines) + "\n" + text[end:]


def _at_least(number: int) -> str:
    """Regular expression for a reference ``#n`` with ``n >= number`` (no leading zeros)."""
    digits = str(number)
    size = len(digits)
    options = [rf"[1-9]\d{{{size},}}", digits]
    for index, digit in enumerate(digits):
        if digit != "9":
            rest = size - index - 1
            options.append(
                f"{digits[:index]}[{int(digit) + 1}-9]" + (rf"\d{{{rest}}}" if rest else "")
            )
    return "#(?:" + "|".join(options) + r")(?!\d)"


def _wrap_step(entity: str) -> str:
    """One entity on lines of at most ``_STEP_LINE`` characters where it can break after a
    comma outside strings; continuation lines are indented by two spaces."""
    if len(entity) <= _STEP_LINE:
        return entity
    chunks = [m.group(0) for m in re.finditer(r"(?:'(?:[^']|'')*'|[^',])*,?", entity) if m[0]]
    lines = [""]
    for chunk in chunks:
        if lines[-1].strip() and len(lines[-1]) + len(chunk) > _STEP_LINE:
            lines.append("  ")
        lines[-1] += chunk
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------
# writing beside the caller


#: A STEP file to write: path, parts, label and motions (:func:`write_step`).
StepJob = tuple[Path, Sequence[tuple[str, bd.Shape, str | None]], str, NDArray[np.float64] | None]


def start_step_writers(jobs: Sequence[StepJob], workers: int | None) -> Beside:
    """Write the STEP files in forked processes at the caller's priority (they are the
    longest writers), or here when fork is unavailable or ``workers == 1``."""
    writing = Beside(workers)
    for job in jobs:
        writing.start(job[0].name, write_step, *job)
    return writing
