"""``--fit``: the close assembled shape against the paper's, and the fit as the design folder
records it (``target.obj``, ``tiles.npz``'s per-tile distances, design.json's
``surface_distance_*``), checked with readers and distances written here, not drawstring's.

One 64-tile saddle (200 mm, no simulation, no solids) per fit, shared by the module.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from drawstring.geometry.core.tile import TILE_FACES
from drawstring.pipeline.policy import DEFAULT_POLICY
from drawstring.pipeline.record import Design, DesignOptions
from drawstring.pipeline.run import design

SIZE_MM = 200.0
OPTIONS = DesignOptions(tiles=60, size_mm=SIZE_MM, simulate=False, cad=False)


@pytest.fixture(scope="module")
def paper() -> Design:
    return design("saddle", replace(OPTIONS, fit="paper"))


@pytest.fixture(scope="module")
def close() -> Design:
    return design("saddle", OPTIONS)


@pytest.fixture(scope="module")
def folder(close: Design, tmp_path_factory: pytest.TempPathFactory) -> Path:
    from drawstring.output.folder import write_design
    from drawstring.output.writers import write_target_mesh, write_tiles_npz

    out = tmp_path_factory.mktemp("fit") / "saddle"
    return write_design(close, out, writers=(write_target_mesh, write_tiles_npz))


def read_obj(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and (0-based) faces of an OBJ file: ``v x y z`` and ``f a b c`` lines only
    (``a/b/c`` index forms are cut at the first slash)."""
    vertices: list[list[float]] = []
    faces: list[list[int]] = []
    for line in path.read_text(encoding="utf-8").splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "v":
            vertices.append([float(x) for x in parts[1:4]])
        elif parts[0] == "f":
            faces.append([int(p.split("/")[0]) - 1 for p in parts[1:]])
    return np.array(vertices), np.array(faces)


def point_triangle_distances(points: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Distance of each point (P, 3) from the nearest of the triangles (F, 3, 3), by brute
    force: the foot on the plane where it falls inside, else the nearest of the three edges."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    p = points[:, None, :]
    height = np.einsum("pfk,fk->pf", p - a, n)
    foot = p - height[..., None] * n
    inside = np.ones(height.shape, dtype=bool)
    for u, v in ((a, b), (b, c), (c, a)):
        inside &= np.einsum("pfk,fk->pf", np.cross(v - u, foot - u), n) >= 0
    best = np.where(inside, np.abs(height), np.inf)
    for u, v in ((a, b), (b, c), (c, a)):
        e = v - u
        s = np.clip(np.einsum("pfk,fk->pf", p - u, e) / np.einsum("fk,fk->f", e, e), 0, 1)
        best = np.minimum(best, np.linalg.norm(p - (u + s[..., None] * e), axis=-1))
    return best.min(axis=1)


def top_faces(tiles: np.ndarray) -> np.ndarray:
    return np.asarray(tiles)[:, TILE_FACES[0]]


def test_fit_paper_lays_out_the_papers_shape_as_before(paper: Design) -> None:
    # The 64-tile saddle at 200 mm with the paper's weights, as the layout gave it before
    # --fit existed (every metric it had then; the surface distance is now measured over the
    # whole top faces, not only their corners).
    metrics = paper.metrics()
    assert metrics["fit"] == {
        "used": "paper",
        "eq1": {"planar": 1e4, "square": 10.0, "surface": 0.1, "face_samples": 0.0},
    }
    assert paper.options.fit == "paper" and paper.options.weights == (1e4, 10.0, 0.1)
    before = {
        "flat_edge_error_max_mm": 7.097e-05,
        "hinge_gap_max_mm": 0.000157009,
        "hinge_gap_in_plane_max_mm": 0.000156406,
        "flat_gap_angle_min_deg": 12.134989,
        "flat_gap_angle_max_deg": 39.741349,
        "planarity_max_before_mm": 0.250350193,
        "tile_side_mean_mm": 27.535804886,
        "tile_side_spread": 1.355789653,
        "thickness_min_mm": 5.997901059,
        "thickness_max_mm": 6.000695078,
        "mass_g": 144.574,
        "hinges_bottom": 56,
    }
    for key, value in before.items():
        assert metrics[key] == pytest.approx(value, rel=1e-4, abs=1e-9), key


def test_weights_given_lay_out_their_own_shape_whatever_fit_says(paper: Design) -> None:
    # --weights equal to the paper's give the paper's design, recorded as weights
    given = design("saddle", replace(OPTIONS, weights=(1e4, 10.0, 0.1)))
    assert given.metrics()["fit"]["used"] == "weights"
    np.testing.assert_array_equal(given.tiles_assembled, paper.tiles_assembled)
    np.testing.assert_array_equal(given.tiles_flat, paper.tiles_flat)


def test_the_close_fit_is_closer_and_keeps_every_layout_target(
    close: Design, paper: Design
) -> None:
    m, p = close.metrics(), paper.metrics()
    assert m["fit"]["used"] == "close"
    assert m["fit"]["eq1"]["surface"] > p["fit"]["eq1"]["surface"]
    assert m["surface_distance_mean_mm"] <= p["surface_distance_mean_mm"]
    assert m["surface_distance_max_mm"] <= p["surface_distance_max_mm"]
    # the saddle's close shape meets both fit levels (paper: 6.9 % and 2.9 %)
    assert m["surface_distance_mean_mm"] <= 0.02 * m["tile_side_mean_mm"]
    assert m["surface_distance_max_mm"] <= 0.01 * close.target.bbox_diagonal_mm
    assert m["flat_edge_error_max_mm"] <= 1e-3
    assert m["hinge_gap_max_mm"] <= 1e-3
    assert m["flat_overlap_area_mm2"] == 0.0
    assert not close.problems
    # the frontier's point of the close shape is the design as kept
    tried = m["fit"]["close"]
    assert tried["surface_distance_mean_mm"] == m["surface_distance_mean_mm"]
    assert tried["surface_distance_max_mm"] == m["surface_distance_max_mm"]
    accuracy = max(m["flat_edge_error_max_mm"], m["hinge_gap_max_mm"])
    assert tried["accuracy_mm"] == pytest.approx(accuracy, rel=1e-3)


def test_a_close_shape_refused_gives_the_papers_design_with_a_note(paper: Design) -> None:
    # a gate no shape passes: the close shape is refused before its layout; --hinges dual
    # asked for, so no close shape is laid out with top hinges either
    policy = replace(DEFAULT_POLICY, close_conical_defect_max_deg=-1.0)
    refused = design("saddle", replace(OPTIONS, hinges="dual"), policy=policy)
    fit = refused.metrics()["fit"]
    assert fit["used"] == "paper" and "from conical" in fit["close"]["refused"]
    assert "close_top" not in fit
    assert any(n.startswith("fit: the close assembled shape") for n in refused.notes)
    np.testing.assert_array_equal(refused.tiles_assembled, paper.tiles_assembled)
    np.testing.assert_array_equal(refused.tiles_flat, paper.tiles_flat)
    # and the warning says what was tried, with the measured distance
    far = [w for w in refused.warnings if w.startswith("tiles sit far from the target")]
    assert len(far) == 1 and "the close fit was not kept" in far[0] and "--hinges top" in far[0]
    mean = paper.metrics()["surface_distance_mean_mm"]
    assert f"{mean:.2f} mm on average" in far[0]


def test_a_close_shape_refused_with_dual_hinges_is_laid_out_with_top_hinges(
    paper: Design,
) -> None:
    # --hinges unset and the dual close shape refused by the gate: the closer shape of
    # policy.close_fit_top is laid out with every hinge on top, and kept
    policy = replace(DEFAULT_POLICY, close_conical_defect_max_deg=-1.0)
    top = design("saddle", OPTIONS, policy=policy)
    m, p = top.metrics(), paper.metrics()
    assert top.options.hinges == "top" and m["hinges_bottom"] == 0
    fit = m["fit"]
    assert fit["used"] == "close" and "from conical" in fit["close"]["refused"]
    assert fit["eq1"] == fit["close_top"]["eq1"]
    assert fit["eq1"]["surface"] == DEFAULT_POLICY.close_fit_top.surface
    assert fit["close_top"]["surface_distance_mean_mm"] == m["surface_distance_mean_mm"]
    assert any("the design has top hinges" in n for n in top.notes)
    # closer than the paper's design, within the fit levels, and every layout target kept
    assert m["surface_distance_mean_mm"] < 0.5 * p["surface_distance_mean_mm"]
    assert m["surface_distance_max_mm"] < p["surface_distance_max_mm"]
    assert m["surface_distance_mean_mm"] <= 0.02 * m["tile_side_mean_mm"]
    assert m["surface_distance_max_mm"] <= 0.01 * top.target.bbox_diagonal_mm
    assert max(m["flat_edge_error_max_mm"], m["hinge_gap_max_mm"]) <= 1e-3
    assert m["flat_overlap_area_mm2"] == 0.0 and not top.problems
    assert not [w for w in top.warnings if "far from the target" in w]
    # it meets the fit level: not laid out again with the co-optimization's pull
    assert "co_surface" not in fit["close_top"]


def test_a_top_hinged_close_design_off_the_fit_level_is_pulled_closer_never_farther() -> None:
    # eq. 1 at surface weight 1 without face samples: laid out with top hinges it misses the
    # fit level, so the shape is laid out again with the co-optimization pulling it to the
    # target (policy.close_fit_top_co), and each pass is kept only where it meets the layout
    # targets and sits closer on average and no farther at most than the one before
    from drawstring.geometry.assembled.top import PAPER_WEIGHTS, Eq1Weights

    policy = replace(DEFAULT_POLICY, close_fit_top=Eq1Weights(1e4, 10.0, 1.0))
    options = replace(OPTIONS, hinges="top")
    pulled = design("saddle", options, policy=policy)
    m, tried = pulled.metrics(), pulled.metrics()["fit"]["close"]
    co = tried["co_surface"]
    assert co["kept"] and pulled.metrics()["fit"]["used"] == "close"
    assert 1 <= len(co["passes"]) <= DEFAULT_POLICY.close_fit_top_passes
    kept = [p for p in co["passes"] if p["kept"]]
    assert kept and co["passes"][: len(kept)] == kept  # a pass not kept ends them
    assert m["surface_distance_mean_mm"] == kept[-1]["surface_distance_mean_mm"]
    assert tried["surface_distance_mean_mm"] == kept[-1]["surface_distance_mean_mm"]
    steps = [co["paper_co"], *kept]
    for before, after in zip(steps, steps[1:], strict=False):
        assert after["surface_distance_mean_mm"] < before["surface_distance_mean_mm"]
        assert after["surface_distance_max_mm"] <= before["surface_distance_max_mm"]
        assert after["accuracy_mm"] <= 1e-3
    assert max(m["flat_edge_error_max_mm"], m["hinge_gap_max_mm"]) <= 1e-3
    assert m["flat_overlap_area_mm2"] == 0.0 and not pulled.problems
    # the layout the passes start from: the same shape with the paper's pull, which a pass
    # with the paper's own weight leaves in place (no closer)
    same = replace(policy, close_fit_top_co=(PAPER_WEIGHTS[2], 0.0))
    paper_co = design("saddle", options, policy=same)
    k, again = paper_co.metrics(), paper_co.metrics()["fit"]["close"]["co_surface"]
    assert not again["kept"] and [p["kept"] for p in again["passes"]] == [False]
    assert again["paper_co"] == co["paper_co"]
    assert co["paper_co"]["surface_distance_mean_mm"] == k["surface_distance_mean_mm"]
    assert co["paper_co"]["surface_distance_max_mm"] == k["surface_distance_max_mm"]
    assert k["surface_distance_mean_mm"] > 0.02 * k["tile_side_mean_mm"] or (
        k["surface_distance_max_mm"] > 0.01 * paper_co.target.bbox_diagonal_mm
    )


def test_a_pulled_layout_that_misses_the_layout_targets_is_polished_back_within_them() -> None:
    # pulled with weight 1e5 the joint solve settles where the pull holds the tiles off flat
    # congruence (the pass misses 1e-3 mm); laid out again from that shape on its own tiling
    # with policy.close_fit_top_polish, the tiles fold flat again and the shape stays as close
    from drawstring.geometry.assembled.top import Eq1Weights

    policy = replace(
        DEFAULT_POLICY, close_fit_top=Eq1Weights(1e4, 10.0, 1.0), close_fit_top_co=(1e5, 1e5)
    )
    polished = design("saddle", replace(OPTIONS, hinges="top"), policy=policy)
    m, tried = polished.metrics(), polished.metrics()["fit"]["close"]
    co = tried["co_surface"]
    first = co["passes"][0]
    assert first["accuracy_mm"] > 1e-3  # the pulled layout alone would not be kept
    polish = first["polish"]
    assert polish["kept"] and polish["accuracy_mm"] <= 1e-3 and first["kept"] and co["kept"]
    # the design is the polished layout, measured as such on the output
    assert m["surface_distance_mean_mm"] == tried["surface_distance_mean_mm"]
    assert tried["surface_distance_mean_mm"] == polish["surface_distance_mean_mm"]
    assert max(m["flat_edge_error_max_mm"], m["hinge_gap_max_mm"]) <= 1e-3
    assert m["flat_overlap_area_mm2"] == 0.0 and not polished.problems
    assert any(n.startswith("fit: the layout pulled to the target met") for n in polished.notes)
    # closer than the layout the passes start from, and the polish moved it little
    start = co["paper_co"]
    assert polish["surface_distance_mean_mm"] < 0.5 * start["surface_distance_mean_mm"]
    assert polish["surface_distance_max_mm"] < start["surface_distance_max_mm"]
    assert polish["surface_distance_mean_mm"] < 1.1 * first["surface_distance_mean_mm"]


def test_a_pulled_layout_whose_co_optimization_folds_a_tile_goes_no_further(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # the 60-tile cloud at 160 mm with top hinges misses the fit level; pulled with weight
    # 300 its co-optimization folds a tile (policy.co_required: refused at that round), and
    # the pass is neither laid out further (no flat layout finished, no hinges) nor kept: the
    # design is the one laid out with the paper's pull, as where no pass is tried
    from drawstring.pipeline import co_rounds, layout_stage

    hinged: list[int] = []
    layout_hinges = layout_stage.layout_hinges

    def counted(*args: object, **kwargs: object):
        hinged.append(1)
        return layout_hinges(*args, **kwargs)

    monkeypatch.setattr(layout_stage, "layout_hinges", counted)
    options = DesignOptions(tiles=60, size_mm=160.0, simulate=False, cad=False, hinges="top")
    policy = replace(DEFAULT_POLICY, close_fit_top_co=(300.0, 300.0))
    pulled = design("cloud", options, policy=policy)
    co = pulled.metrics()["fit"]["close"]["co_surface"]
    refused = {"refused": f"co-optimization not used: {co_rounds.FOLD_REASON}", "kept": False}
    assert co["passes"] == [refused] and not co["kept"]
    hinged_with_pass = len(hinged)
    hinged.clear()
    unpulled = design("cloud", options, policy=replace(policy, close_fit_top_passes=0))
    assert len(hinged) == hinged_with_pass
    assert pulled.hinge_layout is not None and unpulled.hinge_layout is not None
    np.testing.assert_array_equal(pulled.hinge_layout.tiles, unpulled.hinge_layout.tiles)
    m = pulled.metrics()
    assert m["surface_distance_mean_mm"] == co["paper_co"]["surface_distance_mean_mm"]
    assert m["surface_distance_mean_mm"] == unpulled.metrics()["surface_distance_mean_mm"]


def test_the_close_shape_with_top_hinges_steps_back_to_the_dual_weights(paper: Design) -> None:
    # the dual close shape refused by the gate, the closer top shape no closer than the
    # paper's (surface weight 0.01): the dual close shape's weights are laid out with every
    # hinge on top, and kept
    from drawstring.geometry.assembled.top import Eq1Weights

    far = Eq1Weights(1e4, 10.0, 0.01)
    policy = replace(DEFAULT_POLICY, close_conical_defect_max_deg=-1.0, close_fit_top=far)
    stepped = design("saddle", OPTIONS, policy=policy)
    m, fit = stepped.metrics(), stepped.metrics()["fit"]
    assert stepped.options.hinges == "top" and fit["used"] == "close"
    assert fit["eq1"] == fit["close_top"]["eq1"] == DEFAULT_POLICY.close_fit.to_json()
    (earlier,) = fit["close_top"]["earlier"]
    assert earlier["eq1"] == far.to_json()
    assert "no closer than the paper's shape" in earlier["refused"]
    assert m["surface_distance_mean_mm"] < paper.metrics()["surface_distance_mean_mm"]
    assert max(m["flat_edge_error_max_mm"], m["hinge_gap_max_mm"]) <= 1e-3
    assert not stepped.problems


def test_a_close_shape_no_closer_than_the_papers_is_not_kept(paper: Design) -> None:
    # eq. 1 that hardly pulls to the surface (0.01, the paper's 0.1) gives a shape no closer
    # than the paper's: refused for that, with dual hinges and then with top hinges
    from drawstring.geometry.assembled.top import Eq1Weights

    far = Eq1Weights(1e4, 10.0, 0.01)
    policy = replace(DEFAULT_POLICY, close_fit=far, close_fit_top=far, close_fit_rungs=(far,))
    refused = design("saddle", OPTIONS, policy=policy)
    fit = refused.metrics()["fit"]
    assert fit["used"] == "paper" and refused.options.hinges == "dual"
    for tried in (fit["close"], fit["close_top"], fit["between"]):
        assert "no closer than the paper's shape" in tried["refused"]
        assert tried["accuracy_mm"] <= 1e-3
    np.testing.assert_array_equal(refused.tiles_assembled, paper.tiles_assembled)
    np.testing.assert_array_equal(refused.tiles_flat, paper.tiles_flat)


def test_where_no_close_shape_is_kept_the_closest_shape_between_it_and_the_papers_is(
    paper: Design,
) -> None:
    # both close shapes hardly pull to the surface (0.01: no closer than the paper's shape)
    # and the first shape between them and the paper's that is not (policy.close_fit_rungs,
    # here a far one first) is laid out with top hinges and kept, closer than the paper's
    from drawstring.geometry.assembled.top import Eq1Weights

    far = Eq1Weights(1e4, 10.0, 0.01)
    rungs = (far, *DEFAULT_POLICY.close_fit_rungs)
    policy = replace(DEFAULT_POLICY, close_fit=far, close_fit_top=far, close_fit_rungs=rungs)
    between = design("saddle", OPTIONS, policy=policy)
    m, fit = between.metrics(), between.metrics()["fit"]
    assert fit["used"] == "close" and between.options.hinges == "top"
    assert fit["eq1"] == fit["between"]["eq1"] == rungs[1].to_json()
    (earlier,) = fit["between"]["earlier"]
    assert earlier["eq1"] == far.to_json() and "no closer" in earlier["refused"]
    assert "no closer" in fit["close"]["refused"] and "no closer" in fit["close_top"]["refused"]
    assert m["surface_distance_mean_mm"] < paper.metrics()["surface_distance_mean_mm"]
    assert m["surface_distance_max_mm"] <= paper.metrics()["surface_distance_max_mm"]
    assert max(m["flat_edge_error_max_mm"], m["hinge_gap_max_mm"]) <= 1e-3
    assert m["flat_overlap_area_mm2"] == 0.0 and not between.problems
    assert any("between the close one and the paper's" in n for n in between.notes)


def test_far_from_the_target_is_warned_only_where_the_fit_misses(
    close: Design, paper: Design
) -> None:
    assert not [w for w in close.warnings if "far from the target" in w]
    (far,) = [w for w in paper.warnings if "far from the target" in w]
    m = paper.metrics()
    side, diagonal = m["tile_side_mean_mm"], paper.target.bbox_diagonal_mm
    assert f"{100 * m['surface_distance_mean_mm'] / side:.1f} % of the mean tile side" in far
    assert f"{100 * m['surface_distance_max_mm'] / diagonal:.1f} % of the target's" in far
    assert "--fit close" in far


def test_target_obj_is_the_target_scaled_to_the_size(close: Design, folder: Path) -> None:
    vertices, faces = read_obj(folder / "target.obj")
    assert vertices.shape == close.target.vertices.shape
    assert faces.shape == close.target.faces.shape and faces.shape[1] == 3
    np.testing.assert_array_equal(faces, close.target.faces)
    np.testing.assert_allclose(vertices, close.target.vertices, atol=1e-6)
    extent = vertices.max(axis=0) - vertices.min(axis=0)
    assert extent.max() == pytest.approx(SIZE_MM, abs=1e-5)


def test_tile_distances_agree_with_design_json_and_with_target_obj(
    close: Design, folder: Path
) -> None:
    import json

    metrics = json.loads((folder / "design.json").read_text())["metrics"]
    with np.load(folder / "tiles.npz") as npz:
        tiles = npz["assembled"]
        tile_mean = npz["surface_distance_mean_mm"]
        tile_max = npz["surface_distance_max_mm"]
    assert tile_mean.shape == tile_max.shape == (len(tiles),)
    assert np.all((0 <= tile_mean) & (tile_mean <= tile_max))
    # design.json's figures are the tiles': the largest of them, and their area-weighted mean
    quads = top_faces(tiles)
    area = 0.5 * np.linalg.norm(
        np.cross(quads[:, 2] - quads[:, 0], quads[:, 3] - quads[:, 1]), axis=1
    )
    assert metrics["surface_distance_max_mm"] == pytest.approx(tile_max.max(), abs=1e-9)
    weighted = float(area @ tile_mean / area.sum())
    assert metrics["surface_distance_mean_mm"] == pytest.approx(weighted, rel=1e-6)
    # measured independently against target.obj on a few tiles: the corners (sampled too),
    # and the area-weighted midpoint rule on a 16 x 16 grid of each face (the distance has
    # a kink where a face crosses the target: either rule is a few per cent off there)
    vertices, faces = read_obj(folder / "target.obj")
    triangles = vertices[faces]
    s, r = (g.reshape(-1, 1) for g in np.meshgrid(*2 * [(np.arange(16) + 0.5) / 16]))
    for t in np.linspace(0, len(tiles) - 1, 5).astype(int):
        q = quads[t]
        grid = (1 - s) * (1 - r) * q[0] + s * (1 - r) * q[1] + s * r * q[2] + (1 - s) * r * q[3]
        du = (1 - r) * (q[1] - q[0]) + r * (q[2] - q[3])
        dv = (1 - s) * (q[3] - q[0]) + s * (q[2] - q[1])
        jacobian = np.linalg.norm(np.cross(du, dv), axis=1)
        corner = point_triangle_distances(q, triangles)
        assert corner.max() <= tile_max[t] + 1e-6
        inner = point_triangle_distances(grid, triangles)
        assert inner.max() <= tile_max[t] * 1.02 + 1e-3
        assert jacobian @ inner / jacobian.sum() == pytest.approx(tile_mean[t], rel=0.05)


def test_the_rigid_fit_brings_a_moved_design_back_and_keeps_its_layout(close: Design) -> None:
    # the close design's assembled shape turned 3 deg and shifted 2 mm off the target: the
    # rigid fit brings it back onto the kept shape; flat layout, hinges and accuracy unchanged
    from drawstring.pipeline.close_fit import rigidly_fitted
    from drawstring.pipeline.fit_quality import surface_distances
    from drawstring.pipeline.layout_stage import ShapedLayout

    angle = np.radians(3.0)
    turn = np.array(
        [[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]]
    )
    shift = np.array([2.0, 0.0, -1.0])
    a = close.assembled
    moved = replace(
        a, top=a.top @ turn.T + shift, bottom=a.bottom @ turn.T + shift,
        tiles=a.tiles @ turn.T + shift,
    )  # fmt: skip
    assert close.hinge_layout is not None
    layout = ShapedLayout(close.tiling, moved, close.flat, {}, close.hinge_layout, 1.5, ())
    fitted, distances, move = rigidly_fitted(layout, close.target)
    assert move > 2.0
    assert distances.mean < 0.5 * surface_distances(moved.tiles, close.target).mean
    assert distances.mean <= close.metrics()["surface_distance_mean_mm"] * 1.001
    # (near the kept shape, not on it: that one was moved only where its largest distance
    # did not rise, and the fit here goes to the optimum of its own start)
    assert np.abs(moved.tiles - a.tiles).max() > 3.0
    np.testing.assert_allclose(fitted.assembled.tiles, a.tiles, atol=0.25)
    m = close.metrics()
    accuracy = max(m["flat_edge_error_max_mm"], m["hinge_gap_max_mm"])
    assert fitted.accuracy_mm == pytest.approx(accuracy, rel=1e-3)
    assert fitted.flat is close.flat and fitted.hinge_layout is close.hinge_layout


def test_a_shape_set_aside_is_kept_only_where_no_farther_than_the_laid_out_papers() -> None:
    # the first tiling's distances set a close shape aside; against the paper's laid-out
    # design the nearest on average of those no farther on average and at most is kept
    from drawstring.geometry.assembled.fit import TopFaceDistances
    from drawstring.geometry.assembled.top import Eq1Weights
    from drawstring.pipeline.close_fit import _CloseTrial

    def far(mean: float, largest: float) -> TopFaceDistances:
        return TopFaceDistances(np.zeros(0), np.zeros(0), mean, largest)

    trial = _CloseTrial(*(None,) * 6)  # type: ignore[arg-type]
    weights = [Eq1Weights(1e4, 1.0, 100.0, 100.0), Eq1Weights(1e4, 10.0, 10.0, 10.0)]
    trial.set_aside = [
        ("closer, larger max", weights[0], OPTIONS, far(2.0, 9.0)),  # type: ignore[list-item]
        ("close", weights[1], OPTIONS, far(3.0, 7.0)),  # type: ignore[list-item]
    ]
    assert trial.closer_than(far(5.0, 8.0))[0] == "close"  # type: ignore[index]
    assert trial.closer_than(far(5.0, 9.0))[0] == "closer, larger max"  # type: ignore[index]
    assert trial.closer_than(far(2.5, 9.0))[0] == "closer, larger max"  # type: ignore[index]
    assert trial.closer_than(far(1.0, 9.0)) is None
    assert trial.closer_than(far(5.0, 6.0)) is None
