"""The stage drawings of output/drawing.py: each draws its stage's result on a given axis."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from drawstring.geometry.flat.layout import extrude_flat, optimize_flat  # noqa: E402
from drawstring.geometry.flat.verify import heightfield_tiles  # noqa: E402
from drawstring.geometry.hinges.placement import layout_hinges  # noqa: E402
from drawstring.geometry.route.lift import select_lift_points  # noqa: E402
from drawstring.geometry.route.plan import plan_route  # noqa: E402
from drawstring.geometry.tiling.linkage import build_linkage, gap_centroids  # noqa: E402
from drawstring.output.drawing import draw_flat, draw_lift, draw_route  # noqa: E402


@pytest.fixture(scope="module")
def scene():  # type: ignore[no-untyped-def]
    linkage = build_linkage(np.ones((4, 4), dtype=bool))
    uv = linkage.vertex_ij * 10.0 - 20.0
    top, t3 = heightfield_tiles(uv, linkage.tile_corners, "cylinder_inside", 4.0, 40.0)
    flat = optimize_flat(linkage, top, uv=uv, min_gap_angle_deg=10.0)
    layout = layout_hinges(linkage, flat, extrude_flat(flat, t3), t3, strategy="dual")
    return linkage, flat, layout


def test_draw_flat_draws_tiles_gaps_and_hinges(scene) -> None:  # type: ignore[no-untyped-def]
    linkage, flat, layout = scene
    fig, ax = plt.subplots()
    draw_flat(ax, linkage, layout, flat)
    # the gaps shaded by angle, the bottom outlines, the top faces
    assert len(ax.collections) == 3
    assert len(ax.collections[2].get_paths()) == linkage.n_tiles
    labels = ax.get_legend_handles_labels()[1]
    assert "bottom hinge" in labels and "top hinge" in labels
    plt.close(fig)


def test_draw_lift_and_route_mark_the_lift_points(scene) -> None:  # type: ignore[no-untyped-def]
    linkage, flat, layout = scene
    centroids = np.c_[(linkage.tile_cells + 0.5) * 10.0, np.zeros(linkage.n_tiles)]
    centroids[:, 2] = -np.linalg.norm(centroids[:, :2] - 20.0, axis=1)  # highest at the centre
    lift = select_lift_points(linkage, centroids, np.full(linkage.n_tiles, 0.01))
    assert len(lift.lift_gaps) >= 1
    pos = gap_centroids(linkage, layout.tiles[:, :4, :2])
    route = plan_route(linkage, pos, lift.lift_gaps)
    fig, (ax_lift, ax_route) = plt.subplots(1, 2)
    draw_lift(ax_lift, lift, pos)
    draw_route(ax_route, route, pos, lift)
    for ax in (ax_lift, ax_route):
        assert "lift points" in ax.get_legend_handles_labels()[1]
    stars = ax_route.collections[-1].get_offsets()
    np.testing.assert_array_equal(stars, pos[lift.lift_gaps])
    plt.close(fig)
