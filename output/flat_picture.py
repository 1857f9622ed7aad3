"""``flat.png``: the flat layout with its tiles by part, the gaps by opening angle, the hinges
(top or bottom), the string route, the lift points and the trimmed overlaps.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.collections import LineCollection, PolyCollection
from numpy.typing import NDArray

from drawstring.geometry.core.tile import HingeStrategy
from drawstring.geometry.route.rules import NODE_ENTRANCE
from drawstring.geometry.tiling.linkage import gap_centroids
from drawstring.output.pictures import (
    COMPONENT_COLOURS,
    STRING_COLOUR,
    draw_hinges,
    plt,
    save,
)

if TYPE_CHECKING:
    from matplotlib.axes import Axes

    from drawstring.geometry.hinges.placement import HingeLayout
    from drawstring.geometry.route.result import Route
    from drawstring.geometry.tiling.linkage import Linkage
    from drawstring.pipeline.record import Design


def _lighten(colour: str, amount: float) -> tuple[float, float, float]:
    """``colour`` blended towards white by ``amount`` (0: unchanged, 1: white)."""
    from matplotlib.colors import to_rgb

    rgb = np.array(to_rgb(colour))
    r, g, b = (rgb + amount * (1.0 - rgb)).tolist()
    return (r, g, b)


def open_gaps(linkage: Linkage) -> NDArray[np.bool_]:
    """(G,) bool: gaps that open between hinged tiles of one part.

    A gap counts when all its tiles (four, or fewer at the boundary) belong to one component and
    it is not on a split line.  A "gap" on a split has its hinges cut and tiles of two parts
    around it: in the flat layout its tile sides lie far apart, and the space between them is
    not an opening of the linkage.
    """
    keep = np.zeros(linkage.n_gaps, dtype=bool)
    for g in range(linkage.n_gaps):
        parts = np.unique(linkage.tile_component[linkage.gap_tiles(g)])
        keep[g] = len(parts) == 1 and linkage.gap_kind[g] != "split"
    return keep


def gap_rings(linkage: Linkage, corners: NDArray[np.float64]) -> list[NDArray[np.float64]]:
    """(G) polygons (k, 2): each void traced along its tiles' top sides, counter-clockwise."""
    rings = []
    for g in range(linkage.n_gaps):
        ring: list[NDArray[np.float64]] = []
        for t, s in linkage.gap_sides[g]:
            if t < 0:
                continue
            ring.append(corners[t, (s + 1) % 4, :2])
            ring.append(corners[t, s, :2])
        rings.append(np.array(ring).reshape(-1, 2))
    return rings


def side_openings(tiles: NDArray[np.float64]) -> NDArray[np.float64]:
    """(T, 4, 2) float, mm: the centre of each side face seen from above (where the string's
    channel opens; side ``s`` joins top corners ``s``, ``s + 1`` and the bottom ones below)."""
    t = np.asarray(tiles, dtype=np.float64)[..., :2]
    if t.shape[1] == 4:
        return np.asarray(0.5 * (t + np.roll(t, -1, axis=1)))
    top = 0.5 * (t[:, :4] + np.roll(t[:, :4], -1, axis=1))
    low = 0.5 * (t[:, 4:] + np.roll(t[:, 4:], -1, axis=1))
    return np.asarray(0.5 * (top + low))


def route_runs(
    openings: NDArray[np.float64],
    tiles: NDArray[np.int64],
    enter: NDArray[np.int64],
    leave: NDArray[np.int64],
    component: NDArray[np.int64],
) -> tuple[list[NDArray[np.float64]], list[NDArray[np.float64]]]:
    """The closed string route as straight runs between side openings.

    Returns ``(within, between)``: runs through a tile or across a gap of one part, and runs
    from one part to another (across a split, often across empty space in the flat layout).
    """
    within: list[NDArray[np.float64]] = []
    between: list[NDArray[np.float64]] = []
    count = len(tiles)
    for k in range(count):
        tile = int(tiles[k])
        within.append(np.array([openings[tile, enter[k]], openings[tile, leave[k]]]))
        after = int(tiles[(k + 1) % count])
        if count < 2:
            continue
        run = np.array([openings[tile, leave[k]], openings[after, enter[(k + 1) % count]]])
        (within if component[tile] == component[after] else between).append(run)
    return within, between


def draw_flat_layout(
    ax: Axes,
    linkage: Linkage,
    tiles: NDArray[np.float64],
    hinge_points: NDArray[np.float64],
    bottom: NDArray[np.bool_],
    gap_angle_deg: NDArray[np.float64],
    route: Route | None = None,
    lift_gaps: NDArray[np.int64] | Sequence[int] = (),
    trimmed: Sequence[int] = (),
) -> None:
    """The flat layout on ``ax``: tiles by part, open gaps by angle, hinges, route, lift points.

    Parameters
    ----------
    tiles : (T, 8, 3) float, mm, flat tiles (top corners 0..3).
    hinge_points : (H, 2+) float, mm.
    bottom : (H,) bool, hinge on the bottom faces.
    gap_angle_deg : (G,) float, opening angle per gap (NaN: not measured).  Only the gaps of
        :func:`open_gaps` with an angle are shaded (gid ``"gaps"``).
    route : drawn through the tiles' side openings; runs between parts dashed.
    lift_gaps : gap ids of the lift points (starred at the gap centroid).
    trimmed : hinge ids of trimmed pairs (crossed).
    """
    _shade_open_gaps(ax, linkage, tiles, gap_angle_deg)
    colours = [
        _lighten(COMPONENT_COLOURS[c % len(COMPONENT_COLOURS)], 0.45)
        for c in linkage.tile_component
    ]
    ax.add_collection(
        PolyCollection(list(tiles[:, 4:, :2]), facecolors="none", edgecolors="0.5", linewidths=0.3)
    )
    ax.add_collection(
        PolyCollection(list(tiles[:, :4, :2]), facecolors=colours, edgecolors="k", linewidths=0.5)
    )
    draw_hinges(ax, hinge_points, bottom, size=4.0)
    cut = np.asarray(trimmed, dtype=np.int64)
    if cut.size:
        pts = np.asarray(hinge_points)[cut]
        ax.plot(pts[:, 0], pts[:, 1], "x", ms=7, color="k", label="trimmed pair", zorder=6)
    if route is not None and len(route.tiles):
        _draw_route(ax, linkage, tiles, route)
    lifts = np.asarray(lift_gaps, dtype=np.int64)
    if lifts.size:
        centres = gap_centroids(linkage, tiles[:, :4, :2])
        ax.scatter(
            centres[lifts, 0],
            centres[lifts, 1],
            s=180,
            marker="*",
            c=STRING_COLOUR,
            edgecolors="black",
            zorder=7,
            label="lift points",
        )
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")


def _shade_open_gaps(
    ax: Axes, linkage: Linkage, tiles: NDArray[np.float64], gap_angle_deg: NDArray[np.float64]
) -> None:
    """The gaps of :func:`open_gaps` with a measured angle, shaded by it, with a colour bar."""
    angle = np.asarray(gap_angle_deg, dtype=np.float64)
    shade = open_gaps(linkage) & np.isfinite(angle)
    rings = gap_rings(linkage, tiles)
    chosen = np.flatnonzero(shade)
    if len(chosen):
        pc = PolyCollection(
            [rings[g] for g in chosen], array=angle[chosen], cmap="viridis", alpha=0.6
        )
        pc.set_clim(0.0, 90.0)
        pc.set_gid("gaps")
        ax.add_collection(pc)
        ax.figure.colorbar(
            pc, ax=ax, label="gap opening angle (deg), gaps within one part", shrink=0.7
        )


def _draw_route(ax: Axes, linkage: Linkage, tiles: NDArray[np.float64], route: Route) -> None:
    """The string through the tiles' side openings (dashed from one part to another) and the
    boundary entrances."""
    within, between = route_runs(
        side_openings(tiles),
        route.tiles,
        route.enter_side,
        route.leave_side,
        linkage.tile_component,
    )
    ax.add_collection(
        LineCollection(within, colors=STRING_COLOUR, linewidths=1.8, zorder=4, label="string")
    )
    if between:
        ax.add_collection(
            LineCollection(
                between,
                colors=STRING_COLOUR,
                linewidths=1.4,
                linestyles=(0, (4, 3)),
                zorder=4,
                label="string from one part to another",
            )
        )
    centres = gap_centroids(linkage, tiles[:, :4, :2])
    entr = route.gaps[route.labels == NODE_ENTRANCE]
    ax.plot(
        centres[entr, 0],
        centres[entr, 1],
        "o",
        mfc="none",
        mec="k",
        ms=6,
        label="boundary entrances",
        zorder=5,
    )


def flat_gap_angles(
    linkage: Linkage, tiles: NDArray[np.float64], bottom: NDArray[np.bool_]
) -> NDArray[np.float64]:
    """(G,) float, deg: the smallest opening angle at the slit ends of each gap, measured on the
    face that carries each hinge; NaN where a gap has no hinged slit end."""
    from drawstring.geometry.flat.junctions import gap_junctions
    from drawstring.geometry.flat.verify import gap_opening_angles_deg

    angle = np.full(linkage.n_gaps, np.nan)
    junctions = gap_junctions(linkage)
    if not junctions.is_end.any():
        return angle
    measured = gap_opening_angles_deg(linkage, tiles, bottom)
    for g, value in zip(junctions.gap[junctions.is_end], measured, strict=True):
        angle[g] = np.fmin(angle[g], float(value))
    return angle


def draw_trims(ax: Axes, layout: HingeLayout) -> None:
    """The overlaps cut away from the tiles (``hinges.json``'s ``trims``), seen from above:
    each convex piece's outline, hatched, and a cross at its centre (a fraction of a square
    millimetre is a pixel or two in a 200 mm layout)."""
    from scipy.spatial import ConvexHull, QhullError

    outlines = []
    for trim in layout.trims:
        xy = np.asarray(trim.vertices, dtype=np.float64)[:, :2]
        try:
            outlines.append(xy[ConvexHull(xy).vertices])
        except QhullError:  # a piece with no extent seen from above
            continue
    if outlines:
        ax.add_collection(
            PolyCollection(
                outlines,
                facecolors="none",
                edgecolors="#7a0019",
                hatch="/////",
                linewidths=0.5,
                zorder=5,
            )
        )
        centres = np.array([outline.mean(axis=0) for outline in outlines])
        ax.scatter(
            centres[:, 0],
            centres[:, 1],
            marker="x",
            s=14,
            linewidths=0.8,
            color="#7a0019",
            zorder=6,
            label="trimmed overlap (cut away; hatched, crossed)",
        )


def save_flat(result: Design, path: Path) -> None:
    """Flat layout: tiles by component, gaps by opening, hinges top/bottom, route, lift points."""
    linkage = result.tiling.linkage
    layout = result.hinge_layout
    extent = np.ptp(result.tiles_flat[..., :2].reshape(-1, 2), axis=0)
    width = 9.0
    height = float(np.clip(width * extent[1] / max(extent[0], 1e-9), 4.0, 12.0)) + 0.8
    fig, ax = plt.subplots(figsize=(width, height))
    dual = layout.strategy == HingeStrategy.DUAL
    trimmed = [tr.hinge for tr in layout.trims if tr.hinge >= 0] if dual else []
    draw_flat_layout(
        ax,
        linkage,
        layout.tiles,
        layout.hinge_points,
        layout.bottom,
        flat_gap_angles(linkage, layout.tiles, layout.bottom),
        result.route,
        result.lift.lift_gaps,
        trimmed,
    )
    draw_trims(ax, layout)
    m = result.metrics()
    parts = linkage.n_components
    ax.set_title(
        f"flat layout: {linkage.n_tiles} tiles in {parts} part{'s' if parts != 1 else ''}, "
        f"gaps {m['flat_gap_angle_min_deg']:.1f}..{m['flat_gap_angle_max_deg']:.1f} deg, "
        f"overlap {m['flat_overlap_area_mm2']:.2g} mm²\n"
        + (
            "tiles coloured by part; only gaps within one part are shaded; dashed: the string "
            "crossing between parts"
            if parts > 1
            else "gaps shaded by opening angle"
        ),
        fontsize=9,
    )
    fig.tight_layout(rect=(0.0, 0.6 / height, 1.0, 1.0))
    # The legend goes just under the x label, placed in figure space once the equal aspect
    # has shrunk the axes (an offset relative to the axes would cover the label of a wide layout).
    ax.apply_aspect()
    tight = ax.get_tightbbox()
    bottom = 0.0 if tight is None else tight.transformed(fig.transFigure.inverted()).y0
    handles, labels = ax.get_legend_handles_labels()
    fig.legend(
        handles,
        labels,
        loc="upper center",
        bbox_to_anchor=(0.5, bottom - 0.005),
        bbox_transform=fig.transFigure,
        ncol=4,
        fontsize=7,
    )
    save(fig, path)
