"""Fabrication exports read back with independent readers (OCP, lib3mf, ezdxf, zip + XML)."""

from __future__ import annotations

import csv
import dataclasses
import errno
import itertools
import json
import math
import multiprocessing
import os
import re
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest

bd = pytest.importorskip("build123d")
ezdxf = pytest.importorskip("ezdxf")

from cad_sample import SampleDesign, cylinder_design  # noqa: E402

from drawstring.cad.checks import clearances  # noqa: E402
from drawstring.cad.design import CadResult, build_design_solids, normalize_route  # noqa: E402
from drawstring.cad.magnets_labels import _segment_rectangles, label_depth  # noqa: E402
from drawstring.cad.part_mesh import TRIANGLE_BUDGET  # noqa: E402
from drawstring.cad.tiles import move_solid, tile_solid  # noqa: E402
from drawstring.fabrication import step  # noqa: E402
from drawstring.fabrication.beds import TILE_SPACING_MM  # noqa: E402
from drawstring.fabrication.beside import can_fork  # noqa: E402
from drawstring.fabrication.dxf import (  # noqa: E402
    CUT_LAYERS,
    LAYER_CUT_OUTER,
    LAYER_SHEET,
    Part2D,
    nest_parts,
    offset_polygon,
    reads_forwards,
    rotate,
    shelf_pack,
    signed_area,
    text_strokes,
)
from drawstring.fabrication.exports import write_fabrication  # noqa: E402
from drawstring.fabrication.mesh3mf import BED_MARGIN_MM, plan_print_jobs  # noqa: E402
from drawstring.fabrication.printers import Printer, load_printer  # noqa: E402
from drawstring.fabrication.profiles import (  # noqa: E402
    Profile,
    load_profile,
    print_clearance_mm,
)
from drawstring.fabrication.record import ExportRecord  # noqa: E402
from drawstring.geometry.core.errors import InputError  # noqa: E402
from drawstring.geometry.core.tolerances import PRINT_GAP_TOL_MM  # noqa: E402
from drawstring.geometry.tiling.linkage import id_runs  # noqa: E402
from drawstring.output.assembly_guide import write_guide  # noqa: E402

PROFILES = ("fdm-dual", "laser-epdm", "plywood-cnc")
EXPECTED = {
    "fdm-dual": {"print.3mf", "print.ini"},
    # (the samples have bottom-face strips: their template seen from below too)
    "laser-epdm": {
        "tiles.3mf",
        "tiles.ini",
        "hinges.dxf",
        "placement.dxf",
        "placement.svg",
        "placement-bottom.dxf",
        "placement-bottom.svg",
    },
    "plywood-cnc": {
        "panels.dxf",
        "hinges.dxf",
        "cutlist.csv",
        "placement.dxf",
        "placement.svg",
        "placement-bottom.dxf",
        "placement-bottom.svg",
    },
}
COMMON = {
    "flat.step",
    "assembled.step",
    "bom.csv",
    "manifest.json",
    "assembly.md",
    "assembly-tiles.png",
    "assembly-threading.png",
    "assembly-pull.png",
}
PLYWOOD_SIDE, PLYWOOD_RADIUS = 300.0, 1500.0


@dataclasses.dataclass
class Built:
    profile: Profile
    design: SampleDesign
    flat: CadResult
    assembled: CadResult
    folder: Path
    files: list[str]


def _sample(name: str) -> tuple[Profile, SampleDesign]:
    if name == "plywood-cnc":
        design = cylinder_design((3, 3), side=PLYWOOD_SIDE, thickness=60.0, radius=PLYWOOD_RADIUS)
        return load_profile(name), design
    # 3 mm magnets: the shipped 6 mm ones do not fit a 6 mm tile's side face.
    profile = dataclasses.replace(load_profile(name), magnet_diameter_mm=3.0, magnet_height_mm=1.5)
    return profile, cylinder_design((3, 3))


def _write(
    built: Built, folder: Path, printer: Printer | None = None, workers: int | None = 1
) -> list[str]:
    d = built.design
    return write_fabrication(
        folder,
        profile=built.profile,
        linkage=d.linkage,
        tiles_flat=d.tiles_2d,
        tiles_assembled=d.tiles_3d,
        hinge_side=d.hinge_side,
        route_steps=d.route_steps,
        lift_tiles=d.lift_tiles,
        magnet_pairs=d.magnet_pairs,
        trims=d.trims,
        cad_flat=built.flat,
        cad_assembled=built.assembled,
        design_name="sample",
        guide=write_guide,
        workers=workers,
        printer=printer,
    )


def _built(name: str, folder: Path) -> Built:
    """The sample of a profile built and written into ``folder`` (the fixture and the
    fresh-process rerun share it)."""
    profile, d = _sample(name)
    args = (*d.solid_inputs(), profile)
    flat = build_design_solids(*args, workers=1, print_clearance_mm=print_clearance_mm(profile))
    # The assembled pose is the flat solids moved rigidly (what build_design_solids does).
    assembled = dataclasses.replace(
        flat,
        pose="assembled",
        tiles=tuple(move_solid(s, m) for s, m in zip(flat.tiles, flat.transforms, strict=True)),
        pads=(),
        pad_hinge=np.zeros(0, dtype=np.int64),
    )
    result = Built(profile, d, flat, assembled, folder, [])
    result.files = _write(result, result.folder)
    return result


@pytest.fixture(scope="module", params=PROFILES)
def built(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Built:
    return _built(request.param, tmp_path_factory.mktemp(request.param))


def test_files_written(built: Built) -> None:
    names = {Path(f).name for f in built.files}
    assert names == COMMON | EXPECTED[built.profile.process]
    assert all((built.folder / f).is_file() for f in built.files)


#: Loads this test module from argv[1], then builds and writes the sample of each profile
#: argv[2], argv[4], ... into the folder after it.
_BUILD_AGAIN = """
import importlib.util, sys
from pathlib import Path
sys.path.insert(0, str(Path(sys.argv[1]).parent))  # the test module's helpers beside it
spec = importlib.util.spec_from_file_location("exports_tests", sys.argv[1])
module = sys.modules[spec.name] = importlib.util.module_from_spec(spec)
spec.loader.exec_module(module)
for name, folder in zip(sys.argv[2::2], sys.argv[3::2], strict=True):
    module._built(name, Path(folder))
"""


def _other_hash_seed() -> dict[str, str]:
    """This environment with a string hash seed other than this process's (ezdxf once wrote
    its CLASS entries in the order of a set of names)."""
    seed = os.environ.get("PYTHONHASHSEED", "random")
    other = str(int(seed) + 1) if seed.isdigit() else "1"
    return {**os.environ, "PYTHONHASHSEED": other}


@pytest.fixture(scope="module")
def built_again(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Each profile's sample built and written again by one other process, with another
    string hash seed: the folder by profile name."""
    folders = {name: tmp_path_factory.mktemp(f"again-{name}") / "again" for name in PROFILES}
    pairs = [str(a) for name, folder in folders.items() for a in (name, folder)]
    command = [sys.executable, "-c", _BUILD_AGAIN, __file__, *pairs]
    subprocess.run(command, check=True, capture_output=True, timeout=900, env=_other_hash_seed())
    return folders


def test_repeat_run_in_a_fresh_process_is_byte_identical(
    built: Built, built_again: dict[str, Path]
) -> None:
    """Every file again, built and written by another process.

    Writing again in this process would reuse the very same OCCT shapes (same memory
    addresses) and the same string hash seed, which hides any order that follows either:
    OCCT's STEP writer laid out its colours by address, ezdxf its classes by hash.  A new
    process builds its shapes elsewhere, with another seed.
    """
    again = built_again[built.profile.name]
    names = sorted(str(p.relative_to(again)) for p in again.rglob("*") if p.is_file())
    assert names == built.files
    for name in built.files:
        assert (built.folder / name).read_bytes() == (again / name).read_bytes(), name


def test_writing_beside_gives_the_serial_bytes(built: Built, tmp_path: Path) -> None:
    """The STEP and 3MF files written in forked children (``workers`` unset) are the files
    the fixture wrote one after the other in this process (``workers=1``)."""
    if not can_fork():
        pytest.skip("processes cannot fork here")
    files = _write(built, tmp_path, workers=None)
    assert files == built.files
    for name in files:
        assert (tmp_path / name).read_bytes() == (built.folder / name).read_bytes(), name


@pytest.mark.parametrize("workers", [1, None])
def test_a_failing_step_writer_raises_its_own_error(
    built: Built, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, workers: int | None
) -> None:
    """A STEP writer that fails (a full disk) raises the same OSError in a forked child as
    here, which the design folder turns into its one-line refusal; the other writers stop."""
    if built.profile.name != "fdm-dual":
        pytest.skip("one profile suffices")

    def full_disk(path: Path, *_: object) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(step, "write_step", full_disk)
    d = built.design
    with pytest.raises(OSError) as raised:
        write_fabrication(
            tmp_path,
            profile=built.profile,
            linkage=d.linkage,
            tiles_flat=d.tiles_2d,
            tiles_assembled=d.tiles_3d,
            hinge_side=d.hinge_side,
            route_steps=d.route_steps,
            lift_tiles=d.lift_tiles,
            magnet_pairs=d.magnet_pairs,
            trims=d.trims,
            cad_flat=built.flat,
            cad_assembled=built.assembled,
            design_name="sample",
            workers=workers,
        )
    assert raised.value.errno == errno.ENOSPC
    assert raised.value.filename == str(tmp_path / "fabrication" / "flat.step")
    assert multiprocessing.active_children() == []


#: Writes a STEP assembly of twelve coloured boxes to argv[1].
_BOXES_STEP = """
import sys
from pathlib import Path
import build123d as bd
from drawstring.fabrication.step import write_step
parts = [
    (f"part_{k}", bd.Solid.make_box(1.0 + k, 2.0, 3.0).moved(bd.Location((10.0 * k, 0, 0))),
     "TPU" if k % 3 == 0 else "PLA")
    for k in range(12)
]
write_step(Path(sys.argv[1]), parts, "boxes")
"""


def test_step_colours_do_not_depend_on_the_process(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """OCCT orders the colour entities by shape address: two processes (a fresh one and this
    one), same bytes."""
    paths = [tmp_path / "a.step", tmp_path / "b.step"]
    command = [sys.executable, "-c", _BOXES_STEP, str(paths[0])]
    subprocess.run(command, check=True, capture_output=True, timeout=300)
    monkeypatch.setattr(sys, "argv", ["-c", str(paths[1])])
    exec(compile(_BOXES_STEP, "<boxes>", "exec"), {"__name__": "__main__"})
    first, second = (p.read_bytes() for p in paths)
    assert first == second
    # Colours and names survive the re-laid colour section.
    parts = bd.import_step(paths[0]).children
    assert sorted(p.label for p in parts) == sorted(f"part_{k}" for k in range(12))
    colours = {p.label: tuple(round(c, 2) for c in tuple(p.color)[:3]) for p in parts}
    assert colours["part_0"] == (0.16, 0.36, 0.69) and colours["part_1"] == (0.91, 0.64, 0.24)


def test_step_colour_section_is_canonical_in_one_process(tmp_path: Path) -> None:
    """Copies of the same solids sit at other addresses: the file must not change."""
    import copy

    from drawstring.fabrication.step import write_step

    boxes = [
        (f"part_{k}", bd.Solid.make_box(1.0 + k, 2.0, 3.0), "TPU" if k % 2 else "PLA")
        for k in range(8)
    ]
    texts = []
    for round_ in range(3):
        parts = [(n, copy.deepcopy(s), m) for n, s, m in boxes]
        write_step(tmp_path / f"{round_}.step", parts, "boxes")
        texts.append((tmp_path / f"{round_}.step").read_bytes())
    assert texts[0] == texts[1] == texts[2]


def test_step_writes_equal_geometry_once(tmp_path: Path) -> None:
    """Boxes side by side share corners, directions and planes: each is written once, while
    every box keeps its own vertices, edges and faces (a valid solid of its volume)."""
    from drawstring.fabrication.step import write_step

    parts = [
        (f"part_{k}", bd.Solid.make_box(1.0, 2.0, 3.0).moved(bd.Location((k, 0, 0))), "PLA")
        for k in range(6)
    ]
    path = tmp_path / "boxes.step"
    write_step(path, parts, "boxes")
    text = path.read_text(encoding="utf-8")
    entities = re.findall(r"#\d+ = ([A-Z_0-9]+)\(((?:[^;'])*(?:'[^']*')?(?:[^;'])*)\);", text, re.S)
    for kind in ("CARTESIAN_POINT", "DIRECTION", "VECTOR", "LINE", "PLANE"):
        contents = ["".join(body.split()) for k, body in entities if k == kind]
        assert contents and len(contents) == len(set(contents)), kind
    points = {"".join(body.split()) for k, body in entities if k == "CARTESIAN_POINT"}
    assert len(points) <= 7 * 2 * 2 + 1  # box corners on a 7 x 2 x 2 grid, and the origin
    assert sum(k == "VERTEX_POINT" for k, _ in entities) == 8 * len(parts)
    assert sum(k == "ADVANCED_FACE" for k, _ in entities) == 6 * len(parts)
    assert sorted(_step_solids(path)) == pytest.approx([6.0] * len(parts), rel=1e-12)


@pytest.mark.parametrize("name", ["o'neil's DATA; chair", "a ENDSEC; b", "#12 ''x''"])
def test_step_names_with_step_syntax_read_back_and_repeat(tmp_path: Path, name: str) -> None:
    """A design named after a mesh file may hold quotes, section keywords and references: the
    file still reads back with its solids, and two writes are the same bytes."""
    from drawstring.fabrication.step import write_step

    parts = [
        (f"part_{k}", bd.Solid.make_box(1.0, 2.0, 3.0).moved(bd.Location((k, 0, 0))), "PLA")
        for k in range(2)
    ]
    first, second = tmp_path / "a.step", tmp_path / "b.step"
    write_step(first, parts, name)
    write_step(second, parts, name)
    assert first.read_bytes() == second.read_bytes()
    assert sorted(_step_solids(first)) == pytest.approx([6.0, 6.0], rel=1e-12)


def _step_solids(path: Path) -> list:
    from OCP.BRepCheck import BRepCheck_Analyzer
    from OCP.BRepGProp import BRepGProp
    from OCP.GProp import GProp_GProps
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.STEPControl import STEPControl_Reader
    from OCP.TopAbs import TopAbs_SOLID
    from OCP.TopExp import TopExp_Explorer

    reader = STEPControl_Reader()
    assert reader.ReadFile(str(path)) == IFSelect_RetDone
    reader.TransferRoots()
    shape = reader.OneShape()
    explorer = TopExp_Explorer(shape, TopAbs_SOLID)
    volumes = []
    while explorer.More():
        solid = explorer.Current()
        assert BRepCheck_Analyzer(solid).IsValid()
        props = GProp_GProps()
        BRepGProp.VolumeProperties_s(solid, props)
        volumes.append(props.Mass())
        explorer.Next()
    return volumes


@pytest.mark.parametrize("pose", ["flat", "assembled"])
def test_step_assemblies_read_back(built: Built, pose: str) -> None:
    """One valid solid per tile (and hinge part, flat): the tiles without their engraved
    numbers, each number as its outline beside it."""
    path = built.folder / "fabrication" / f"{pose}.step"
    cad = built.flat if pose == "flat" else built.assembled
    tiles = built.flat.unengraved
    assert len(tiles) == len(cad.tiles)  # every sample engraves numbers
    expected = sorted([s.volume for s in tiles] + [s.volume for s in cad.pads])
    volumes = sorted(_step_solids(path))
    assert len(volumes) == len(expected)
    np.testing.assert_allclose(volumes, expected, rtol=1e-6)
    text = path.read_text(encoding="utf-8")
    assert "'tile_0'" in text and "2000-01-01T00:00:00" in text
    # edges carry their 3D curves only (readers rebuild the curves on faces)
    assert "PCURVE" not in text
    if cad.pads:
        assert f"'hinge_{int(cad.pad_hinge[0])}'" in text
    # each engraved number as closed outlines, one per seven-segment stroke, where it is on
    # the tile: on the bottom face of the tile as it lies in this file
    parts = {p.label: p for p in bd.import_step(path).children}
    numbered = [t for t, o in enumerate(built.flat.number_outlines) if o is not None]
    assert numbered and sorted(n for n in parts if n.startswith("number_")) == sorted(
        f"number_{t}" for t in numbered
    )
    for t in numbered:
        edges = parts[f"number_{t}"].edges()  # a closed polyline per stroke
        assert len(edges) == len(_segment_rectangles(str(t), 1.0))
        assert all(e.is_closed and len(e.vertices()) == 1 for e in edges)
        solid = parts[f"tile_{t}"]
        bottom = min(solid.faces(), key=lambda f: f.center().Z)
        for edge in edges:
            for point in (edge.position_at(u) for u in np.linspace(0.0, 1.0, 9)):
                if pose == "flat":  # the bottom face lies on the bed
                    assert point.Z == pytest.approx(bottom.center().Z, abs=1e-6)
                assert solid.distance_to(point) < 1e-6


def test_step_tiles_are_the_tiles_without_numbers(built: Built) -> None:
    """The STEP files' tiles weigh what the same tiles built without numbers weigh, and each
    differs from the printed (engraved) tile by its digits' outline area times the depth."""
    profile, d = built.profile, built.design
    plain = build_design_solids(
        *d.solid_inputs(),
        profile,
        labels=False,
        workers=1,
        print_clearance_mm=print_clearance_mm(profile),
    )
    np.testing.assert_allclose(
        [s.volume for s in built.flat.unengraved], [s.volume for s in plain.tiles], rtol=1e-9
    )
    depth = label_depth(profile)
    for engraved, filled, outline in zip(
        built.flat.tiles, built.flat.unengraved, built.flat.number_outlines, strict=True
    ):
        assert outline is not None
        area = sum(
            0.5 * np.linalg.norm(np.cross(p, np.roll(p, -1, axis=0)).sum(0)) for p in outline
        )
        pockets = area * depth
        assert filled.volume - engraved.volume == pytest.approx(pockets, rel=1e-4)
        assert filled.is_valid and len(filled.faces()) < len(engraved.faces())


def _read_3mf(path: Path):
    import lib3mf

    wrapper = lib3mf.get_wrapper()
    model = wrapper.CreateModel()
    model.QueryReader("3mf").ReadFromFile(str(path))
    meshes = []
    iterator = model.GetMeshObjects()
    while iterator.MoveNext():
        mesh = iterator.GetCurrentMeshObject()
        vertices = np.array([v.Coordinates[0:3] for v in mesh.GetVertices()])
        triangles = np.array([t.Indices[0:3] for t in mesh.GetTriangleIndices()])
        meshes.append((mesh.IsManifoldAndOriented(), vertices, triangles))
    return meshes


def _components(vertices: np.ndarray, triangles: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """The connected pieces of a triangle mesh, each with its own vertices."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    n = len(vertices)
    rows = np.concatenate([triangles[:, 0], triangles[:, 1]])
    cols = np.concatenate([triangles[:, 1], triangles[:, 2]])
    _, label = connected_components(sp.coo_matrix((np.ones(len(rows)), (rows, cols)), (n, n)))
    pieces = []
    for k in np.unique(label[triangles[:, 0]]):
        keep = np.flatnonzero(label == k)
        index = np.full(n, -1)
        index[keep] = np.arange(len(keep))
        tris = triangles[label[triangles[:, 0]] == k]
        pieces.append((vertices[keep], index[tris]))
    return pieces


def _mesh_volume(vertices: np.ndarray, triangles: np.ndarray) -> float:
    tri = vertices[triangles]
    return float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6)


def test_3mf_meshes_and_extruders(built: Built) -> None:
    process = built.profile.process
    if process == "plywood-cnc":
        pytest.skip("no 3MF for plywood")
    path = built.folder / "fabrication" / ("print.3mf" if process == "fdm-dual" else "tiles.3mf")
    meshes = _read_3mf(path)
    assert meshes and all(ok for ok, _, _ in meshes)
    volume = sum(_mesh_volume(v, t) for _, v, t in meshes)
    cad = sum(s.volume for s in built.flat.tiles)
    if process == "fdm-dual":
        cad += sum(s.volume for s in built.flat.pads)
    assert volume == pytest.approx(cad, rel=0.01)
    with zipfile.ZipFile(path) as archive:
        names = archive.namelist()
        # every declared base material is used (loose tiles declared an unused "pad")
        model = ET.fromstring(archive.read("3D/3dmodel.model"))
        core = "{http://schemas.microsoft.com/3dmanufacturing/core/2015/02}"
        declared = len(model.findall(f"{core}resources/{core}basematerials/{core}base"))
        used = {t.get("p1") for t in model.iter(f"{core}triangle")}
        assert used == {str(k) for k in range(declared)}
        if process != "fdm-dual":
            assert "Metadata/Slic3r_PE_model.config" not in names
            return
        config = ET.fromstring(archive.read("Metadata/Slic3r_PE_model.config"))
        bambu = ET.fromstring(archive.read("Metadata/model_settings.config"))
    extruders = []
    for obj, prusa_obj, (_, _, triangles) in zip(
        bambu.findall("object"), config.findall("object"), meshes, strict=True
    ):
        parts, next_first = [], 0
        for part_el in obj.findall("part"):  # one per part
            first, last = int(part_el.get("firstid")), int(part_el.get("lastid"))
            assert first == next_first and last >= first
            next_first = last + 1
            keys = {m.get("key"): m.get("value") for m in part_el.findall("metadata")}
            parts.append((keys["name"].split("_")[0], keys["extruder"], first, last))
            kind = "tile" if keys["name"].startswith("tile") else "pad"
            assert last + 1 - first <= TRIANGLE_BUDGET[kind]  # a part's triangles, read back
        assert next_first == len(triangles)
        # PrusaSlicer's volumes: one per run of parts on one extruder, over the same ranges
        runs: list[list] = []
        for _, extruder, first, last in parts:
            if runs and runs[-1][0] == extruder:
                runs[-1][2] = last
            else:
                runs.append([extruder, first, last])
        volumes = [
            [
                {m.get("key"): m.get("value") for m in v.findall("metadata")}["extruder"],
                int(v.get("firstid")),
                int(v.get("lastid")),
            ]
            for v in prusa_obj.findall("volume")
        ]
        assert volumes == runs
        extruders += parts
    assert {e for k, e, *_ in extruders if k == "tile"} == {"1"}
    assert {e for k, e, *_ in extruders if k == "hinge"} == {"2"}
    assert sum(k == "tile" for k, *_ in extruders) == len(built.flat.tiles)
    assert sum(k == "hinge" for k, *_ in extruders) == len(built.flat.pads)


def test_every_printed_tile_rests_on_the_bed(built: Built) -> None:
    """fdm-dual jobs print top faces down: the tops lie in one plane, the bottoms do not (a
    tile is as thick as its frustum), so every tile volume of print.3mf (read back with lib3mf,
    split by the Bambu/Orca config's part ranges) reaches down to z = 0 and nothing goes below."""
    if built.profile.process != "fdm-dual":
        pytest.skip("dual extrusion only")
    path = built.folder / "fabrication" / "print.3mf"
    with zipfile.ZipFile(path) as archive:
        config = ET.fromstring(archive.read("Metadata/model_settings.config"))
    lowest = []
    for obj, (_, vertices, triangles) in zip(
        config.findall("object"), _read_3mf(path), strict=True
    ):
        assert vertices[:, 2].min() >= -1e-6
        for volume_el in obj.findall("part"):
            keys = {m.get("key"): m.get("value") for m in volume_el.findall("metadata")}
            if keys["name"].startswith("tile"):
                first, last = int(volume_el.get("firstid")), int(volume_el.get("lastid"))
                lowest.append(vertices[triangles[first : last + 1]][:, :, 2].min())
    assert len(lowest) == len(built.flat.tiles)
    assert np.max(lowest) <= 1e-4


def _printed_tiles(path: Path) -> dict[int, np.ndarray]:
    """Each PLA tile of a print.3mf by its number, as (triangles, 3, 3) float, read back with
    lib3mf and split by the Bambu/Orca config's part ranges."""
    with zipfile.ZipFile(path) as archive:
        config = ET.fromstring(archive.read("Metadata/model_settings.config"))
    tiles = {}
    for obj, (_, vertices, triangles) in zip(
        config.findall("object"), _read_3mf(path), strict=True
    ):
        for volume_el in obj.findall("part"):
            keys = {m.get("key"): m.get("value") for m in volume_el.findall("metadata")}
            if keys["extruder"] == "1":
                first, last = int(volume_el.get("firstid")), int(volume_el.get("lastid"))
                tiles[int(keys["name"].removeprefix("tile_"))] = vertices[
                    triangles[first : last + 1]
                ]
    return tiles


def test_printed_tiles_stay_a_nozzle_apart(built: Built) -> None:
    """Hinged tiles meet at their hinge edges in the flat pose; as printed (print.3mf read
    back, distances by manifold3d on its meshes) every two PLA tiles stay at least a nozzle
    width apart, so a slicer cannot join them.  Loose tiles are not relieved."""
    import manifold3d

    guide = (built.folder / "fabrication" / "assembly.md").read_text(encoding="utf-8")
    if built.profile.process != "fdm-dual":
        assert print_clearance_mm(built.profile) == 0.0
        assert "print 0." not in guide
        return
    nozzle = built.profile.nozzle_mm
    assert f"Hinged tiles print {nozzle:g} mm apart, joined only by their pads" in guide
    meshes = []
    printed = _printed_tiles(built.folder / "fabrication" / "print.3mf")
    assert sorted(printed) == list(range(len(built.flat.tiles)))
    for _, soup in sorted(printed.items()):
        mesh = manifold3d.Mesh(
            vert_properties=soup.reshape(-1, 3).astype(np.float32),
            tri_verts=np.arange(soup.shape[0] * 3, dtype=np.uint32).reshape(-1, 3),
        )
        mesh.merge()
        meshes.append(manifold3d.Manifold(mesh))
    assert len(meshes) == len(built.flat.tiles)
    # (the sample lays the tiles across its split edge to edge, where a design's flat layout
    # parts them: those pairs are left out)
    split = {tuple(sorted(p)) for p in built.design.magnet_pairs[:, [0, 2]].tolist()}
    gaps = [
        meshes[i].min_gap(meshes[j], 2.0 * nozzle)
        for i, j in itertools.combinations(range(len(meshes)), 2)
        if (i, j) not in split
    ]
    hinged = len(built.design.linkage.hinges)
    assert sum(g < 2.0 * nozzle for g in gaps) >= hinged  # the hinged pairs are close...
    assert min(gaps) >= nozzle - 1e-3  # ... and a nozzle apart
    # without the reliefs they touch at the hinges
    plain = [tile_solid(t) for t in built.design.tiles_2d]
    near = clearances(plain, 2.0 * nozzle)
    assert near.min_distance < 1e-3


def test_print_jobs_turn_tiles_of_different_thickness_onto_their_common_top_plane() -> None:
    # Two boxes side by side, tops at z = 6, one 6 mm and one 5.7 mm thick (as tiles of a quad
    # mesh that is not conical are), and a pad sunk 1 mm into both tops: on the bed both
    # tiles touch z = 0, the pad lies on it, and the job keeps its footprint on the bed.
    from types import SimpleNamespace

    from drawstring.fabrication.beds import jobs_on_bed
    from drawstring.fabrication.mesh3mf import PartMesh, PrintJob

    def box(x0: float, x1: float, z0: float, z1: float, name: str, kind: str) -> PartMesh:
        corners = np.array([[x, y, z] for x in (x0, x1) for y in (0.0, 10.0) for z in (z0, z1)])
        return PartMesh(name, kind, corners, np.array([[0, 1, 2]]))  # type: ignore[arg-type]

    tiles = {0: box(0, 10, 0.0, 6.0, "tile_0", "tile"), 1: box(11, 21, 0.3, 6.0, "tile_1", "tile")}
    pads = {0: box(8, 13, 5.0, 6.0, "hinge_0", "pad")}
    offset = np.array([100.0, 50.0, 0.0])
    job = PrintJob((0, 1), (0,), offset, np.array([21.0, 10.0]))
    record = SimpleNamespace(jobs=[])
    (parts,) = jobs_on_bed([job], tiles, pads, record)  # type: ignore[arg-type]
    low = {p.name: p.vertices.min(axis=0) for p in parts}
    high = {p.name: p.vertices.max(axis=0) for p in parts}
    assert low["tile_0"][2] == pytest.approx(0.0) and low["tile_1"][2] == pytest.approx(0.0)
    assert high["tile_1"][2] == pytest.approx(5.7) and low["hinge_0"][2] == pytest.approx(0.0)
    every = np.vstack([p.vertices for p in parts])
    np.testing.assert_allclose(every.min(axis=0)[:2], [100.0, 50.0])
    np.testing.assert_allclose(every.max(axis=0)[:2], [121.0, 60.0])


@pytest.mark.skipif(shutil.which("prusa-slicer") is None, reason="prusa-slicer not installed")
def test_prusaslicer_slices_with_both_extruders(built: Built, tmp_path: Path) -> None:
    if built.profile.process != "fdm-dual":
        pytest.skip("dual extrusion only")
    gcode = tmp_path / "out.gcode"
    command = [
        "prusa-slicer",
        "--export-gcode",
        "--bed-shape",
        "0x0,330x0,330x240,0x240",
        "--nozzle-diameter",
        "0.4,0.4",
        "--filament-diameter",
        "1.75,1.75",
        "--temperature",
        "210,230",
        "--first-layer-temperature",
        "210,230",
        "--center",
        "165,120",
        str(built.folder / "fabrication" / "print.3mf"),
        "-o",
        str(gcode),
    ]
    subprocess.run(command, check=True, capture_output=True, timeout=300)
    lines = gcode.read_text(encoding="utf-8", errors="replace").splitlines()
    assert any(line.startswith("T0") for line in lines)
    assert any(line.startswith("T1") for line in lines)


def _polyline_points(entity) -> np.ndarray:
    from ezdxf import path as dxfpath

    return np.array([(p.x, p.y) for p in dxfpath.make_path(entity).flattening(0.01)])


@pytest.mark.parametrize("name", ["hinges.dxf", "panels.dxf", "placement.dxf"])
def test_dxf_reads_back_clean(built: Built, name: str) -> None:
    path = built.folder / "fabrication" / name
    if not path.exists():
        pytest.skip(f"{name} is not made for {built.profile.process}")
    doc = ezdxf.readfile(path)
    auditor = doc.audit()
    assert not auditor.has_errors
    assert doc.units == ezdxf.units.MM
    msp = doc.modelspace()
    assert not list(msp.query("TEXT MTEXT"))
    if name == "placement.dxf":
        return
    for entity in msp:
        if entity.dxf.layer in CUT_LAYERS:
            assert entity.dxftype() == "LWPOLYLINE" and entity.closed
    frames = []
    for entity in msp.query(f"LWPOLYLINE[layer=='{LAYER_SHEET}']"):
        if entity.closed:
            points = _polyline_points(entity)
            frames.append((points.min(axis=0), points.max(axis=0)))
    assert frames
    outers: dict[int, list] = {k: [] for k in range(len(frames))}
    for entity in msp:
        if entity.dxf.layer == LAYER_SHEET:
            continue
        points = _polyline_points(entity)
        lo, hi = points.min(axis=0), points.max(axis=0)
        inside = [
            k for k, (f_lo, f_hi) in enumerate(frames) if np.all(lo >= f_lo) and np.all(hi <= f_hi)
        ]
        assert len(inside) == 1, "an entity lies outside every sheet"
        if entity.dxf.layer == LAYER_CUT_OUTER:
            outers[inside[0]].append((lo, hi))
    count = sum(len(v) for v in outers.values())
    expected = len(built.flat.pads) if name == "hinges.dxf" else 6 * len(built.flat.tiles)
    assert count == expected
    for boxes in outers.values():
        for (lo_a, hi_a), (lo_b, hi_b) in itertools.combinations(boxes, 2):
            assert np.any(hi_a <= lo_b) or np.any(hi_b <= lo_a), "nested parts overlap"


def test_strip_numbers_that_turned_read_as_another_are_underlined(built: Built) -> None:
    # A cut strip is a loose part: turned over, its "6" is a "9" (a review), so such numbers
    # get one more stroke, a line under the number inside the strip; the others do not.
    if built.profile.process == "fdm-dual":
        pytest.skip("no cut hinges")
    from drawstring.cad.magnets_labels import reads_as_another
    from drawstring.fabrication.parts import STRIP_UNDERLINE_DROP, strip_part

    d, profile = built.design, built.profile
    seen = set()
    for h, pad in zip(built.flat.pad_hinge, built.flat.pads, strict=True):
        part, fits = strip_part(
            int(h), pad, d.tiles_2d, d.linkage.hinges[h], d.hinge_side[h],
            profile.hinge_width_mm, 0.5 * profile.hinge_pad_length_mm,
        )  # fmt: skip
        if not fits:
            continue
        a, b = int(d.linkage.hinges[h][0]), int(d.linkage.hinges[h][2])
        glyphs = sum(len(text_strokes(str(t), 1.0, np.zeros(2))) for t in (a, b))
        lines = sum(reads_as_another(str(t)) for t in (a, b))
        assert len(part.strokes) == glyphs + lines
        seen.add(lines > 0)
        # every stroke, underlines included, lies inside the strip's outline
        assert all(_inside_polygon(part.outline, p) for stroke in part.strokes for p in stroke)
    assert seen == {True, False}
    assert STRIP_UNDERLINE_DROP < 1.0


def _inside_polygon(polygon: np.ndarray, point: np.ndarray) -> bool:
    a, b = polygon, np.roll(polygon, -1, axis=0)
    spans = (a[:, 1] > point[1]) != (b[:, 1] > point[1])
    with np.errstate(divide="ignore", invalid="ignore"):
        cross = a[:, 0] + (point[1] - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    return bool((spans & (point[0] < cross)).sum() % 2 == 1)


def test_hinge_strips_are_kerf_compensated(built: Built) -> None:
    if built.profile.process == "fdm-dual":
        pytest.skip("no cut hinges")
    from drawstring.fabrication.parts import planar_outline

    doc = ezdxf.readfile(built.folder / "fabrication" / "hinges.dxf")
    cut = sum(
        abs(signed_area(_polyline_points(e)))
        for e in doc.modelspace().query(f"LWPOLYLINE[layer=='{LAYER_CUT_OUTER}']")
    )
    expected = 0.0
    for pad in built.flat.pads:
        outline = planar_outline(pad)[0]
        perimeter = float(np.linalg.norm(np.roll(outline, -1, axis=0) - outline, axis=1).sum())
        expected += abs(signed_area(outline)) + 0.5 * built.profile.kerf_mm * perimeter
    assert cut == pytest.approx(expected, rel=2e-3)
    assert cut > sum(abs(signed_area(planar_outline(p)[0])) for p in built.flat.pads)


def test_plywood_cutlist_known_dihedral(built: Built) -> None:
    if built.profile.process != "plywood-cnc":
        pytest.skip("plywood only")
    rows = list(csv.DictReader((built.folder / "fabrication" / "cutlist.csv").open()))
    assert len(rows) == 6 * len(built.flat.tiles)
    # Cylinder tiles: top and side faces 1 and 3 meet at 90 - half the angular step.
    step = np.degrees(2 * np.arcsin(PLYWOOD_SIDE / (2 * PLYWOOD_RADIUS)))
    angles = {
        float(row[f"edge{k}_dihedral_deg"]) for row in rows if row["face"] == "T" for k in range(4)
    }
    assert min(angles) == pytest.approx(90 - 0.5 * step, abs=0.01)
    assert max(angles) == pytest.approx(90.0, abs=0.01)
    assert sum(int(row["holes"]) for row in rows) > 0


def test_outputs_state_the_measured_mass_and_route(built: Built) -> None:
    """bom.csv, manifest.json and assembly.md give the same mass, route and string length,
    the ones measured on the solids and the channels."""
    from drawstring.cad.checks import _opening
    from drawstring.cad.design import route_links
    from drawstring.cad.features import channel_radius
    from drawstring.cad.paths import route_openings
    from drawstring.fabrication.measures import measure_fabrication
    from drawstring.fabrication.panels import panel_holes, plywood_panels

    d, profile, cad = built.design, built.profile, built.flat
    measures = measure_fabrication(
        profile, d.tiles_2d, d.tiles_3d, d.route_steps, d.lift_tiles, cad,
        hinges=d.linkage.hinges, hinge_side=d.hinge_side,
    )  # fmt: skip
    # The masses: the solids' volumes (plywood: the panels, with every hole) times the densities.
    if profile.process == "plywood-cnc":
        steps = normalize_route(d.route_steps)
        holes = panel_holes(profile, d.tiles_2d, d.tiles_3d, d.linkage.hinges, d.hinge_side, cad)
        panels, _ = plywood_panels(profile, d.tiles_2d, steps, d.lift_tiles, *holes)
        area = sum(p.area for p in panels)
        tile_g = area * profile.panel_thickness_mm * profile.density_kg_m3 * 1e-6
    else:
        volume = sum(s.volume for s in cad.tiles)
        tile_g = volume * profile.density_kg_m3 * profile.infill_fraction * 1e-6
    hinge_g = sum(s.volume for s in cad.pads) * profile.hinge_density_kg_m3 * 1e-6
    assert measures.tile_mass_g == pytest.approx(tile_g, abs=0.051)
    assert measures.hinge_mass_g == pytest.approx(hinge_g, abs=0.051)
    assert measures.mass_g == round(measures.tile_mass_g + measures.hinge_mass_g, 1)
    # The route: inside the channels, then straight from each opening to the next, and those
    # straight runs are where the holes are on the solids.
    steps = normalize_route(d.route_steps)
    entry, exit_, inside = route_openings(d.tiles_2d, steps)
    between = np.linalg.norm(np.roll(entry, -1, axis=0) - exit_, axis=1)
    assert measures.route_flat_mm == round(float(inside.sum() + between.sum()), 1)
    radius = channel_radius(profile)
    for tile_a, side_a, tile_b, side_b in route_links(steps):
        k = next(i for i in range(len(steps)) if steps[i, 1] == tile_a and steps[i, 3] == side_a)
        hole_a = _opening(cad.tiles[tile_a], d.tiles_2d[tile_a], side_a, radius)
        hole_b = _opening(cad.tiles[tile_b], d.tiles_2d[tile_b], side_b, radius)
        assert hole_a is not None and hole_b is not None
        assert float(np.linalg.norm(hole_b - hole_a)) == pytest.approx(between[k], abs=0.05)

    rows = {r["item"]: r for r in csv.DictReader((built.folder / "fabrication/bom.csv").open())}
    tile_item = "panel" if profile.process == "plywood-cnc" else "tile"
    hinge_item = "hinge pad" if profile.process == "fdm-dual" else "hinge strip"
    assert float(rows[tile_item]["mass_g"]) == measures.tile_mass_g
    assert float(rows[hinge_item]["mass_g"]) == measures.hinge_mass_g
    assert rows["mass"]["description"] == f"{measures.mass_g} g"
    assert float(rows["string"]["length_mm"]) == measures.string_mm
    # string mass: its round section times its length times its density (kg/m^3 = 1e-6 g/mm^3)
    section = np.pi * (0.5 * profile.string_diameter_mm) ** 2
    string_g = section * measures.string_mm * profile.string_density_kg_m3 * 1e-6
    assert float(rows["string"]["mass_g"]) == pytest.approx(string_g, abs=0.051)
    assert float(rows["string"]["mass_g"]) > 0
    assert f"flat route {measures.route_flat_mm / 1000:.3f} m" in rows["string"]["note"]
    manifest = json.loads((built.folder / "fabrication/manifest.json").read_text())
    estimates = manifest["estimates"]
    assert estimates["mass_g"] == measures.mass_g
    assert estimates["tile_mass_g"] == measures.tile_mass_g
    assert estimates["hinge_mass_g"] == measures.hinge_mass_g
    assert estimates["flat_route_length_mm"] == measures.route_flat_mm
    assert estimates["string_length_mm"] == measures.string_mm
    guide = (built.folder / "fabrication/assembly.md").read_text()
    assert f"**{measures.string_mm / 1000:.2f} m**" in guide


def test_bom_counts_the_screws_of_the_holes_cut(built: Built) -> None:
    """One screw per pilot hole: counted on the tile solids (blind cylinders of the screw
    radius), not assumed two per tile per hinge."""
    if built.profile.hinge_interlock != "screws":
        pytest.skip("plywood screws only")
    radius = 0.5 * float(np.clip(0.12 * built.profile.hinge_width_mm, 2.0, 5.0))
    holes = sum(
        face.geom_type == bd.GeomType.CYLINDER
        and face.radius is not None
        and abs(face.radius - radius) < 1e-6
        for solid in built.flat.tiles
        for face in solid.faces()
    )
    rows = {r["item"]: r for r in csv.DictReader((built.folder / "fabrication/bom.csv").open())}
    assert holes > 0 and int(rows["screw"]["count"]) == holes == built.flat.fasteners
    # what to buy: a screw for the pilot hole, long enough for the strip and the panel
    grip = built.profile.hinge_thickness_mm + built.profile.panel_thickness_mm
    assert (
        f"for a {2 * radius:g} mm pilot hole, at least {grip:g} mm long"
        in (rows["screw"]["description"])
    )


def test_bom_string_and_magnets(built: Built) -> None:
    rows = list(csv.DictReader((built.folder / "fabrication" / "bom.csv").open()))
    items = {row["item"]: row for row in rows}
    assert float(items["string"]["length_mm"]) > 0
    assert "x 1.2" in items["string"]["note"]
    if built.flat.magnets:
        assert int(items["magnet"]["count"]) == 2 * len(built.flat.magnets)
        assert " N out" in items["magnet"]["note"] and " S out" in items["magnet"]["note"]
        # discs of NdFeB at 7.5 g/cm^3
        disc = (
            math.pi * (built.profile.magnet_diameter_mm / 2) ** 2 * built.profile.magnet_height_mm
        )
        expected = 2 * len(built.flat.magnets) * disc * 7.5e-3
        assert float(items["magnet"]["mass_g"]) == pytest.approx(expected, abs=0.05)


def test_print_jobs_split_along_rows_or_refuse() -> None:
    design = cylinder_design((4, 3))
    tiles = design.tiles_2d
    span = np.ptp(tiles[:, :, :2].reshape(-1, 2), axis=0)
    jobs, cut = plan_print_jobs(tiles, design.linkage.hinges, (0.6 * span[0] + 10, span[1] + 20))
    assert len(jobs) >= 2 and cut
    assert sorted(t for job in jobs for t in job.tiles) == list(range(len(tiles)))
    for job in jobs:
        assert job.size[0] <= 0.6 * span[0] and job.size[1] <= span[1] + 10
    with pytest.raises(InputError, match="does not fit the 12 x 12 mm bed"):
        plan_print_jobs(tiles, design.linkage.hinges, (12.0, 12.0))


def test_the_guide_names_the_tiles_without_a_number(built: Built, tmp_path: Path) -> None:
    """Tiles too small for the engraved digits are named in the guide, not said to carry
    their number."""
    if built.profile.process == "plywood-cnc":
        pytest.skip("plywood panels are labelled on their inner faces")
    _write(
        dataclasses.replace(built, flat=dataclasses.replace(built.flat, unlabelled=(1, 3))),
        tmp_path,
    )
    guide = (tmp_path / "fabrication/assembly.md").read_text()
    assert "2 tiles too small for the digits carry no number (tiles 1, 3)" in guide
    plain = (built.folder / "fabrication/assembly.md").read_text()
    assert ("carry no number" in plain) == bool(built.flat.unlabelled)


def test_what_the_guide_asks_for_is_in_the_bom(built: Built) -> None:
    """A user-acceptance review: the fdm guide asked for glue the BOM did not list, the
    plywood guide said to knot a steel cable, and the laser guide laid tiles top up "by
    number" with the numbers under them."""
    guide = (built.folder / "fabrication/assembly.md").read_text()
    bom = list(csv.DictReader((built.folder / "fabrication/bom.csv").open()))
    items = [row["item"] for row in bom]
    if re.search(r"\b[Gg]lue", guide.replace("glued", "")):
        assert "glue" in items
    cable = built.profile.process == "plywood-cnc"  # vinyl-coated stainless steel cable
    assert ("knot the two ends" in guide) != cable
    assert ("crimp ferrule" in guide) == cable == ("ferrule" in items)
    if built.profile.process == "laser-epdm":
        assert "top faces up by number (read each tile's number in its bottom face" in guide
    if built.profile.process == "plywood-cnc":  # numbers inside the boxes: pencilled outside
        assert "pencil each box's number on its bottom as you glue it" in guide
        assert "channel tubes" in next(r["description"] for r in bom if r["item"] == "glue")
    if "Glue the magnets" in guide or "glue them from inside" in guide:
        assert "magnets" in " ".join(r["description"] for r in bom if r["item"] == "glue")
    if built.profile.process == "fdm-dual":
        magnets = bool(len(built.design.magnet_pairs))
        glue = [row["description"] for row in bom if row["item"] == "glue"]
        assert glue == (["CA (cyanoacrylate) glue for the magnets"] if magnets else [])


def test_plywood_channel_tubes_name_their_tile_and_step(built: Built) -> None:
    """Each channel tube in manifest.json carries its tile and route step (or lift bore), in
    route order, with the length bom.csv counts."""
    if built.profile.process != "plywood-cnc":
        pytest.skip("plywood-cnc only")
    manifest = json.loads((built.folder / "fabrication/manifest.json").read_text())
    tubes = manifest["estimates"]["channel_tubes"]
    steps = normalize_route(built.design.route_steps)  # (S, 4): gap, tile, enter, leave
    lifts = np.asarray(built.design.lift_tiles).reshape(-1, 2)
    assert len(tubes) == len(steps) + len(lifts)
    assert [t["route_step"] for t in tubes[: len(steps)]] == list(range(len(steps)))
    assert [t["tile"] for t in tubes[: len(steps)]] == [int(t) for t in steps[:, 1]]
    assert [t["lift_bore"] for t in tubes[len(steps) :]] == list(range(len(lifts)))
    assert [t["tile"] for t in tubes[len(steps) :]] == [int(t) for t in lifts[:, 0]]
    assert [t["length_mm"] for t in tubes] == manifest["estimates"]["channel_tubes_mm"]


def test_the_plywood_guide_names_the_tiles_to_trim(built: Built, tmp_path: Path) -> None:
    """Plywood panels make whole boxes: the tiles whose overlap the hinge stage cuts away
    (trims) are named in the guide, to be sawn or sanded off after gluing."""
    if built.profile.process != "plywood-cnc":
        pytest.skip("plywood-cnc only")
    design = dataclasses.replace(built.design, trims={4: [], 7: []})
    _write(dataclasses.replace(built, design=design), tmp_path)
    guide = (tmp_path / "fabrication/assembly.md").read_text()
    assert "2 tiles overlap a hinged neighbour in the flat pose (tiles 4, 7;" in guide
    plain = (built.folder / "fabrication/assembly.md").read_text()
    assert ("overlap a hinged neighbour" in plain) == bool(built.design.trims)


def test_loose_tiles_are_nested_on_the_beds_and_the_guide_lists_them(
    built: Built, tmp_path: Path
) -> None:
    """laser-epdm on a bed smaller than the layout: the loose tiles are turned and nested, each
    once, apart from the others, on as few beds as the packing needs; each bed is one object
    of tiles.3mf and has its own file, and assembly.md lists every bed's tiles."""
    if built.profile.process != "laser-epdm":
        pytest.skip("laser-epdm only")
    span = np.ptp(built.design.tiles_2d[:, :, :2].reshape(-1, 2), axis=0)
    bed = (float(0.6 * span[0] + 10), float(span[1] + 20))
    # no printer preset: the profile's own [machine] bed
    small = dataclasses.replace(built.profile, bed_x_mm=bed[0], bed_y_mm=bed[1], printer="")
    _write(dataclasses.replace(built, profile=small), tmp_path)
    manifest = json.loads((tmp_path / "fabrication/manifest.json").read_text())
    jobs = manifest["print_jobs"]
    assert [job["bed"] for job in jobs] == list(range(1, len(jobs) + 1))
    n_tiles = len(built.design.tiles_2d)
    assert sorted(t for job in jobs for t in job["tiles"]) == list(range(n_tiles))
    guide = (tmp_path / "fabrication/assembly.md").read_text()
    for job in jobs:
        assert f"- bed {job['bed']}: tiles {id_runs(job['tiles'])}" in guide
    # every tile is on its bed, keeps its volume, and its footprint (convex hull) stays
    # TILE_SPACING_MM clear of the others': some axis (an edge normal, x or y) separates them
    from scipy.spatial import ConvexHull

    volumes = []
    footprint_area = 0.0
    for job in jobs:
        name = f"tiles-bed{job['bed']}.3mf" if len(jobs) > 1 else "tiles.3mf"
        ((_, bed_vertices, bed_triangles),) = _read_3mf(tmp_path / "fabrication" / name)
        pieces = _components(bed_vertices, bed_triangles)
        assert len(pieces) == len(job["tiles"])
        hulls = []
        for vertices, triangles in pieces:
            assert np.all(vertices[:, :2] >= BED_MARGIN_MM - 1e-6)
            assert np.all(vertices[:, :2] <= np.array(bed) - BED_MARGIN_MM + 1e-6)
            tri = vertices[triangles]
            volumes.append(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum())
            hull = ConvexHull(vertices[:, :2])
            hulls.append(vertices[hull.vertices, :2])
            footprint_area += hull.volume
        for i, a in enumerate(hulls):
            for b in hulls[i + 1 :]:
                axes = [np.roll(p, -1, axis=0) - p for p in (a, b)]
                normals = np.vstack([*(e[:, ::-1] * [1.0, -1.0] for e in axes), np.eye(2)])
                normals /= np.linalg.norm(normals, axis=1, keepdims=True)
                pa, pb = a @ normals.T, b @ normals.T
                gap = np.maximum(pb.min(axis=0) - pa.max(axis=0), pa.min(axis=0) - pb.max(axis=0))
                assert gap.max() >= TILE_SPACING_MM - 1e-6
    expected = sorted(solid.volume for solid in built.flat.tiles)
    np.testing.assert_allclose(sorted(np.array(volumes) / 6.0), expected, rtol=0.01)
    # the tiles take far fewer beds than bands of the flat layout (whose gaps are wasted)
    usable = (bed[0] - 2 * BED_MARGIN_MM) * (bed[1] - 2 * BED_MARGIN_MM)
    assert len(jobs) <= math.ceil(2.0 * footprint_area / usable)


def test_offset_and_shelf_pack_known_answers() -> None:
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    assert signed_area(offset_polygon(square, 0.1)) == pytest.approx(1.44)
    assert signed_area(offset_polygon(square[::-1], -0.1)) == pytest.approx(-0.64)
    sizes = np.array([[30.0, 10.0], [10.0, 40.0], [25.0, 25.0], [50.0, 5.0]])
    sheet, position, turned = shelf_pack(sizes, (60.0, 45.0), 2.0, 1.0)
    placed = np.where(turned[:, None], sizes[:, ::-1], sizes)
    for i, j in itertools.combinations(range(len(sizes)), 2):
        if sheet[i] == sheet[j]:
            a_lo, a_hi = position[i], position[i] + placed[i]
            b_lo, b_hi = position[j], position[j] + placed[j]
            assert np.any(a_hi <= b_lo) or np.any(b_hi <= a_lo)
    assert np.all(position + placed <= [59.0, 44.0])
    with pytest.raises(InputError, match="does not fit"):
        shelf_pack(np.array([[100.0, 100.0]]), (60.0, 45.0), 2.0, 1.0)
    # a small part goes back to the first sheet that has room for it
    boxes = np.array([[40.0, 30.0], [40.0, 30.0], [15.0, 10.0]])
    sheet, position, turned = shelf_pack(boxes, (60.0, 45.0), 2.0, 1.0, long_side_x=False)
    assert sheet.tolist() == [0, 1, 0] and not turned.any()
    assert np.allclose(position, [[1.0, 1.0], [1.0, 1.0], [43.0, 1.0]])
    # turned only where it fits no other way
    sheet, _, turned = shelf_pack(np.array([[20.0, 40.0], [50.0, 10.0]]), (45.0, 60.0), 2.0, 1.0,
                                  long_side_x=False)  # fmt: skip
    assert turned.tolist() == [False, True]
    with pytest.raises(InputError, match="does not fit"):
        shelf_pack(np.array([[50.0, 10.0]]), (45.0, 60.0), 2.0, 1.0, turn=False)


def test_nested_labels_read_forwards_so_a_six_stays_a_six() -> None:
    # A strip engraved "6" along its length, drawn at every eighth of a turn: the nesting turns
    # each to its smallest bounding rectangle, which left about half of them upside down (a
    # user-acceptance review read tile 8's strip as "6 8" and 56's as "95").  Turned half a
    # turn more where needed, every label reads left to right or upwards, the engraving is the
    # upright "6" drawn where it lies, and the parts still fit their sheet without overlap.
    strip = np.array([[-6.0, -1.0], [6.0, -1.0], [6.0, 1.0], [-6.0, 1.0]])
    parts = []
    for k in range(8):
        angle = 0.25 * np.pi * k + 0.1
        outline = rotate(strip, angle) + [3.0 * k, 1.0]
        strokes = text_strokes("6", 1.5, outline.mean(axis=0), angle)
        parts.append(Part2D(f"strip_{k}", outline, strokes=strokes, text_angle=angle))
    nesting = nest_parts(parts, (60.0, 40.0), kerf=0.0, spacing=1.0)
    placed = [part for sheet in nesting.sheets for part in sheet]
    assert len(placed) == 8
    for part in placed:
        assert part.text_angle is not None and reads_forwards(part.text_angle)
        upright = text_strokes("6", 1.5, part.outline.mean(axis=0), part.text_angle)
        assert all(np.allclose(a, b, atol=1e-9) for a, b in zip(part.strokes, upright, strict=True))
        assert np.all(part.outline >= 0.0) and np.all(part.outline <= [60.0, 40.0])
    turned = [k for k in range(8) if not reads_forwards(0.25 * np.pi * k + 0.1)]
    assert turned, "some strips start upside down"


def test_a_design_states_one_mass_and_route_length_everywhere(tmp_path: Path) -> None:
    """design.json (metrics.cad), route.json, bom.csv, manifest.json and assembly.md of one
    design agree on the measured route, string and mass."""
    from drawstring.output.folder import write_design
    from drawstring.pipeline.record import DesignOptions
    from drawstring.pipeline.run import design

    options = DesignOptions(grid=(3, 3), resolution=1500, simulate=False)
    out = write_design(design("saddle", options), tmp_path / "saddle")
    metrics = json.loads((out / "design.json").read_text())["metrics"]
    cad = metrics["cad"]
    route = json.loads((out / "route.json").read_text())
    estimates = json.loads((out / "fabrication/manifest.json").read_text())["estimates"]
    rows = {r["item"]: r for r in csv.DictReader((out / "fabrication/bom.csv").open())}
    guide = (out / "fabrication/assembly.md").read_text()

    flat, assembled = cad["route_length_mm"]["flat"], cad["route_length_mm"]["assembled"]
    assert route["length_flat_mm"] == flat == estimates["flat_route_length_mm"]
    assert route["length_assembled_mm"] == assembled < flat
    assert metrics["route"]["length_mm"] == {"flat": flat, "assembled": assembled}
    assert f"flat route {flat / 1000:.3f} m" in rows["string"]["note"]
    string = cad["string_length_mm"]
    assert string == estimates["string_length_mm"] == float(rows["string"]["length_mm"])
    assert f"**{string / 1000:.2f} m**" in guide
    assert metrics["mass_g"] == cad["mass_g"] == estimates["mass_g"]
    assert cad["mass_g"] == float(rows["mass"]["description"][:-2])
    assert cad["tile_mass_g"] == estimates["tile_mass_g"] == float(rows["tile"]["mass_g"])
    assert cad["hinge_mass_g"] == estimates["hinge_mass_g"] == float(rows["hinge pad"]["mass_g"])
    assert cad["mass_g"] == round(cad["tile_mass_g"] + cad["hinge_mass_g"], 1)
    # printed together, the hinged tiles are relieved to stay a nozzle apart (measured on the
    # solids; test_printed_tiles_stay_a_nozzle_apart reads a print.3mf back)
    assert cad["print_clearance_mm"] == 0.4 and cad["tile_pairs_closer"] == 0
    assert 0.4 - PRINT_GAP_TOL_MM <= cad["tile_gap_min_mm"] < 0.45


# --------------------------------------------------------------------------------------------
# assembly guide


def test_assembly_sections_are_numbered_in_order(built: Built) -> None:
    import re

    guide = (built.folder / "fabrication" / "assembly.md").read_text()
    numbers = [int(n) for n in re.findall(r"^## (\d+)\. ", guide, flags=re.M)]
    assert numbers == list(range(1, len(numbers) + 1)) and len(numbers) >= 4
    # The sample's route enters its first tile and leaves its last through the top face: one
    # lift point, where both string ends stand up; the spare lift bore is named.
    steps = normalize_route(built.design.route_steps)
    first, last = int(steps[0, 1]), int(steps[-1, 1])
    lines = guide.splitlines()
    assert any(
        line.startswith(f"1. tile {first}:") and "in through the top face ▼ at lift point A" in line
        for line in lines
    )
    assert any(
        line.startswith(f"{len(steps)}. tile {last}:")
        and "out through the top face ▲ at lift point A" in line
        for line in lines
    )
    tile, side = built.design.lift_tiles[0]
    assert f"tile {tile} side {side}" in guide
    assert "string ends at lift point A" in guide


def _ring_route() -> tuple[object, object, list[int]]:
    """A closed route round a 4 x 3 grid with two lift gaps, as the pipeline builds it."""
    from drawstring.geometry.route.result import Route
    from drawstring.geometry.tiling.linkage import build_linkage

    link = build_linkage(np.ones((4, 3), dtype=bool))
    ring = [(0, 0), (1, 0), (2, 0), (3, 0), (3, 1), (3, 2), (2, 2), (1, 2), (0, 2), (0, 1)]
    index = {tuple(c): t for t, c in enumerate(link.tile_cells.tolist())}
    tiles = [index[c] for c in ring]
    towards = {(0, -1): 0, (1, 0): 1, (0, 1): 2, (-1, 0): 3}

    def side(a: int, b: int) -> int:
        di, dj = (link.tile_cells[b] - link.tile_cells[a]).tolist()
        return towards[(di, dj)]

    count = len(tiles)
    enter = [side(t, tiles[k - 1]) for k, t in enumerate(tiles)]
    leave = [side(t, tiles[(k + 1) % count]) for k, t in enumerate(tiles)]
    gaps: list[int] = []
    for k, t in enumerate(tiles):  # a gap by both tiles, else one by this tile
        near = [g for g in range(link.n_gaps) if t in link.gap_tiles(g).tolist()]
        both = [g for g in near if tiles[k - 1] in link.gap_tiles(g).tolist()]
        fresh = [g for g in both + near if g not in gaps]
        gaps.append((fresh or both or near)[0])
    route = Route(
        gaps=np.array(gaps),
        labels=np.zeros(count, dtype=np.int64),
        tiles=np.array(tiles),
        enter_side=np.array(enter),
        leave_side=np.array(leave),
        turn_angle_total_rad=0.0,
        method="test",
        lower_bound_rad=None,
        crossings=0,
        boundary_tiles_covered=True,
        length_flat_mm=0.0,
    )
    once = [k for k in range(1, count) if gaps.count(gaps[k]) == 1]
    return link, route, [gaps[once[1]], gaps[once[-2]]]


def test_every_lift_exit_of_route_json_is_in_assembly_md(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import re

    from drawstring.geometry.route.result import route_to_json
    from drawstring.geometry.tiling.linkage import gap_centroids, rotating_squares_layout
    from drawstring.output import pictures as picture_files
    from drawstring.output.assembly_pictures import write_pictures
    from drawstring.output.assembly_text import write_assembly
    from drawstring.pipeline.cad_stage import lift_exits, route_steps

    link, route, lift_gaps = _ring_route()
    top = rotating_squares_layout(link, 0.4, 12.0)
    tiles = np.zeros((link.n_tiles, 8, 3))
    tiles[:, :4, :2], tiles[:, 4:, :2], tiles[:, :4, 2] = top, top, 6.0
    document = route_to_json(route, link, gap_centroids(link, top), lift_gaps=lift_gaps)
    exits = [p for p in document["lift_points"] if p.get("exit") == "top"]
    assert len(exits) == 2
    steps, lifts = route_steps(route), lift_exits(route, np.array(lift_gaps))
    figures = []
    monkeypatch.setattr(
        picture_files, "save", lambda fig, path, **_: figures.append((fig, path.name))
    )
    pictures = write_pictures(
        tmp_path, tiles, tiles, link.hinges, ["top"] * link.n_hinges, steps, lifts
    )
    record = ExportRecord(
        estimates={
            "string_length_mm": 900.0,
            "string_rule": "rule",
            "flat_route_length_mm": 500.0,
            "string_tail_mm": 150.0,
        }
    )
    record.sheets = {"hinges": {"sheets": 1}}
    write_assembly(
        tmp_path / "assembly.md",
        load_profile("laser-epdm"),
        "ring",
        record,
        link.hinges,
        ["top"] * link.n_hinges,
        steps,
        lifts,
        [],
        [],
        pictures,
    )
    lines = (tmp_path / "assembly.md").read_text().splitlines()
    numbers = [int(n) for n in re.findall(r"^## (\d+)\. ", "\n".join(lines), flags=re.M)]
    assert numbers == list(range(1, len(numbers) + 1))
    letters = set()
    for lift in exits:
        up = [line for line in lines if f". tile {lift['arrive_tile']}: " in line]
        down = [line for line in lines if f". tile {lift['depart_tile']}: " in line]
        assert len(up) == len(down) == 1
        letter = re.search(r"out through the top face ▲ at lift point (\w)", up[0])
        assert letter is not None, up[0]
        assert f"in through the top face ▼ at lift point {letter[1]}" in down[0]
        letters.add(letter[1])
    assert letters == {"A", "B"}
    # The threading picture draws what its legend lists: one ▲ and one ▼ per lift point.
    (threading,) = [fig for fig, name in figures if name == "assembly-threading.png"]
    ax = threading.axes[0]
    drawn = [line.get_marker() for line in ax.lines if len(line.get_xdata())]
    assert drawn.count("^") == drawn.count("v") == 2
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "string comes up out of the top face" in legend
    assert "string goes back down into the top face" in legend


def test_threading_labels_do_not_overlap() -> None:
    from drawstring.output.pictures import place_labels

    rng = np.random.default_rng(3)
    anchors = np.vstack([rng.normal(0.0, 8.0, (40, 2)), [[0.0, 0.0]] * 5])  # a dense cluster
    sizes = np.tile([14.0, 10.0], (len(anchors), 1))
    placed = place_labels(anchors, sizes, blocked=np.array([[-5.0, -5.0, 5.0, 5.0]]))
    boxes = np.hstack([placed - sizes / 2, placed + sizes / 2])
    for a, b in itertools.combinations(range(len(boxes)), 2):
        p, q = boxes[a], boxes[b]
        assert not (p[0] < q[2] and q[0] < p[2] and p[1] < q[3] and q[1] < p[3]), (a, b)
    for box in boxes:  # none over the blocked box either
        assert not (box[0] < 5 and -5 < box[2] and box[1] < 5 and -5 < box[3])


def test_placement_marks_hinges_as_every_picture_does(built: Built) -> None:
    # Top-face strips blue with a circle, bottom-face strips orange with a square (black-edged
    # markers), as flat.png and the assembly pictures; the guide says the same.
    if "placement.svg" not in EXPECTED[built.profile.process]:
        pytest.skip(f"no placement template for {built.profile.process}")
    from drawstring.fabrication.parts import PLACEMENT_HINGES
    from drawstring.output.pictures import BOTTOM_HINGE, TOP_HINGE

    top, bottom = PLACEMENT_HINGES["top"], PLACEMENT_HINGES["bottom"]
    assert (top.colour, top.marker) == (TOP_HINGE["colour"], "circle")
    assert (bottom.colour, bottom.marker) == (BOTTOM_HINGE["colour"], "square")
    sides = [built.design.hinge_side[int(h)] for h in built.flat.pad_hinge]
    counts = {"top": sides.count("top"), "bottom": sides.count("bottom")}
    assert counts["top"] and counts["bottom"]  # the sample has hinges on both faces
    root = ET.parse(built.folder / "fabrication" / "placement.svg").getroot()
    svg = "{http://www.w3.org/2000/svg}"
    strokes = [e.get("stroke") for e in root.iter(f"{svg}polygon")]
    assert strokes.count(top.colour) == counts["top"]
    assert strokes.count(bottom.colour) == counts["bottom"]
    assert "#c02090" not in (built.folder / "fabrication" / "placement.svg").read_text()
    circles, squares = list(root.iter(f"{svg}circle")), list(root.iter(f"{svg}rect"))
    assert [c.get("fill") for c in circles] == [top.colour] * counts["top"]
    assert [r.get("fill") for r in squares] == [bottom.colour] * counts["bottom"]
    assert {e.get("stroke") for e in circles + squares} == {"#000000"}
    doc = ezdxf.readfile(built.folder / "fabrication" / "placement.dxf")
    for style, count in ((top, counts["top"]), (bottom, counts["bottom"])):
        layer = doc.layers.get(style.layer)
        assert layer.color == style.aci and layer.rgb == style.rgb
        entities = doc.modelspace().query(f"*[layer=='{style.layer}']")
        assert len(entities) == 2 * count  # the strip and its marker
        kinds = {e.dxftype() for e in entities}
        assert kinds == ({"LWPOLYLINE", "CIRCLE"} if style is top else {"LWPOLYLINE"})
    # the template seen from below: the bottom strips only, mirrored, tiles and numbers too
    below = ezdxf.readfile(built.folder / "fabrication" / "placement-bottom.dxf").modelspace()
    assert len(below.query(f"*[layer=='{bottom.layer}']")) == 2 * counts["bottom"]
    assert len(below.query(f"*[layer=='{top.layer}']")) == 0
    above = doc.modelspace()
    for layer in ("TILE_TOP", "LABEL"):
        assert len(below.query(f"*[layer=='{layer}']")) == len(above.query(f"*[layer=='{layer}']"))

    def outline_xs(modelspace: Any) -> np.ndarray:
        return np.array(
            [p[0] for e in modelspace.query("LWPOLYLINE[layer=='TILE_TOP']") for p in e]
        )

    # both templates start 10 mm in from their left edge: mirrored, x -> width - x
    xs, xs_below = outline_xs(above), outline_xs(below)
    assert np.ptp(xs) == pytest.approx(np.ptp(xs_below))
    np.testing.assert_allclose(np.sort(xs_below), np.sort(xs.min() + xs.max() - xs), atol=1e-3)
    guide = (built.folder / "fabrication" / "assembly.md").read_text()
    assert "orange, marked with a square: on the bottom faces" in guide and "pink" not in guide
    assert "lay the tiles on it top faces down" in guide
    # laser tiles carry their numbers in their bottom faces, plywood boxes inside
    if built.profile.process == "laser-epdm":
        assert "by the numbers in their bottom faces" in guide
    else:
        assert "pencil each box's number on its bottom" in guide
    # the guide gives the template's printed size, as the SVG states it in mm
    width, height = (float(root.get(k, "0").removesuffix("mm")) for k in ("width", "height"))
    assert f"it is {round(width, 1):g} x {round(height, 1):g} mm" in guide


def test_stops_past_z_get_two_letters() -> None:
    from drawstring.output.assembly_order import stop_label

    labels = [stop_label(k) for k in range(30)]
    assert labels[:3] == ["A", "B", "C"] and labels[25:28] == ["Z", "AA", "AB"]
    assert len(set(labels)) == 30


def test_the_route_length_goes_up_over_and_down_the_lift_bores() -> None:
    from drawstring.cad.paths import lift_path, route_length

    # a 2 x 2 block of 10 mm boxes, 3 mm thick, touching; the loop 0 -> 1 -> 3 -> 2 -> 0
    offsets = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)
    cells = np.array([[0, 0], [1, 0], [0, 1], [1, 1]], dtype=float)
    top = np.concatenate([(cells[:, None] + offsets) * 10.0, np.zeros((4, 4, 1))], axis=2)
    tiles = np.concatenate([top, top - [0.0, 0.0, 3.0]], axis=1)
    steps = np.array([[0, 0, 2, 1], [1, 1, 3, 2], [2, 3, 0, 3], [3, 2, 1, 0]])
    plain = route_length(tiles, steps)
    bores = np.array([[0, 1], [1, 3]])  # the string is pulled up between tiles 0 and 1
    lifted = route_length(tiles, steps, bores)
    up, down = lift_path(tiles[0], 1), lift_path(tiles[1], 3)
    assert up.arc[2][2] == pytest.approx(0.0) and down.arc[2][2] == pytest.approx(0.0)
    over = float(np.linalg.norm(down.arc[2] - up.arc[2]))
    # each bore climbs half the thickness at least; the faces touch, so straight across is 0
    assert lifted - plain >= over + 3.0 - 1e-9
    assert lifted - plain <= over + 2 * (1.5 + 10.0)
    # a bore on one side only is not a lift crossing
    assert route_length(tiles, steps, bores[:1]) == pytest.approx(plain)
    # the same in any pose
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    moved = tiles @ turn.T + [5.0, -2.0, 7.0]
    assert route_length(moved, steps, bores) == pytest.approx(lifted, rel=1e-12)


@pytest.mark.parametrize("stacked", [False, True])
def test_print_jobs_share_beds_where_they_fit_and_each_bed_has_a_file(
    built: Built, tmp_path: Path, stacked: bool
) -> None:
    """A layout split into jobs: jobs that fit one bed together share it (apart), and with
    more than one bed every bed also gets a file of its own with its jobs on the plate."""
    if built.profile.process != "fdm-dual":
        pytest.skip("jobs of hinged tiles only (laser-epdm nests loose tiles)")
    span = np.ptp(built.design.tiles_2d[:, :, :2].reshape(-1, 2), axis=0)
    bed = (float(0.6 * span[0] + 10), float((2.4 if stacked else 1.0) * span[1] + 30))
    # a printer with a bed this small, without a wipe tower
    small = dataclasses.replace(
        load_printer("generic-dual"), bed_x_mm=bed[0], bed_y_mm=bed[1], wipe_tower_width_mm=0.0
    )
    files = {Path(f).name for f in _write(built, tmp_path, printer=small)}
    manifest = json.loads((tmp_path / "fabrication/manifest.json").read_text())
    jobs = manifest["print_jobs"]
    beds = sorted({job["bed"] for job in jobs})
    assert len(jobs) >= 2 and beds == list(range(1, len(beds) + 1))
    # stacked: two bands of tiles fit the bed's depth, so tile jobs share beds; otherwise each
    # has its own (the loose pads of fdm-dual may join one)
    assert all(len(job["size_mm"]) == 2 for job in jobs)  # the loose pads' job too
    tile_beds = [job["bed"] for job in jobs if not job.get("loose")]
    assert (len(set(tile_beds)) < len(tile_beds)) == stacked
    stem = "print" if built.profile.process == "fdm-dual" else "tiles"
    per_bed = (
        {f"{stem}-bed{b}{ext}" for b in beds for ext in (".3mf", ".ini")}
        if len(beds) > 1
        else set()
    )
    assert per_bed <= files and not {f for f in files if "-bed" in f} - per_bed
    combined = _read_3mf(tmp_path / "fabrication" / f"{stem}.3mf")
    assert len(combined) == len(jobs)
    for b in beds:
        on_bed = [job for job in jobs if job["bed"] == b]
        meshes = _read_3mf(tmp_path / "fabrication" / f"{stem}-bed{b}.3mf") if per_bed else combined
        assert len(meshes) == len(on_bed)
        boxes = []
        for job, (_, vertices, _) in zip(on_bed, meshes, strict=True):
            low, high = vertices.min(axis=0), vertices.max(axis=0)
            # the manifest's size is the job's printed footprint (turned or not on the bed)
            assert np.allclose(sorted(high[:2] - low[:2]), sorted(job["size_mm"]), atol=0.006)
            assert np.all(low[:2] >= -1e-6) and np.all(high[:2] <= np.array(bed) + 1e-6)
            boxes.append((low[:2], high[:2]))
        for i, (lo_i, hi_i) in enumerate(boxes):  # jobs on one bed do not touch
            for lo_j, hi_j in boxes[i + 1 :]:
                assert np.any(hi_i < lo_j) or np.any(hi_j < lo_i)
    guide = (tmp_path / "fabrication/assembly.md").read_text()
    if per_bed:
        assert f"`{stem}-bed1.3mf` to `{stem}-bed{len(beds)}.3mf`" in guide
    # the loose pads are glued in (CA glue, as the guide says), and the BOM lists the glue
    assert "glue it into the recess (CA glue)" in guide
    glue = [
        r for r in csv.DictReader((tmp_path / "fabrication/bom.csv").open()) if r["item"] == "glue"
    ]
    assert len(glue) == 1 and "loose hinge pads" in glue[0]["description"]
    loose = [job for job in jobs if job.get("loose")]
    if loose:  # the guide says how to find each loose pad
        assert "in the order of this list" in guide
        listed = [int(line.split()[2].rstrip(":")) for line in guide.splitlines()
                  if line.startswith("- hinge ")]  # fmt: skip
        assert listed == [h for job in loose for h in job["pads"]]


def test_jobs_are_turned_onto_the_bed_where_they_fit_only_so() -> None:
    """The job planner may cut bands along the bed's other side; such a job is turned by 90
    degrees onto the bed, and small jobs share one."""
    from drawstring.fabrication.beds import fill_beds
    from drawstring.fabrication.mesh3mf import BED_MARGIN_MM, PartMesh

    def box(name: str, w: float, h: float) -> PartMesh:
        corners = np.array([[x, y, z] for x in (0, w) for y in (0, h) for z in (0, 3.0)])
        return PartMesh(name, "tile", corners, np.array([[0, 1, 2]]))

    bed = (100.0 + 2 * BED_MARGIN_MM, 60.0 + 2 * BED_MARGIN_MM)
    jobs = [[box("tall", 40.0, 90.0)], [box("a", 30.0, 20.0)], [box("b", 30.0, 20.0)]]
    beds = fill_beds(jobs, bed)
    assert beds == [0, 1, 1]
    turned = jobs[0][0].vertices
    assert np.allclose(np.ptp(turned[:, :2], axis=0), [90.0, 40.0])  # now 90 wide, 40 deep
    for parts in jobs:
        for part in parts:
            assert np.all(part.vertices[:, :2] >= BED_MARGIN_MM - 1e-9)
            assert np.all(part.vertices[:, :2] <= np.array(bed) - BED_MARGIN_MM + 1e-9)
    a, b = jobs[1][0].vertices, jobs[2][0].vertices
    assert a[:, 0].max() < b[:, 0].min() or b[:, 0].max() < a[:, 0].min()  # side by side


def test_nested_tiles_turn_to_fit_and_a_tile_too_large_is_refused() -> None:
    """Loose tiles are turned to their smallest bounding rectangles: a long thin tile lying
    diagonally fits a bed it would not fit as drawn; one too large for the bed is refused."""
    from drawstring.fabrication.beds import nested_tiles
    from drawstring.fabrication.mesh3mf import PartMesh

    def slab(length: float, width: float, turn_deg: float) -> PartMesh:
        corners = np.array([[x, y, z] for x in (0, length) for y in (0, width) for z in (0, 3.0)])
        c, s = np.cos(np.radians(turn_deg)), np.sin(np.radians(turn_deg))
        corners[:, :2] = corners[:, :2] @ np.array([[c, s], [-s, c]])
        return PartMesh("tile_0", "tile", corners, np.array([[0, 1, 2]]))

    bed = (100.0 + 2 * BED_MARGIN_MM, 20.0 + 2 * BED_MARGIN_MM)
    (placed,) = nested_tiles([slab(90.0, 10.0, 35.0)], bed)
    xy = placed[0].vertices[:, :2]
    assert np.allclose(np.ptp(xy, axis=0), [90.0, 10.0])
    assert np.all(xy >= BED_MARGIN_MM - 1e-9) and np.all(xy <= np.array(bed) - BED_MARGIN_MM + 1e-9)
    with pytest.raises(InputError, match="a tile does not fit the .* bed .* or more tiles"):
        nested_tiles([slab(120.0, 10.0, 0.0)], bed)


def test_loose_tiles_print_top_faces_down() -> None:
    """Loose (laser-epdm) tiles are turned over onto their flat top faces: two boxes with tops
    at z = 6 and bottoms at 0 and 0.3 mm (tiles of a mesh that is not conical differ in
    thickness) both rest on z = 0, the thinner one 5.7 mm high, and a half turn keeps every
    triangle facing outwards (the signed volume stays positive)."""
    from drawstring.fabrication.beds import nested_tiles
    from drawstring.fabrication.mesh3mf import PartMesh

    def box(z0: float, name: str) -> PartMesh:
        corners = np.array([[x, y, z] for x in (0, 10.0) for y in (0, 8.0) for z in (z0, 6.0)])
        quads = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
        triangles = np.array([t for a, b, c, d in quads for t in ([a, b, c], [a, c, d])])
        return PartMesh(name, "tile", corners, triangles)

    def volume(mesh: PartMesh) -> float:
        p = mesh.vertices[mesh.triangles]
        return float(np.einsum("ti,ti->t", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6.0)

    tiles = [box(0.0, "tile_0"), box(0.3, "tile_1")]
    assert volume(tiles[0]) == pytest.approx(480.0) and volume(tiles[1]) == pytest.approx(456.0)
    (placed,) = nested_tiles(tiles, (200.0, 200.0))
    heights = {p.name: (p.vertices[:, 2].min(), p.vertices[:, 2].max()) for p in placed}
    assert heights["tile_0"] == pytest.approx((0.0, 6.0))
    assert heights["tile_1"] == pytest.approx((0.0, 5.7))
    assert [volume(p) for p in placed] == pytest.approx([480.0, 456.0])


def test_plywood_panels_carry_the_magnet_holes_and_the_strips_pilot_holes(built: Built) -> None:
    """The box panels get every hole the solids have: the magnets' through the side panels
    (cut: wider than the tool), the hinge strips' screw pilot holes through the top or bottom
    panels and the cable holes (drilled: the DRILL layer, narrower than the 6 mm tool)."""
    if built.profile.process != "plywood-cnc":
        pytest.skip("plywood only")
    from drawstring.cad.hinge_plans import strip_hole_plans
    from drawstring.fabrication.dxf import LAYER_CUT_INNER, LAYER_DRILL

    d, profile = built.design, built.profile
    plans = strip_hole_plans(d.tiles_2d, d.linkage.hinges, list(d.hinge_side), profile)
    pilots = sum(plan.made for plan in plans)
    # two openings per route step and lift bore; a bore leaving where a channel opens shares
    # its hole
    from drawstring.fabrication.panels import cable_runs

    runs = cable_runs(d.tiles_2d, normalize_route(d.route_steps), np.asarray(d.lift_tiles))
    openings = {(r.tile, f, *np.round(p, 6)) for r in runs for f, p in r.drill_points}
    cables = len(openings)
    assert 2 * len(runs) - 2 <= cables <= 2 * len(runs)
    magnets = 2 * len(built.flat.magnets)
    assert pilots > 0 and magnets > 0
    msp = ezdxf.readfile(built.folder / "fabrication" / "panels.dxf").modelspace()

    def radii(layer: str) -> list[float]:
        found = []
        for entity in msp.query(f"LWPOLYLINE[layer=='{layer}']"):
            if len(entity) == 2:  # a circle: two half-circle arcs
                points = np.array(entity.get_points("xy"))
                found.append(round(0.5 * float(np.linalg.norm(points[1] - points[0])), 3))
        return found

    pocket = 0.5 * built.flat.magnets[0].diameter_mm
    assert 2 * pocket >= profile.tool_diameter_mm
    # cut holes are drawn on the beam's centre path, half a kerf inside
    assert radii(LAYER_CUT_INNER).count(round(pocket - 0.5 * profile.kerf_mm, 3)) == magnets
    drilled = radii(LAYER_DRILL)
    assert len(drilled) == pilots + cables
    assert drilled.count(round(plans[0].radius, 3)) >= pilots
    rows = list(csv.DictReader((built.folder / "fabrication" / "cutlist.csv").open()))
    assert sum(int(r["holes"]) for r in rows) == pilots + cables + magnets


def test_magnet_pockets_keep_their_place_on_the_face_in_another_pose() -> None:
    from drawstring.cad.magnets_labels import MagnetPair

    design = cylinder_design((3, 3))
    assembled = design.tiles_3d
    quad = assembled[4][[1, 2, 5, 6]]  # side 1 of tile 4: top 1, top 2, bottom 1, bottom 2
    centre = 0.5 * (0.3 * quad[0] + 0.7 * quad[1]) + 0.5 * (0.3 * quad[2] + 0.7 * quad[3])
    pair = MagnetPair(4, 1, 5, 3, centre, 3.0, 2.0, "N", "S", True)
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    moved = assembled @ turn.T + [10.0, -4.0, 2.0]
    (tile_a, side_a, point_a), (tile_b, side_b, _) = pair.flat_points(assembled, moved)
    assert (tile_a, side_a, tile_b, side_b) == (4, 1, 5, 3)
    np.testing.assert_allclose(point_a, turn @ centre + [10.0, -4.0, 2.0], atol=1e-9)


def test_plywood_pilot_holes_keep_a_wall_from_the_panel_edges(built: Built) -> None:
    """A screw pilot hole keeps wood round it: the side panels and their finger joints take the
    outer panel thickness of a top or bottom panel, and the hole stays clear of that."""
    if built.profile.process != "plywood-cnc":
        pytest.skip("plywood only")
    from drawstring.cad.hinge_plans import strip_hole_plans
    from drawstring.fabrication.dxf import LAYER_DRILL

    d, profile = built.design, built.profile
    radius = strip_hole_plans(d.tiles_2d, d.linkage.hinges, list(d.hinge_side), profile)[0].radius
    msp = ezdxf.readfile(built.folder / "fabrication" / "panels.dxf").modelspace()
    outlines = [
        np.array(e.get_points("xy")) for e in msp.query(f"LWPOLYLINE[layer=='{LAYER_CUT_OUTER}']")
    ]
    walls = []
    for entity in msp.query(f"LWPOLYLINE[layer=='{LAYER_DRILL}']"):
        a, b = np.array(entity.get_points("xy"))
        centre, r = 0.5 * (a + b), 0.5 * float(np.linalg.norm(b - a))
        if abs(r - radius) > 1e-6:
            continue  # a cable hole
        inside = [
            o for o in outlines if np.all(centre > o.min(axis=0)) and np.all(centre < o.max(axis=0))
        ]
        assert len(inside) == 1
        ring = inside[0]
        start, end = ring, np.roll(ring, -1, axis=0)
        seg = end - start
        t = np.clip(
            np.einsum("ij,ij->i", centre - start, seg) / np.einsum("ij,ij->i", seg, seg), 0, 1
        )
        walls.append(float(np.linalg.norm(start + t[:, None] * seg - centre, axis=1).min()) - r)
    assert walls and min(walls) >= 0.5 * profile.tool_diameter_mm


def test_loose_pads_that_fill_a_bed_go_on_to_the_next() -> None:
    # Ten 20 x 8 mm pads on a 60 x 60 mm bed (44 x 44 inside the margins): rows of two, four
    # rows a bed, so two beds, in the order given; a pad larger than the bed is refused.
    from drawstring.fabrication.mesh3mf import BED_MARGIN_MM, PartMesh, arrange_loose

    def pad(h: int, w: float = 20.0, d: float = 8.0) -> PartMesh:
        corners = np.array([[x, y, z] for x in (0, w) for y in (0, d) for z in (4.0, 6.0)])
        return PartMesh(f"hinge_{h}", "pad", corners + 50.0, np.array([[0, 1, 2]]))

    beds = arrange_loose([pad(h) for h in range(10)], (60.0, 60.0), 3.0)
    assert [[p.name for p in bed] for bed in beds] == [
        [f"hinge_{h}" for h in range(8)],
        ["hinge_8", "hinge_9"],
    ]
    for bed in beds:
        every = np.vstack([p.vertices for p in bed])
        assert every[:, 2].min() == 0.0
        assert np.all(every[:, :2] >= BED_MARGIN_MM) and np.all(every[:, :2] <= 60 - BED_MARGIN_MM)
    with pytest.raises(InputError, match="loose hinge pad .* does not fit the 60 x 60 mm bed"):
        arrange_loose([pad(0, w=50.0)], (60.0, 60.0), 3.0)


def test_the_guide_points_to_the_test_coupon(built: Built) -> None:
    guide = (built.folder / "fabrication" / "assembly.md").read_text()
    assert f"`drawstring coupon --profile {built.profile.name}" in guide


def test_the_guide_points_to_the_coupon_of_its_profile_and_printer(built: Built) -> None:
    """assembly.md names a `drawstring coupon` command whose --profile and --printer load
    the design's own profile and printer."""
    guide = (built.folder / "fabrication" / "assembly.md").read_text(encoding="utf-8")
    match = re.search(r"`drawstring coupon --profile (\S+?)(?: --printer (\S+?))?`", guide)
    assert match is not None
    assert load_profile(match[1]).process == built.profile.process
    manifest = json.loads((built.folder / "fabrication" / "manifest.json").read_text())
    if manifest["printer"] is None:
        assert match[2] is None
    else:
        assert load_printer(match[2]).name == manifest["printer"]["name"]
