"""PrusaSlicer settings (.ini) per print bed, slicing, the slicer's numbers in bom.csv and
manifest.json, print beds on the printer's bed with the wipe tower clear of the parts, and
the Bambu Studio / OrcaSlicer per-part extruder metadata read back.

Tests that run PrusaSlicer skip where ``prusa-slicer`` is not on PATH.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import re
import shutil
import subprocess
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("build123d")

from cad_sample import cylinder_design  # noqa: E402

from drawstring.cad.design import CadResult, build_design_solids  # noqa: E402
from drawstring.cad.tiles import move_solid  # noqa: E402
from drawstring.fabrication.exports import write_fabrication  # noqa: E402
from drawstring.fabrication.mesh3mf import BED_MARGIN_MM  # noqa: E402
from drawstring.fabrication.printers import SHIPPED_PRINTERS, load_printer  # noqa: E402
from drawstring.fabrication.profiles import Profile, load_profile, print_clearance_mm  # noqa: E402
from drawstring.fabrication.slicer import (  # noqa: E402
    IniJob,
    prusa_ini,
    read_gcode_summary,
    wipe_tower_footprint,
)

HAS_SLICER = shutil.which("prusa-slicer") is not None
needs_slicer = pytest.mark.skipif(not HAS_SLICER, reason="prusa-slicer not installed")


@dataclasses.dataclass
class Sample:
    profile: Profile
    flat: CadResult
    assembled: CadResult


@pytest.fixture(scope="module")
def sample() -> Sample:
    profile = dataclasses.replace(
        load_profile("fdm-dual"), magnet_diameter_mm=3.0, magnet_height_mm=1.5
    )
    design = cylinder_design((3, 3))
    flat = build_design_solids(
        *design.solid_inputs(), profile, workers=1, print_clearance_mm=print_clearance_mm(profile)
    )
    assembled = dataclasses.replace(
        flat,
        pose="assembled",
        tiles=tuple(move_solid(s, m) for s, m in zip(flat.tiles, flat.transforms, strict=True)),
        pads=(),
    )
    return Sample(profile, flat, assembled)


def _write(sample: Sample, folder: Path, printer: str, slice_beds: bool) -> list[str]:
    design = cylinder_design((3, 3))
    return write_fabrication(
        folder,
        profile=sample.profile,
        linkage=design.linkage,
        tiles_flat=design.tiles_2d,
        tiles_assembled=design.tiles_3d,
        hinge_side=design.hinge_side,
        route_steps=design.route_steps,
        lift_tiles=design.lift_tiles,
        magnet_pairs=design.magnet_pairs,
        trims=design.trims,
        cad_flat=sample.flat,
        cad_assembled=sample.assembled,
        design_name="sample",
        workers=1,
        printer=load_printer(printer),
        slice_beds=slice_beds,
    )


def _ini(text: str) -> dict[str, str]:
    return dict(
        line.split(" = ", 1) for line in text.splitlines() if " = " in line and line[0] != "#"
    )


def _models(path: Path) -> list[tuple[str, np.ndarray, int]]:
    """Every object of a 3MF: its name, vertices and triangle count."""
    with zipfile.ZipFile(path) as archive:
        root = ET.fromstring(archive.read("3D/3dmodel.model"))
    ns = {"m": "http://schemas.microsoft.com/3dmanufacturing/core/2015/02"}
    objects = []
    for obj in root.iterfind("m:resources/m:object", ns):
        vertices = np.array(
            [[float(v.get(k, 0.0)) for k in "xyz"] for v in obj.iterfind(".//m:vertex", ns)]
        )
        objects.append((obj.get("name", ""), vertices, len(obj.findall(".//m:triangle", ns))))
    return objects


@pytest.mark.parametrize("name", SHIPPED_PRINTERS)
def test_the_ini_states_the_printers_settings(name: str) -> None:
    printer = load_printer(name)
    profile = load_profile("fdm-dual" if printer.toolheads > 1 else "laser-epdm")
    extruders = 2 if printer.toolheads > 1 else 1
    tower = (40.0, 50.0) if extruders == 2 else None
    values = _ini(prusa_ini(printer, profile, IniJob(extruders, tower, "test")))
    x0, y0 = printer.bed_origin_x_mm, printer.bed_origin_y_mm
    corners = [tuple(float(v) for v in c.split("x")) for c in values["bed_shape"].split(",")]
    assert corners[0] == (x0, y0) and corners[2] == (x0 + printer.bed_x_mm, y0 + printer.bed_y_mm)
    assert values["nozzle_diameter"].split(",") == [f"{printer.nozzle_mm:g}"] * extruders
    temperatures = [int(t) for t in values["temperature"].split(",")]
    assert temperatures == [printer.pla_nozzle_c, printer.tpu_nozzle_c][:extruders]
    assert float(values["layer_height"]) == printer.layer_height_mm
    assert int(values["perimeters"]) == printer.perimeters
    assert values["fill_density"] == f"{round(100 * profile.infill_fraction)}%"
    assert values["wipe_tower"] == ("1" if tower else "0")
    if tower:
        assert (float(values["wipe_tower_x"]), float(values["wipe_tower_y"])) == tower


@needs_slicer
@pytest.mark.parametrize("name", ["generic-dual", "bambu-h2d", "snapmaker-u1"])
def test_prusaslicer_loads_the_ini_and_keeps_its_values(name: str, tmp_path: Path) -> None:
    """Write the .ini, let PrusaSlicer load it and save its whole configuration, read the key
    values back."""
    printer = load_printer(name)
    written = tmp_path / "job.ini"
    text = prusa_ini(printer, load_profile("fdm-dual"), IniJob(2, (60.0, 70.0), "test"))
    written.write_text(text, encoding="utf-8")
    saved = tmp_path / "saved.ini"
    subprocess.run(
        ["prusa-slicer", "--load", str(written), "--save", str(saved)],
        check=True,
        capture_output=True,
        timeout=120,
    )
    ours, theirs = _ini(text), _ini(saved.read_text(encoding="utf-8"))
    for key in (
        "bed_shape",
        "nozzle_diameter",
        "temperature",
        "bed_temperature",
        "filament_max_volumetric_speed",
        "filament_density",
        "layer_height",
        "perimeters",
        "extra_perimeters",
        "overhangs",
        "fill_density",
        "perimeter_speed",
        "travel_speed",
        "machine_max_acceleration_x",
        "wipe_tower",
        "wipe_tower_x",
        "wipe_tower_y",
        "wipe_tower_width",
        "wiping_volumes_matrix",
        "gcode_flavor",
    ):
        mine = re.split(r"[,x]", ours[key])
        read = re.split(r"[,x]", theirs[key])
        if ours[key].replace(".", "").replace(",", "").replace("x", "").isdigit():
            assert [float(v) for v in read] == pytest.approx([float(v) for v in mine]), key
        else:
            assert theirs[key] == ours[key], key


def test_the_gcode_summary_is_read(tmp_path: Path) -> None:
    gcode = tmp_path / "x.gcode"
    gcode.write_text(
        "T0\nG1 X1 E1\nT1\nG1 X2 E1\nT0\n"
        "; filament used [mm] = 1234.50, 56.70\n"
        "; filament used [cm3] = 2.97, 0.14\n"
        "; filament used [g] = 3.68, 0.17\n"
        "; total toolchanges = 2\n"
        "; estimated printing time (normal mode) = 1d 2h 3m 4s\n",
        encoding="utf-8",
    )
    summary = read_gcode_summary(gcode)
    assert summary.time_s == ((24 + 2) * 60 + 3) * 60 + 4
    assert summary.filament_g == (3.68, 0.17) and summary.filament_mm == (1234.5, 56.7)
    assert summary.tools == (0, 1) and summary.toolchanges == 2
    gcode.write_text("G1 X1\n", encoding="utf-8")
    with pytest.raises(ValueError, match="no PrusaSlicer summary"):
        read_gcode_summary(gcode)


@pytest.mark.parametrize("name", ["bambu-h2d", "snapmaker-u1", "generic-dual"])
def test_beds_lie_on_the_printers_bed_with_the_wipe_tower_clear_of_the_parts(
    sample: Sample, tmp_path: Path, name: str
) -> None:
    printer = load_printer(name)
    _write(sample, tmp_path, name, slice_beds=False)
    out = tmp_path / "fabrication"
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["printer"]["name"] == name
    (bed,) = manifest["beds"]
    ini = _ini((out / bed["settings"]).read_text())
    low = np.array([printer.bed_origin_x_mm, printer.bed_origin_y_mm]) + BED_MARGIN_MM
    high = low + np.array(printer.bed) - 2 * BED_MARGIN_MM
    boxes = []
    for _, vertices, _ in _models(out / bed["model"]):
        assert np.all(vertices[:, :2] >= low - 1e-6) and np.all(vertices[:, :2] <= high + 1e-6)
        boxes.append((vertices[:, :2].min(axis=0), vertices[:, :2].max(axis=0)))
    corner = np.array(bed["wipe_tower_mm"])
    assert [float(ini["wipe_tower_x"]), float(ini["wipe_tower_y"])] == pytest.approx(corner)
    size = np.array(wipe_tower_footprint(printer))
    assert np.all(corner >= low - 1e-6) and np.all(corner + size <= high + 1e-6)
    for part_low, part_high in boxes:
        assert np.any(corner + size <= part_low) or np.any(corner >= part_high)


def test_without_slicing_bom_gives_the_estimate_and_no_slicer_file(
    sample: Sample, tmp_path: Path
) -> None:
    files = _write(sample, tmp_path, "generic-dual", slice_beds=False)
    assert "fabrication/slicer.json" not in files
    manifest = json.loads((tmp_path / "fabrication/manifest.json").read_text())
    assert "slicer" not in manifest
    rows = {r["item"]: r for r in csv.DictReader((tmp_path / "fabrication/bom.csv").open())}
    assert rows["print_time"]["description"] == f"{manifest['estimates']['print_time_h']} h"
    assert "estimate" in rows["print_time"]["note"]
    filament = [r for r in csv.DictReader((tmp_path / "fabrication/bom.csv").open())
                if r["item"] == "filament"]  # fmt: skip
    assert {r["material"] for r in filament} == {"PLA", "TPU 95A"}


@needs_slicer
def test_sliced_numbers_are_the_slicers_in_bom_manifest_and_slicer_json(
    sample: Sample, tmp_path: Path
) -> None:
    files = _write(sample, tmp_path, "generic-dual", slice_beds=True)
    out = tmp_path / "fabrication"
    assert "fabrication/slicer.json" in files
    sliced = json.loads((out / "slicer.json").read_text())
    assert sliced["slicer"].startswith("PrusaSlicer-")
    (bed,) = sliced["beds"]
    assert bed["tools"] == ["T0", "T1"] and bed["settings"] == "print.ini"
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["slicer"]["print_time_h"] == sliced["total"]["time_h"]
    assert manifest["slicer"]["filament_g"] == sliced["total"]["filament_g"]
    rows = list(csv.DictReader((out / "bom.csv").open()))
    (time_row,) = [r for r in rows if r["item"] == "print_time"]
    assert time_row["description"] == f"{sliced['total']['time_h']} h"
    assert sliced["slicer"] in time_row["note"]
    grams = {r["material"]: float(r["mass_g"]) for r in rows if r["item"] == "filament"}
    assert grams == pytest.approx(
        {k: round(v, 1) for k, v in sliced["total"]["filament_g"].items()}
    )
    # what the .ini and the 3MF slice to by hand is what drawstring reported
    gcode = tmp_path / "by-hand.gcode"
    subprocess.run(
        ["prusa-slicer", "--export-gcode", "--load", str(out / "print.ini"),
         str(out / "print.3mf"), "-o", str(gcode)],
        check=True, capture_output=True, timeout=900,
    )  # fmt: skip
    by_hand = read_gcode_summary(gcode)
    # PrusaSlicer slices on several threads: its own estimate of one file and settings varies
    # by a second or so from run to run
    assert by_hand.time_s == pytest.approx(bed["time_s"], rel=1e-3, abs=2.0)
    assert list(by_hand.filament_g) == pytest.approx(
        [bed["filament_g"]["PLA"], bed["filament_g"]["TPU 95A"]], rel=2e-3
    )


def test_bambu_and_orca_per_part_extruders_read_back(sample: Sample, tmp_path: Path) -> None:
    """Metadata/model_settings.config: one ``<object>`` per 3MF object, its parts in the
    order of its triangles, each part's range covering exactly its part's triangles, named
    ``tile_<id>`` or ``hinge_<id>``, on extruder 1 (tiles) or 2 (hinge pads); PrusaSlicer's
    config has the same objects, its volumes the runs of parts on one extruder."""
    _write(sample, tmp_path, "generic-dual", slice_beds=False)
    path = tmp_path / "fabrication" / "print.3mf"
    with zipfile.ZipFile(path) as archive:
        bambu = ET.fromstring(archive.read("Metadata/model_settings.config"))
        prusa = ET.fromstring(archive.read("Metadata/Slic3r_PE_model.config"))
    models = _models(path)
    assert len(bambu.findall("object")) == len(prusa.findall("object")) == len(models)
    kinds = {"tile": "1", "hinge": "2"}
    for obj, prusa_obj, (_, _, triangles) in zip(
        bambu.findall("object"), prusa.findall("object"), models, strict=True
    ):
        assert obj.get("id") == prusa_obj.get("id")
        meta = {m.get("key"): m.get("value") for m in obj.findall("metadata")}
        assert meta["extruder"] == "1"
        parts = obj.findall("part")
        assert [p.get("id") for p in parts] == [str(i + 1) for i in range(len(parts))]
        expected_first = 0
        runs: list[tuple[str, int, int]] = []
        for part in parts:
            assert part.get("subtype") == "normal_part"
            first, last = int(part.get("firstid", -1)), int(part.get("lastid", -1))
            assert first == expected_first and last >= first
            expected_first = last + 1
            name = {m.get("key"): m.get("value") for m in part.findall("metadata")}
            assert name["extruder"] == kinds[name["name"].split("_")[0]]
            if runs and runs[-1][0] == name["extruder"]:
                runs[-1] = (runs[-1][0], runs[-1][1], last)
            else:
                runs.append((name["extruder"], first, last))
        assert expected_first == triangles
        volumes = prusa_obj.findall("volume")
        assert [
            (
                {m.get("key"): m.get("value") for m in v.findall("metadata")}["extruder"],
                int(v.get("firstid", -1)),
                int(v.get("lastid", -1)),
            )
            for v in volumes
        ] == runs
