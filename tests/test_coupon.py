"""``drawstring coupon``: a coupon for every shipped profile that slices (printed) or whose
DXF sheets audit clean (cut), its folder and refusals, and the guide's pointer to it."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

pytest.importorskip("build123d")
ezdxf = pytest.importorskip("ezdxf")

from drawstring.app.cli import EXIT_INPUT, main  # noqa: E402
from drawstring.fabrication.coupon import COUPON_CELLS, coupon_side_mm  # noqa: E402
from drawstring.fabrication.printers import load_printer  # noqa: E402
from drawstring.fabrication.profiles import SHIPPED_PROFILES, load_profile  # noqa: E402
from drawstring.output.assembly_text import coupon_text  # noqa: E402
from drawstring.output.coupon import write_coupon  # noqa: E402

HAS_SLICER = shutil.which("prusa-slicer") is not None
DXF = {
    "fdm-dual": [],
    "laser-epdm": ["hinges.dxf", "placement.dxf"],
    "plywood-cnc": ["panels.dxf", "hinges.dxf", "placement.dxf"],
}
MODEL = {"fdm-dual": "print", "laser-epdm": "tiles", "plywood-cnc": None}


@pytest.fixture(scope="module", params=SHIPPED_PROFILES)
def coupon(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("coupons") / f"coupon-{request.param}"
    folder, _ = write_coupon(request.param, None, out, slice_beds=True)
    return folder


def test_the_coupon_has_nine_tiles_with_every_feature(coupon: Path) -> None:
    manifest = json.loads((coupon / "manifest.json").read_text())
    profile = load_profile(manifest["profile"])
    assert manifest["design"] == "coupon"
    assert manifest["tiles"] == COUPON_CELLS[0] * COUPON_CELLS[1]
    assert len(manifest["magnets"]) == 1  # the split's pair of pockets
    assert manifest["hinge_parts"] > 0
    checks = (coupon / "coupon.md").read_text()
    assert checks.startswith(f"# Test coupon ({profile.name})")
    assert "string" in checks and "magnet" in checks
    listed = {Path(f["path"]).name for f in manifest["files"]}
    assert listed <= {p.name for p in coupon.iterdir()}
    assert coupon_side_mm(profile) > 0


def test_a_printed_coupon_slices_with_both_materials_well_under_an_hour(coupon: Path) -> None:
    manifest = json.loads((coupon / "manifest.json").read_text())
    stem = MODEL[manifest["process"]]
    if stem is None:
        pytest.skip("nothing printed")
    assert (coupon / f"{stem}.3mf").is_file() and (coupon / f"{stem}.ini").is_file()
    if not HAS_SLICER:
        assert manifest["estimates"]["print_time_h"] < 1.0
        pytest.skip("prusa-slicer not installed: the estimate only")
    sliced = json.loads((coupon / "slicer.json").read_text())
    (bed,) = sliced["beds"]
    dual = manifest["process"] == "fdm-dual"
    # one extruder: PrusaSlicer selects no tool at all
    assert bed["tools"] == (["T0", "T1"] if dual else [])
    assert sliced["total"]["time_h"] < 1.0


def test_a_cut_coupons_sheets_audit_clean(coupon: Path) -> None:
    manifest = json.loads((coupon / "manifest.json").read_text())
    names = DXF[manifest["process"]]
    if not names:
        pytest.skip("nothing cut")
    for name in names:
        doc = ezdxf.readfile(coupon / name)
        auditor = doc.audit()
        assert not auditor.has_errors, (name, [str(e) for e in auditor.errors])
        assert len(doc.modelspace()) > 0


def test_a_coupon_folder_is_replaced_and_a_foreign_one_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "c"
    args = ["coupon", "--out", str(out), "--quiet"]
    assert main(args) == 0
    first = (out / "print.3mf").read_bytes()
    assert main(args) == 0  # an earlier coupon is replaced, to the byte
    assert (out / "print.3mf").read_bytes() == first
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine", encoding="utf-8")
    assert main(["coupon", "--out", str(foreign), "--quiet"]) == EXIT_INPUT
    assert "not a drawstring coupon" in capsys.readouterr().err
    assert [p.name for p in foreign.iterdir()] == ["notes.txt"]
    assert main(["coupon", "--profile", "resin.toml", "--out", str(tmp_path / "x")]) == EXIT_INPUT
    assert not (tmp_path / "x").exists()


def test_every_guide_points_to_the_coupon_of_its_profile_and_printer() -> None:
    profile = load_profile("fdm-dual")
    text = coupon_text(profile, load_printer("bambu-h2d"))
    assert "`drawstring coupon --profile fdm-dual --printer bambu-h2d`" in text
    text = coupon_text(load_profile("plywood-cnc"), None)
    assert "`drawstring coupon --profile plywood-cnc`" in text
