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
from drawstring.geometry.core.errors import InputError
from drawstring.geometry.core.tile import HingeStrategy
from drawstring.geometry.tiling.linkage import build_linkage
from drawstring.pipeline.auto import CHOSEN_LAYOUTS, LaidOut, chooses_values, chosen_layout
from drawstring.pipeline.cad_stage import FeatureShortfall, hinge_strip_shortfall
from drawstring.pipeline.record import DesignOptions
from drawstring.pipeline.retry import STEP_RATIO, feature_check
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


def test_a_layout_missing_the_tolerance_steps_the_tiles_down_until_one_meets_it() -> None:
    # The defaults (40 tiles) miss fdm-dual's 0.05 mm; the tool tries a quarter fewer tiles,
    # then a quarter fewer again, each checked by the refusing check, and keeps the first
    # that meets the tolerance.
    profile = load_profile("fdm-dual")
    asked = DesignOptions(cad=False, simulate=False)
    options = replace(resolve_options(asked, profile), tiles=40)
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
