"""Values the tool chooses itself (:mod:`drawstring.pipeline.auto`) where the user gave none of
--size, --thickness, --tiles, and the CAD feature checks asked before any layout
(:func:`~drawstring.pipeline.retry.feature_check`)."""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from drawstring.fabrication.profiles import load_profile
from drawstring.geometry.core.errors import InputError, ThicknessError
from drawstring.geometry.core.tile import HingeStrategy
from drawstring.geometry.tiling.linkage import build_linkage
from drawstring.pipeline import auto
from drawstring.pipeline.auto import (
    CHOSEN_LAYOUTS,
    RETRY_LAYOUTS,
    LaidOut,
    checked_feature_refusal,
    chooses_values,
    chosen_layout,
)
from drawstring.pipeline.cad_stage import FeatureShortfall, WeldedHinges, hinge_strip_shortfall
from drawstring.pipeline.record import DesignOptions
from drawstring.pipeline.retry import (
    FEATURE_MARGIN,
    STEP_RATIO,
    Retry,
    feature_check,
    feature_ratio,
)
from drawstring.pipeline.run import resolve_options

DATA = Path(__file__).resolve().parent / "data"
PROFILES_DIR = Path(__file__).resolve().parents[1] / "profiles"
HEMISPHERE = DATA / "hemisphere.obj"


def design(out: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "drawstring.app.cli", "design", str(HEMISPHERE), *args]
        + ["--no-cad", "--no-simulate", "--quiet", "--out", str(out)],
        capture_output=True,
        text=True,
        check=False,
    )


@pytest.fixture(scope="module")
def small_profile(tmp_path_factory: pytest.TempPathFactory) -> Path:
    # fdm-dual with 12 mm tiles, 40 of them, on a 20 mm hemisphere: the tiles turn inside out
    path = tmp_path_factory.mktemp("profile") / "small.toml"
    text = (PROFILES_DIR / "fdm-dual.toml").read_text()
    for old, new in (
        ("default_size_mm = 160.0", "default_size_mm = 20.0"),
        ("size_min_mm = 80.0", "size_min_mm = 10.0"),
        ("default_tiles = 200", "default_tiles = 40"),
        ("\nthickness_mm = 6.0", "\nthickness_mm = 12.0"),
    ):
        assert old in text
        text = text.replace(old, new)
    path.write_text(text)
    return path


def test_refused_defaults_are_replaced_by_the_checked_retry_and_said_so(
    tmp_path: Path, small_profile: Path
) -> None:
    # Given a tile count, the user keeps it and gets the refusal with its checked retry.
    given = design(tmp_path / "given", "--profile", str(small_profile), "--tiles", "40")
    assert given.returncode == 2, given.stderr
    assert not (tmp_path / "given").exists()
    found = re.search(r"retry with: --tiles 40 --size (\S+)$", given.stderr.strip())
    assert found is not None, given.stderr
    size = float(found.group(1))
    # Given none of the three, the tool designs at that retry's size itself.
    auto = tmp_path / "auto"
    done = design(auto, "--profile", str(small_profile))
    assert done.returncode == 0, done.stderr
    doc = json.loads((auto / "design.json").read_text())
    chosen = doc["metrics"]["chosen_values"]
    assert doc["options"]["size_mm"] == size and doc["options"]["tiles"] == 40
    assert doc["options"]["thickness_mm"] == 12.0
    assert chosen["reason"] == "refused" and chosen["used"] == {"size_mm": size}
    assert chosen["defaults"] == {"size_mm": 20.0, "thickness_mm": 12.0, "tiles": 40}
    assert "too small for 12 mm thick tiles" in chosen["refusal"]
    (tried,) = chosen["tried"]
    assert tried["option"] == "size" and tried["value"] == size
    assert tried["accuracy_mm"] <= doc["quality"]["tolerance_mm"]
    assert doc["problems"] == []
    assert any(f"the design uses --size {size:g}" in n for n in doc["notes"])
    # It is the design those values give when asked for.
    asked = tmp_path / "asked"
    again = design(asked, "--profile", str(small_profile), "--size", f"{size:g}")
    assert again.returncode == 0, again.stderr
    for name in ("tiles.npz", "flat.obj", "hinges.json", "route.json"):
        assert (auto / name).read_bytes() == (asked / name).read_bytes(), name


@dataclass(frozen=True)
class _Shaped:
    accuracy_mm: float


def _laid(options: Any, accuracy: float) -> LaidOut:
    return LaidOut(None, None, (), _Shaped(accuracy), options, None)  # type: ignore[arg-type]


def _never_refused(*_args: object) -> InputError:
    raise AssertionError("the defaults were laid out: nothing to refuse")


def _forty_tiles() -> tuple[Any, DesignOptions, Any]:
    """fdm-dual, the options asked (no CAD, no simulation) and resolved at 40 tiles: the
    defaults of the chosen-values tests."""
    profile = load_profile("fdm-dual")
    asked = DesignOptions(cad=False, simulate=False)
    return profile, asked, replace(resolve_options(asked, profile), tiles=40)


def test_a_layout_missing_the_tolerance_steps_the_tiles_down_until_one_meets_it() -> None:
    # The defaults (40 tiles) miss fdm-dual's 0.05 mm; the tool tries a quarter fewer tiles,
    # then a quarter fewer again, each checked by the refusing check, and keeps the first
    # that meets the tolerance.
    profile, asked, options = _forty_tiles()
    laid_out: list[int] = []

    def lay_out(changed: Any) -> LaidOut:
        laid_out.append(changed.tiles)
        return _laid(changed, 0.3 if changed.tiles > 25 else 0.01)

    first = _laid(options, 0.4)
    kept, chosen = chosen_layout(
        first, str(HEMISPHERE), asked, options, profile, lay_out, _never_refused
    )
    steps = [math.floor(40 * STEP_RATIO), math.floor(math.floor(40 * STEP_RATIO) * STEP_RATIO)]
    assert laid_out == steps == [30, 22]
    assert kept.options.tiles == 22 and chosen is not None
    assert chosen["reason"] == "tolerance" and chosen["accuracy_mm"] == 0.4
    assert chosen["used"] == {"tiles": 22}
    assert [(t["value"], t["accuracy_mm"]) for t in chosen["tried"]] == [(30, 0.3), (22, 0.01)]
    note = kept.notes[-1]
    assert "--tiles 30 (0.3 mm, dual hinges) missed the 0.05 mm; the design uses --tiles 22" in note
    # where none meets it, at most CHOSEN_LAYOUTS are tried and the defaults are kept
    laid_out.clear()
    kept, chosen = chosen_layout(
        first, str(HEMISPHERE), asked, options, profile,
        lambda changed: lay_out(changed) and _laid(changed, 0.2), _never_refused,
    )  # fmt: skip
    assert len(laid_out) == CHOSEN_LAYOUTS and laid_out[:2] == [30, 22]
    assert kept is not first and kept.shaped is first.shaped and chosen is not None
    assert chosen["used"] == {} and "so the defaults are kept" in kept.notes[-1]
    # a layout within the tolerance at the defaults is kept as it is, and so is one that
    # misses it without the co-optimization (no tile count mends that)
    fine = _laid(options, 0.04)
    assert chosen_layout(
        fine, str(HEMISPHERE), asked, options, profile, lay_out, _never_refused
    ) == (fine, None)
    plain = replace(options, co_optimize=False)
    missed = _laid(plain, 0.4)
    assert chosen_layout(
        missed, str(HEMISPHERE), asked, plain, profile, lay_out, _never_refused
    ) == (missed, None)


def test_a_value_whose_layout_has_no_route_is_a_refused_step_and_the_search_goes_on() -> None:
    # The route of a candidate layout (planned with CAD before any solid) can fail: that value
    # is recorded as refused and the next one is laid out, as for a refused value.
    from drawstring.geometry.core.errors import DesignError

    profile, asked, options = _forty_tiles()
    laid_out: list[int] = []

    def lay_out(changed: Any) -> LaidOut:
        laid_out.append(changed.tiles)
        if changed.tiles == 30:
            raise DesignError("no string route through every part")
        return _laid(changed, 0.01)

    kept, chosen = chosen_layout(
        _laid(options, 0.4), str(HEMISPHERE), asked, options, profile, lay_out, _never_refused
    )
    assert laid_out == [30, 22] and kept.options.tiles == 22 and chosen is not None
    assert chosen["tried"][0] == {
        "option": "tiles", "value": 30, "refused": "no string route through every part",
    }  # fmt: skip
    assert "--tiles 30 (refused)" in kept.notes[-1]


def test_only_defaults_left_unset_let_the_tool_choose() -> None:
    assert chooses_values(DesignOptions(hinges=HingeStrategy.TOP, cad=False))
    for given in ({"size_mm": 160.0}, {"thickness_mm": 6.0}, {"tiles": 200}, {"grid": (9, 9)}):
        assert not chooses_values(DesignOptions(**given))  # type: ignore[arg-type]


def _grid_tiles(sides: np.ndarray, thickness: float = 6.0) -> tuple[Any, np.ndarray]:
    """A 3 x 3 linkage whose tiles are flat squares of the given side lengths (one per tile),
    each centred on its grid cell, extruded straight down."""
    link = build_linkage(np.ones((3, 3), dtype=bool))
    unit = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]])
    centres = 10.0 * (link.tile_cells + 0.5)
    top = centres[:, None, :] + sides[:, None, None] * unit[None]
    top3 = np.concatenate([top, np.zeros((len(sides), 4, 1))], axis=2)
    bottom3 = top3 - np.array([0.0, 0.0, thickness])
    return link, np.concatenate([top3, bottom3], axis=1)


def _strip_need(profile: Any) -> float:
    # strip_room on a square face whose neighbouring corners hold strips (90 degrees apart),
    # plus half the strip: the reach from a hinged corner to the face's centre
    width, wall = profile.hinge_width_mm, max(profile.nozzle_mm, 2 * profile.kerf_mm, 0.3)
    room = max(0.5 * width + wall, (width + wall) / (2 * math.sin(math.radians(45))))
    return room + 0.5 * width


@pytest.mark.parametrize("hinges", [HingeStrategy.DUAL, HingeStrategy.TOP])
def test_hinge_strips_are_checked_on_the_first_tilings_tiles(hinges: HingeStrategy) -> None:
    pytest.importorskip("build123d")
    profile = load_profile("fdm-dual")
    need = _strip_need(profile)  # 1.25 mm for fdm-dual's 0.8 mm strip and 0.4 mm nozzle
    assert need == pytest.approx(0.4 + 1.2 / math.sqrt(2))
    # squares whose corners lie just inside, and just outside, that reach of their centres
    short = math.sqrt(2) * need * 0.98
    link, tiles = _grid_tiles(np.full(9, short))
    have, needed = hinge_strip_shortfall(profile, link, tiles, 12.0, hinges) or (0.0, 0.0)
    assert have == pytest.approx(short / math.sqrt(2)) and needed == pytest.approx(need)
    link, tiles = _grid_tiles(np.full(9, math.sqrt(2) * need * 1.02))
    assert hinge_strip_shortfall(profile, link, tiles, 12.0, hinges) is None


def test_the_refusing_check_with_cad_refuses_a_tile_too_small_for_its_strips() -> None:
    # Wide boundary tiles (room for the string channel) around a middle tile too small for
    # its four hinge strips: refused on these tiles, before any layout, by the check the
    # retry search asks too.
    pytest.importorskip("build123d")
    profile = load_profile("fdm-dual")
    options = resolve_options(DesignOptions(hinges=HingeStrategy.TOP), profile)
    sides = np.full(9, 8.0)
    middle = 4
    sides[middle] = 1.5
    link, tiles = _grid_tiles(sides)
    assert not link.boundary_tile[middle] and link.boundary_tile.sum() == 8
    check = feature_check(profile, options)
    with pytest.raises(FeatureShortfall, match="hinge strip needs 1.25 mm") as refused:
        check(SimpleNamespace(linkage=link), SimpleNamespace(tiles=tiles))  # type: ignore[arg-type]
    assert refused.value.have == pytest.approx(1.5 / math.sqrt(2))
    sides[middle] = 2.0
    link, tiles = _grid_tiles(sides)
    check(SimpleNamespace(linkage=link), SimpleNamespace(tiles=tiles))  # type: ignore[arg-type]


def _short(options: Any, have: float, need: float) -> LaidOut:
    # a layout meeting the tolerance whose tiles are too small for a feature
    shortfall = FeatureShortfall("lift-point tiles too shallow", have, need)
    return replace(_laid(options, 0.001), routed=object(), shortfall=shortfall)  # type: ignore[arg-type]


def test_a_layout_too_small_for_the_features_is_a_miss_and_the_search_steps_on() -> None:
    # The defaults (40 tiles) lay out with tiles 5 % short of a feature: the first step
    # scales the room up by that with a 4 % margin (tiles by its square), the next steps by
    # STEP_RATIO; a layout short again is a miss, never kept, and where none has room the
    # design is refused in words, with no retry nobody checked.
    profile, asked, options = _forty_tiles()
    ratio = feature_ratio("tiles", FeatureShortfall("", 1.0, 1.05))
    assert ratio == pytest.approx((1.0 / (1.05 * FEATURE_MARGIN)) ** 2)
    first_step = math.floor(40 * ratio)
    assert first_step == 33
    laid_out: list[int] = []

    def lay_out(changed: Any) -> LaidOut:
        laid_out.append(changed.tiles)
        if changed.tiles > 25:
            return _short(changed, 1.0, 1.02)
        return replace(_laid(changed, 0.01), routed=object())  # type: ignore[arg-type]

    kept, chosen = chosen_layout(
        _short(options, 1.0, 1.05), str(HEMISPHERE), asked, options, profile, lay_out,
        _never_refused,
    )  # fmt: skip
    # each miss steps by its own shortfall: 2 % short, 0.89 times the tiles
    again = feature_ratio("tiles", FeatureShortfall("", 1.0, 1.02))
    assert laid_out == [33, math.floor(33 * again), math.floor(29 * again)] == [33, 29, 25]
    assert chosen is not None and chosen["reason"] == "features"
    assert chosen["shortfall"] == "lift-point tiles too shallow"
    assert chosen["used"] == {"tiles": 25} and kept.options.tiles == 25
    assert [t.get("shortfall") for t in chosen["tried"]] == [
        "lift-point tiles too shallow", "lift-point tiles too shallow", None,
    ]  # fmt: skip
    assert (
        "--tiles 33 (lift-point tiles too shallow), --tiles 29 (lift-point tiles too shallow) "
        "missed; the design uses --tiles 25, whose tiles have room for the profile's features"
    ) in kept.notes[-1]
    # every layout short: refused, naming what was tried, after CHOSEN_LAYOUTS layouts
    laid_out.clear()
    with pytest.raises(InputError) as refused:
        chosen_layout(
            _short(options, 1.0, 1.05), str(HEMISPHERE), asked, options, profile,
            lambda changed: lay_out(changed) and _short(changed, 1.0, 1.02), _never_refused,
        )  # fmt: skip
    assert len(laid_out) == CHOSEN_LAYOUTS
    line = str(refused.value)
    assert "retry with:" not in line and "\n" not in line
    assert line.endswith("give the tiles more room with a larger --size or fewer tiles")


def test_with_no_fewer_tiles_left_the_search_grows_the_size_at_the_tiles_reached(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # 12 tiles short of a feature, and fewer tiles than a quarter of the defaults' 40 are not
    # offered: the next layout keeps 12 tiles and grows the size, and that design is the
    # one the same options give when asked for.
    profile, asked, options = _forty_tiles()
    seen: list[tuple[int, float]] = []

    def lay_out(changed: Any) -> LaidOut:
        seen.append((changed.tiles, changed.size_mm))
        if changed.tiles == 12 and changed.size_mm == options.size_mm:
            return _short(changed, 1.0, 1.1)
        return _laid(changed, 0.01)

    # the defaults were refused, and the retry search found 12 tiles
    searched = (Retry("tiles", 12, "--tiles 12", 1, 0.0), [], set())
    monkeypatch.setattr(auto, "refusal_search", lambda *_args: searched)
    kept, chosen = chosen_layout(
        ThicknessError("inside out", 6.0, 3, 0.0), str(HEMISPHERE), asked, options, profile,
        lay_out, lambda exc, _searched: InputError(f"refused: {exc}"),
    )  # fmt: skip
    size = seen[1][1]
    assert seen[0] == (12, options.size_mm) and seen[1][0] == 12
    # scaled by the shortfall and the margin, rounded up to two digits
    assert size == math.ceil(options.size_mm * 1.1 * FEATURE_MARGIN / 10) * 10
    assert chosen is not None and chosen["used"] == {"tiles": 12, "size_mm": size}
    assert chosen["tried"][1] == {
        "option": "size", "value": size, "with": {"tiles": 12}, "accuracy_mm": 0.01,
        "hinges": "dual",
    }  # fmt: skip
    assert f"the design uses --tiles 12 --size {size:g}" in kept.notes[-1]


def test_a_size_whose_hinged_tiles_overlap_where_the_string_runs_steps_the_tiles_there(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # The defaults were refused and the retry search found a larger size; laid out there,
    # hinged tiles overlap where their channels run (WeldedHinges), which a larger size keeps:
    # the search steps the tile count down at that size instead, until one has room.  A
    # shortfall of another feature at that size grows the size as before.
    profile, asked, options = _forty_tiles()
    seen: list[tuple[int, float]] = []

    def lay_out(changed: Any) -> LaidOut:
        seen.append((changed.tiles, changed.size_mm))
        if changed.tiles > 25:
            welded = WeldedHinges("print welded at the hinge", 1e-3, 0.8)
            return replace(_laid(changed, 0.001), routed=object(), shortfall=welded)  # type: ignore[arg-type]
        return replace(_laid(changed, 0.001), routed=object())  # type: ignore[arg-type]

    searched = (Retry("size", 220.0, "--size 220", 1, 0.0), [], set())
    monkeypatch.setattr(auto, "refusal_search", lambda *_args: searched)
    refused = ThicknessError("inside out", 6.0, 3, 0.0)
    kept, chosen = chosen_layout(
        refused, str(HEMISPHERE), asked, options, profile, lay_out,
        lambda exc, _searched: InputError(f"refused: {exc}"),
    )  # fmt: skip
    assert seen == [(40, 220.0), (30, 220.0), (22, 220.0)]  # STEP_RATIO steps, at 220 mm
    assert chosen is not None and chosen["used"] == {"size_mm": 220.0, "tiles": 22}
    assert chosen["tried"][1]["with"] == {"size": 220.0}
    assert kept.options.tiles == 22 and kept.options.size_mm == 220.0
    assert "the design uses --size 220 --tiles 22" in kept.notes[-1]

    seen.clear()  # short of a lift bore's depth at that size instead: the size grows

    def shallow(changed: Any) -> LaidOut:
        seen.append((changed.tiles, changed.size_mm))
        laid = replace(_laid(changed, 0.001), routed=object())  # type: ignore[arg-type]
        if changed.size_mm > 220.0:
            return laid
        return replace(laid, shortfall=FeatureShortfall("too shallow", 1.0, 1.02))

    kept, chosen = chosen_layout(
        refused, str(HEMISPHERE), asked, options, profile, shallow,
        lambda exc, _searched: InputError(f"refused: {exc}"),
    )  # fmt: skip
    assert seen[0] == (40, 220.0) and seen[1][0] == 40 and seen[1][1] > 220.0
    assert chosen is not None and chosen["used"] == {"size_mm": seen[1][1]}


#: The saddle at 30 mm on a 10 x 8 grid: its eq.-1 tiles pass the first tiling's checks, but
#: laid out, its lift-point tiles are too shallow for fdm-dual's lift bores.
SMALL_SADDLE = {"resolution": 1500, "simulate": False, "fit": "paper"}


def test_laid_out_tiles_too_small_are_refused_before_any_solid_with_a_retry_that_passes(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    pytest.importorskip("build123d")
    from drawstring.pipeline import run
    from drawstring.pipeline.cad_stage import feature_fit_refusal
    from drawstring.pipeline.record import Progress

    def no_solids(*_args: object) -> None:
        raise AssertionError("the CAD stage was reached")

    monkeypatch.setattr(run, "with_cad", no_solids)
    progress = Progress(quiet=True)
    options = DesignOptions(grid=(10, 8), size_mm=30.0, **SMALL_SADDLE)  # type: ignore[arg-type]
    with pytest.raises(InputError) as refused:
        run.design("saddle", options, progress=progress)
    line = str(refused.value)
    found = re.search(
        r"^--size 30 mm with --grid 10 8 gives tiles too small for the fdm-dual profile: "
        r"lift-point tiles [\d.]+ mm deep.*; retry with: --grid 10 8 --size (\d+)$",
        line,
    )
    assert found is not None, line
    assert "route" in progress.timings and "cad" not in progress.timings
    # the size quoted passes the same checks, and the CAD stage's own check on that design
    monkeypatch.setattr(run, "with_cad", lambda result, _progress: result)
    retried = run.design("saddle", replace(options, size_mm=float(found.group(1))))
    assert retried.options.size_mm > 30.0
    assert feature_fit_refusal(retried) is None


def test_chosen_values_step_past_laid_out_tiles_too_small_before_any_solid(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    # A profile whose defaults are that saddle's size and 80 tiles: the defaults lay out with
    # lift-point tiles too shallow, a miss, and the tool steps to fewer tiles before building
    # any solid; the design it makes is the one those values give when asked for.
    pytest.importorskip("build123d")
    from drawstring.pipeline import run
    from drawstring.pipeline.cad_stage import feature_fit_refusal

    text = (PROFILES_DIR / "fdm-dual.toml").read_text()
    for old, new in (
        ("default_size_mm = 160.0", "default_size_mm = 30.0"),
        ("size_min_mm = 80.0", "size_min_mm = 10.0"),
        ("default_tiles = 200", "default_tiles = 80"),
    ):
        assert old in text
        text = text.replace(old, new)
    profile = tmp_path / "small.toml"
    profile.write_text(text)
    built: list[Any] = []
    monkeypatch.setattr(run, "with_cad", lambda result, _progress: built.append(result) or result)
    options = DesignOptions(profile=str(profile), **SMALL_SADDLE)  # type: ignore[arg-type]
    result = run.design("saddle", options)
    chosen = result.measured["chosen_values"]
    assert chosen["reason"] == "features" and "lift-point tiles" in chosen["shortfall"]
    last = chosen["tried"][-1]
    assert "shortfall" not in last and last["option"] == "tiles" and last["value"] < 80
    assert chosen["used"] == {"tiles": last["value"]} == {"tiles": result.options.tiles}
    assert built == [result]  # solids only for the design chosen
    assert feature_fit_refusal(result) is None
    asked = run.design("saddle", replace(options, tiles=last["value"]))
    assert np.array_equal(asked.tiles_assembled, result.tiles_assembled)
    assert np.array_equal(asked.route.gaps, result.route.gaps)


def test_a_given_tile_count_too_small_for_the_features_is_refused_with_a_size_laid_out() -> None:
    # The user gave --tiles 40 and left the size: the refusal's retry grows the size by the
    # shortfall with its margin, keeps their 40 tiles, and quotes it only where that layout
    # had room; where it fell short too the line says so in words and quotes no value.
    profile = load_profile("fdm-dual")
    asked = DesignOptions(tiles=40, cad=False, simulate=False)
    options = resolve_options(asked, profile)
    refused = _short(options, 1.0, 1.1)
    size = math.ceil(options.size_mm * 1.1 * FEATURE_MARGIN / 10) * 10
    seen: list[tuple[int, float]] = []

    def roomy(changed: Any) -> LaidOut:
        seen.append((changed.tiles, changed.size_mm))
        return replace(_laid(changed, 0.01), routed=object())  # type: ignore[arg-type]

    line = str(checked_feature_refusal(refused, str(HEMISPHERE), asked, options, profile, roomy))
    assert seen == [(40, size)]
    assert line == (
        f"--size {options.size_mm:g} mm with 40 tiles gives tiles too small for the fdm-dual "
        f"profile: lift-point tiles too shallow; retry with: --tiles 40 --size {size:g}"
    )
    seen.clear()
    line = str(
        checked_feature_refusal(
            refused,
            str(HEMISPHERE),
            asked,
            options,
            profile,
            lambda changed: roomy(changed) and _short(changed, 1.0, 1.01),
        )  # fmt: skip
    )
    # two layouts, the second stepped on from the first's shortfall, both named
    assert len(seen) == RETRY_LAYOUTS == 2 and seen[0] == (40, size) and "retry with:" not in line
    assert seen[1][0] == 40 and seen[1][1] > size
    short = "the tiles still fall short: lift-point tiles too shallow"
    assert line.endswith(
        f"give the tiles more room with a larger --size or fewer tiles (laid out at --tiles 40 "
        f"--size {size:g}, {short}) (laid out at --tiles 40 --size {seen[1][1]:g}, {short})"
    )


def test_a_close_shape_too_small_for_the_features_gives_way_to_the_papers_shape(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # the feature checks after the route find the close shape's tiles too small (stood in
    # for here: any layout of a close shape): the paper's shape is laid out, routed and
    # checked at the same options, and used with a note, not a refusal
    pytest.importorskip("build123d")
    from drawstring.pipeline import auto, run
    from drawstring.pipeline.cad_stage import WeldedHinges

    def close_too_small(_profile: object, shaped: Any, _routed: object) -> WeldedHinges | None:
        if shaped.fit is not None and shaped.fit.get("used") == "close":
            return WeldedHinges("2 hinged pair(s) lie so close that they would print welded", 0, 1)
        return None

    monkeypatch.setattr(auto, "routed_shortfall", close_too_small)
    monkeypatch.setattr(run, "with_cad", lambda result, _progress: result)
    options = DesignOptions(tiles=40, resolution=1500, simulate=False)
    result = run.design("saddle", options)
    fit = result.measured["fit"]
    assert fit["used"] == "paper" and "close" in fit
    assert "print welded" in fit["features"]["refused"]
    assert any("the paper's shape has room for them" in n for n in result.notes)
    paper = run.design("saddle", replace(options, fit="paper"))
    assert np.array_equal(paper.tiles_assembled, result.tiles_assembled)
    assert np.array_equal(paper.route.gaps, result.route.gaps)
    # where the paper's shape falls short too, the refusal stands as before
    monkeypatch.setattr(auto, "routed_shortfall", lambda *_args: WeldedHinges("welded", 0, 1))
    with pytest.raises(InputError, match="welded"):
        run.design("saddle", options)
