"""Profiles: shipped files load, user copies round-trip, bad values are refused by name."""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path

import pytest

from drawstring.fabrication.profiles import (
    SHIPPED_PROFILES,
    Process,
    load_profile,
    parse_profile,
)
from drawstring.geometry.core.errors import InputError, InternalError


@pytest.mark.parametrize("name", SHIPPED_PROFILES)
def test_shipped_profiles_load(name: str) -> None:
    profile = load_profile(name)
    assert profile.name == name
    assert profile.process == name
    assert profile.thickness_mm > 0
    assert 0 <= profile.min_gap_angle_deg < 90


@pytest.mark.parametrize("name", SHIPPED_PROFILES)
def test_process_is_the_enum_and_written_as_its_name(name: str) -> None:
    profile = load_profile(name)
    assert type(profile.process) is Process
    assert profile.process is Process(name)
    assert json.loads(json.dumps(profile.to_json()))["process"] == name
    assert f'process = "{name}"' in profile.to_toml()


@pytest.mark.parametrize("name", SHIPPED_PROFILES)
def test_show_output_round_trips(name: str, tmp_path: Path) -> None:
    profile = load_profile(name)
    copy = tmp_path / "mine.toml"
    copy.write_text(profile.to_toml(), encoding="utf-8")
    again = load_profile(copy)
    assert {k: v for k, v in again.to_json().items() if k != "source"} == {
        k: v for k, v in profile.to_json().items() if k != "source"
    }


def shipped_table(name: str = "fdm-dual") -> dict:
    return tomllib.loads(load_profile(name).to_toml())


@pytest.mark.parametrize(
    ("section", "key", "value", "words"),
    [
        ("tile", "thickness_mm", -1.0, "out of range"),
        ("tile", "thickness_mm", "thick", "must be float"),
        ("tile", "min_gap_angle_deg", 95.0, "out of range"),
        ("hinge", "interlock", "glue", "must be one of"),
        ("tile", "colour", "red", "unknown key tile.colour"),
        ("machine", "bed_x_mm", 0.0, "out of range"),
        # fewer tiles than a 3 x 3 grid can never give a string route (profiles.MIN_TILES)
        ("design", "default_tiles", 6, "out of range (7 to 20000 tiles)"),
    ],
)
def test_bad_values_are_refused_with_file_key_value_and_range(
    section: str, key: str, value: object, words: str
) -> None:
    table = shipped_table()
    table[section][key] = value
    with pytest.raises(InputError) as info:
        parse_profile(table, "my.toml")
    message = str(info.value)
    assert message.startswith("my.toml")
    assert words in message
    assert "\n" not in message


def test_missing_key_and_unknown_section() -> None:
    table = shipped_table()
    del table["string"]["diameter_mm"]
    with pytest.raises(InputError, match="missing key string.diameter_mm"):
        parse_profile(table, "my.toml")
    table = shipped_table()
    table["paint"] = {"colour": "red"}
    with pytest.raises(InputError, match=r"unknown section \[paint\]"):
        parse_profile(table, "my.toml")


def test_unknown_profile_name_and_missing_file(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="unknown profile"):
        load_profile("resin-printer")
    with pytest.raises(InputError, match="does not exist"):
        load_profile(tmp_path / "nope.toml")
    broken = tmp_path / "broken.toml"
    broken.write_text("name = ", encoding="utf-8")
    with pytest.raises(InputError, match="not valid TOML"):
        load_profile(broken)


def test_size_range_must_hold_the_default_size() -> None:
    table = shipped_table()
    table["design"]["size_max_mm"] = 100.0  # below the default 160 mm
    with pytest.raises(InputError, match="must lie between"):
        parse_profile(table, "my.toml")


@pytest.mark.parametrize("name", SHIPPED_PROFILES)
def test_rough_estimate_scales_with_area(name: str) -> None:
    from drawstring.fabrication.profiles import rough_estimate

    profile = load_profile(name)
    small = rough_estimate(profile, 100.0, 200)
    large = rough_estimate(profile, 200.0, 200)
    # Tile mass grows with the area (4x); hinge mass stays (same tile count: 2 hinges each).
    hinge_g = (
        2 * 200 * profile.hinge_thickness_mm * profile.hinge_width_mm
        * profile.hinge_pad_length_mm * 1e-6 * profile.hinge_density_kg_m3
    )  # fmt: skip
    assert small.mass_g > hinge_g
    if profile.process == "plywood-cnc":
        # box tiles: their six panels, top and bottom growing with the area, the sides with
        # the tile side only (the thickness stays)
        from drawstring.fabrication.profiles import ESTIMATE_AREA_FACTOR

        for guess, size in ((small, 100.0), (large, 200.0)):
            side = math.sqrt(ESTIMATE_AREA_FACTOR * size**2 / 200)
            panels = 200 * (2 * side**2 + 4 * side * profile.thickness_mm)
            tile_g = panels * profile.panel_thickness_mm * 1e-6 * profile.density_kg_m3
            assert math.isclose(guess.mass_g - hinge_g, tile_g, rel_tol=1e-9)
    else:
        assert math.isclose(large.mass_g - hinge_g, 4 * (small.mass_g - hinge_g), rel_tol=1e-9)
    assert large.cost > small.cost > 0
    assert large.hours >= small.hours > 0
    with pytest.raises(InternalError):  # the command line refuses such a size first
        rough_estimate(profile, -1.0, 200)


@pytest.mark.parametrize("name", SHIPPED_PROFILES)
def test_smallest_size_gives_tiles_the_cad_features_fit(name: str) -> None:
    # The saddle at the profile's size_min_mm with its default tiles passes the check that
    # refuses tiles too small for the string channel, lift bores and hinge strips before the
    # CAD build (feature_fit_refusal); no solid is built.
    from drawstring.pipeline.cad_stage import feature_fit_refusal
    from drawstring.pipeline.record import DesignOptions
    from drawstring.pipeline.run import design

    profile = load_profile(name)
    options = DesignOptions(profile=name, size_mm=profile.size_min_mm, simulate=False, cad=False)
    result = design("saddle", options)
    assert result.options.tiles == profile.default_tiles
    assert feature_fit_refusal(result) is None


def test_a_profile_written_before_the_string_density_existed_still_loads() -> None:
    # Keys added later carry a default, so users' saved profiles keep loading.
    table = shipped_table()
    assert table["string"]["density_kg_m3"] == 970.0
    del table["string"]["density_kg_m3"]
    profile = parse_profile(table, "old.toml")
    assert profile.string_density_kg_m3 == 1000.0
    # a required key stays required
    del table["string"]["diameter_mm"]
    with pytest.raises(InputError, match="missing key string.diameter_mm"):
        parse_profile(table, "old.toml")


def test_an_inverted_size_range_is_named_as_such() -> None:
    table = shipped_table()
    table["design"]["size_min_mm"] = 500.0  # above the size_max_mm of 450
    with pytest.raises(InputError, match=r"size_min_mm \(500.0\) is above .* swap them"):
        parse_profile(table, "my.toml")
