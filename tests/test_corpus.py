"""Three meshes of the real-mesh corpus (``tests/data/``, licences beside them; sources in
``corpus-provenance.tsv``), designed at the defaults as a new user would: an easy one that
deploys within the fabrication tolerance, one refused in plain words, and a hard one whose
string route once crossed itself."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

DATA = Path(__file__).resolve().parent / "data"
PROFILES_DIR = Path(__file__).resolve().parents[1] / "profiles"


def design(mesh: str, out: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "drawstring.app.cli", "design", str(DATA / mesh), *args]
        + ["--quiet", "--out", str(out)],
        capture_output=True,
        text=True,
        check=False,
    )


def test_the_crumpled_sheet_deploys_within_the_fabrication_tolerance(tmp_path: Path) -> None:
    # Intrinsically flat but crumpled: 4 parts, deploys in the simulation; its 1e-3 mm targets
    # are missed in depth only (quality levels), within fdm-dual's 0.05 mm: exit 0.
    out = tmp_path / "crumpled"
    done = design("crumpled_developable.obj", out, "--no-cad")
    assert done.returncode == 0, done.stderr
    doc = json.loads((out / "design.json").read_text())
    metrics, quality = doc["metrics"], doc["quality"]
    assert doc["problems"] == [] and metrics["simulation"]["deployed"] is True
    assert metrics["route"]["crossings"] == 0
    tolerance = quality["tolerance_mm"]
    assert tolerance == 0.05
    for key in ("flat_edge_error_max_mm", "hinge_gap_max_mm", "contact_gap_max_mm"):
        assert metrics[key] <= tolerance
        assert quality["measures"][key]["level"] in ("target", "tolerance")
    # the levels say what the numbers say
    assert (quality["measures"]["hinge_gap_max_mm"]["level"] == "target") == (
        metrics["hinge_gap_max_mm"] <= 1e-3
    )


@pytest.mark.parametrize("cad", [[], ["--no-cad"]])
def test_the_hand_is_refused_in_plain_words_with_nothing_written(
    tmp_path: Path, cad: list[str]
) -> None:
    # Thin fingers: 6 mm tiles at 160 mm turn inside out, and no size within fdm-dual's range,
    # no thickness the string channel allows (with or without CAD: a --no-cad design is the
    # same product) and no tile count down to a quarter keeps them whole: one line saying why,
    # no retry that would not work, nothing written.
    out = tmp_path / "hand"
    done = design("hand.obj", out, "--no-simulate", *cad)
    assert done.returncode == 2, done.stderr
    (line,) = done.stderr.strip().splitlines()
    assert "turn inside out or fold" in line and "retry with" not in line
    assert "no --size up to 450 (the fdm-dual profile's largest)" in line
    assert "--thickness down to 3.6 (the string channel's least)" in line
    assert "curve tighter than tiles this thick can follow" in line
    assert not out.exists()


def test_the_panton_chair_route_never_crosses_itself(tmp_path: Path) -> None:
    # An S-shaped sheet split into two parts that bend in opposite senses: laid side by side
    # flat, the parts overlap, and segments of different parts seemed to cross.  Only
    # segments within one part can cross; the route here crosses nowhere.
    out = tmp_path / "panton"
    done = design("panton_chair.obj", out, "--no-cad", "--no-simulate")
    assert done.returncode == 0, done.stderr
    doc = json.loads((out / "design.json").read_text())
    assert doc["linkage"]["components"] >= 2
    assert doc["metrics"]["route"]["crossings"] == 0
    assert not any("crosses itself" in p for p in doc["problems"])
    assert doc["metrics"]["route"]["boundary_tiles_covered"]


def test_hinges_left_unset_go_on_top_where_dual_misses_the_tolerance(tmp_path: Path) -> None:
    # The crumpled sheet's dual hinges miss in depth by about 0.048 mm: within fdm-dual's
    # 0.05 mm, over a profile asking 0.01 mm.  With --hinges unset that profile gets the
    # layout with every hinge on top, which meets it; asked for, with the profile's tile count
    # given too (else the tool would choose fewer tiles), dual hinges stay, named as the
    # problem.  (The paper's shape: with --fit close the closer
    # shape is laid out with top hinges before it, tests/test_fit.py.)
    profile = tmp_path / "tight.toml"
    text = (PROFILES_DIR / "fdm-dual.toml").read_text()
    profile.write_text(text.replace("tolerance_mm = 0.05", "tolerance_mm = 0.01"))
    auto = tmp_path / "auto"
    args = ("--no-cad", "--no-simulate", "--profile", str(profile), "--fit", "paper")
    done = design("crumpled_developable.obj", auto, *args)
    assert done.returncode == 0, done.stderr
    doc = json.loads((auto / "design.json").read_text())
    choice = doc["metrics"]["hinge_choice"]
    assert doc["options"]["hinges"] == "top" and choice["used"] == "top"
    assert choice["dual_accuracy_mm"] > 0.01 >= choice["top_accuracy_mm"]
    assert doc["metrics"]["hinges_bottom"] == 0 and doc["problems"] == []
    assert any(n.startswith("hinges: with dual hinges the flat layout is") for n in doc["notes"])
    # the top layout is the one --hinges top makes
    top = tmp_path / "top"
    assert design("crumpled_developable.obj", top, *args, "--hinges", "top").returncode == 0
    for name in ("tiles.npz", "flat.obj", "hinges.json", "route.json"):
        assert (auto / name).read_bytes() == (top / name).read_bytes(), name
    dual = tmp_path / "dual"
    done = design("crumpled_developable.obj", dual, *args, "--hinges", "dual", "--tiles", "200")
    assert done.returncode == 3
    doc = json.loads((dual / "design.json").read_text())
    assert "hinge_choice" not in doc["metrics"] and doc["options"]["hinges"] == "dual"
    assert any("in depth" in p for p in doc["problems"])
