"""Printer presets: the shipped ones load and cite their source, bad ones are refused by name
(exit 2 from the command line, nothing written), and the chosen printer is recorded."""

from __future__ import annotations

import dataclasses
import json
import tomllib
from pathlib import Path

import pytest

from drawstring.app.cli import EXIT_INPUT, main
from drawstring.fabrication.printers import (
    SHIPPED_PRINTERS,
    load_printer,
    parse_printer,
    print_bed,
    resolve_printer,
    with_printer,
)
from drawstring.fabrication.profiles import load_profile
from drawstring.geometry.core.errors import InputError

#: The dual-material machines shipped, with the bed (x, y) both toolheads reach and where it
#: starts, as their makers publish them.
MAKERS = {
    "prusa-xl-2t": ((360.0, 360.0), (0.0, 0.0), 2),
    "bambu-h2d": ((300.0, 320.0), (25.0, 0.0), 2),
    "snapmaker-u1": ((270.0, 270.0), (0.5, 1.0), 4),
}


@pytest.mark.parametrize("name", SHIPPED_PRINTERS)
def test_shipped_printers_load_and_round_trip(name: str, tmp_path: Path) -> None:
    printer = load_printer(name)
    assert printer.name == name
    assert printer.origin.endswith("(shipped)")
    copy = tmp_path / "mine.toml"
    copy.write_text(printer.to_toml(), encoding="utf-8")
    again = load_printer(copy)
    assert {k: v for k, v in again.to_json().items() if k != "origin"} == {
        k: v for k, v in printer.to_json().items() if k != "origin"
    }


@pytest.mark.parametrize("name", sorted(MAKERS))
def test_the_makers_printers_have_their_published_beds_and_cite_them(name: str) -> None:
    printer = load_printer(name)
    bed, origin, toolheads = MAKERS[name]
    assert printer.bed == bed
    assert (printer.bed_origin_x_mm, printer.bed_origin_y_mm) == origin
    assert printer.toolheads == toolheads
    assert printer.source.startswith("https://")
    assert printer.maker and printer.maker != "generic"


def _table(name: str = "prusa-xl-2t") -> dict:
    return tomllib.loads(load_printer(name).to_toml())


@pytest.mark.parametrize(
    ("section", "key", "value", "words"),
    [
        ("toolheads", "count", 0, "out of range"),
        ("bed", "x_mm", -5.0, "out of range"),
        ("pla", "nozzle_c", "hot", "must be int"),
        ("motion", "gcode_flavor", "sailfish", "must be one of"),
        ("bed", "colour", "black", "unknown key bed.colour"),
        ("print", "layer_height_mm", 0.4, "more than 0.8 x"),
    ],
)
def test_bad_printer_values_are_refused_with_file_key_and_range(
    section: str, key: str, value: object, words: str
) -> None:
    table = _table()
    table[section][key] = value
    with pytest.raises(InputError) as info:
        parse_printer(table, "my-printer.toml")
    assert str(info.value).startswith("my-printer.toml")
    assert words in str(info.value)
    assert "\n" not in str(info.value)


def test_a_process_gets_a_printer_with_the_toolheads_it_needs() -> None:
    fdm, laser, plywood = (load_profile(n) for n in ("fdm-dual", "laser-epdm", "plywood-cnc"))
    assert resolve_printer(fdm).name == "generic-dual"
    assert resolve_printer(laser).name == "generic-single"
    assert resolve_printer(fdm, "bambu-h2d").name == "bambu-h2d"
    assert resolve_printer(laser, "prusa-xl-2t").name == "prusa-xl-2t"  # tiles on one toolhead
    with pytest.raises(InputError, match="needs 2"):
        resolve_printer(fdm, "generic-single")
    assert resolve_printer(plywood) is None
    with pytest.raises(InputError, match="prints nothing"):
        resolve_printer(plywood, "prusa-xl-2t")
    with pytest.raises(InputError, match="unknown printer"):
        resolve_printer(fdm, "resin-vat")


def test_a_profile_that_names_no_printer_prints_on_its_own_bed() -> None:
    own = dataclasses.replace(load_profile("fdm-dual"), printer="", bed_x_mm=200.0, nozzle_mm=0.6)
    printer = resolve_printer(own)
    assert printer is not None and printer.toolheads == 2
    assert printer.bed == (200.0, own.bed_y_mm) == print_bed(own, printer)
    assert with_printer(own, printer).nozzle_mm == 0.6


def test_the_printers_nozzle_is_the_designs() -> None:
    profile = load_profile("fdm-dual")
    printer = dataclasses.replace(load_printer("prusa-xl-2t"), nozzle_mm=0.6)
    used = with_printer(profile, printer)
    assert used.nozzle_mm == 0.6 and used.printer == "prusa-xl-2t"
    assert print_bed(used, printer) == (360.0, 360.0)


@pytest.mark.parametrize(
    ("printer", "words"),
    [
        ("resin-vat", "unknown printer 'resin-vat'"),
        ("generic-single", "needs 2"),
        ("bad.toml", "toolheads.count = 0 is out of range"),
    ],
)
def test_a_bad_printer_exits_2_with_one_line_and_writes_nothing(
    printer: str, words: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    if printer == "bad.toml":
        text = load_printer("prusa-xl-2t").to_toml().replace("count = 2", "count = 0")
        assert tomllib.loads(text)["toolheads"]["count"] == 0
        printer = str(tmp_path / "bad.toml")
        Path(printer).write_text(text, encoding="utf-8")
    out = tmp_path / "out"
    status = main(["design", "saddle", "--printer", printer, "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert status == EXIT_INPUT
    assert words in err and err.count("\n") == 1
    assert not out.exists()
    coupon = tmp_path / "coupon"
    assert main(["coupon", "--printer", printer, "--out", str(coupon), "--quiet"]) == EXIT_INPUT
    assert capsys.readouterr().err.count("\n") == 1 and not coupon.exists()


def test_profiles_lists_the_printers_and_shows_one_as_toml(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    assert main(["profiles"]) == 0
    listing = capsys.readouterr().out
    for name in SHIPPED_PRINTERS:
        assert f"{name}: " in listing
    assert main(["profiles", "--show", "bambu-h2d"]) == 0
    copy = tmp_path / "h2d.toml"
    copy.write_text(capsys.readouterr().out, encoding="utf-8")
    assert load_printer(copy).bed == (300.0, 320.0)
    assert main(["profiles", "--show", str(copy)]) == 0  # a printer file shows as a printer
    assert 'name = "bambu-h2d"' in capsys.readouterr().out


def test_the_chosen_printer_is_recorded_in_design_json(tmp_path: Path) -> None:
    out = tmp_path / "d"
    args = ["design", "saddle", "--grid", "3", "3", "--no-cad", "--no-simulate", "--quiet"]
    assert main([*args, "--printer", "bambu-h2d", "--slice", "--out", str(out)]) == 0
    options = json.loads((out / "design.json").read_text())["options"]
    assert options["printer"] == "bambu-h2d" and options["slice"] is True
    assert main([*args, "--profile", "plywood-cnc", "--out", str(out)]) == 0
    options = json.loads((out / "design.json").read_text())["options"]
    assert options["printer"] is None and options["slice"] is False


def test_the_report_checks_the_layout_against_the_printers_bed(tmp_path: Path) -> None:
    import numpy as np

    from drawstring.output.report_data import FolderContents
    from drawstring.output.report_sections import bed_note

    flat = np.zeros((2, 8, 3))
    flat[1, :, 0] = 340.0  # wider than generic-dual's 330 mm bed, within the XL's 360 mm
    flat[1, :, 1] = 200.0
    options = {"profile": "fdm-dual", "printer": "prusa-xl-2t"}
    found = FolderContents(tmp_path, {"options": options}, None, flat, None, None, ())
    assert "(fits the 360 × 360 mm bed of prusa-xl-2t" in bed_note(found)
    options["printer"] = "generic-dual"
    assert "does not fit the 330 × 240 mm bed of generic-dual" in bed_note(found)
