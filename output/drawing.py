"""Matplotlib drawings of single stages on a given axis: the flat layout with its hinges, the
lift points over the gap energy basins, and the string route.

The geometry stages compute; these draw their results on an ``Axes`` the caller owns (for a
quick look in a notebook or a debugging script).  The design folder's pictures are drawn by
:mod:`drawstring.output.pictures`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from drawstring.geometry.core.types import FloatArray
from drawstring.geometry.flat.verify import gap_opening_angles_deg
from drawstring.geometry.route.rules import NODE_ENTRANCE

if TYPE_CHECKING:
    from drawstring.geometry.flat.layout import FlatResult
    from drawstring.geometry.hinges.placement import HingeLayout
    from drawstring.geometry.route.lift import LiftPoints
    from drawstring.geometry.route.result import Route
    from drawstring.geometry.tiling.linkage import Linkage

__all__ = ["draw_flat", "draw_lift", "draw_route"]


def draw_flat(
    ax: Any,
    linkage: Linkage,
    layout: HingeLayout,
    flat: FlatResult | None = None,
) -> None:
    """Draw the flat layout on a matplotlib axis.

    Tiles (top faces) coloured by component, bottom outlines thin, gaps shaded by opening angle,
    hinges as filled dots (top) or hollow circles (bottom); a ``dual`` layout's trimmed pairs
    (every ``top`` pair is trimmed where it overlaps) crossed.
    """
    from matplotlib import colormaps
    from matplotlib.collections import PolyCollection

    tiles = layout.tiles
    comp_cmap = colormaps["Pastel1"]
    colours = [comp_cmap(int(c) % 9) for c in linkage.tile_component]
    if flat is not None and flat.junctions.elements.size:
        gap_polys: list[FloatArray] = []
        gap_vals: list[float] = []
        measured = gap_opening_angles_deg(linkage, tiles, layout.bottom)
        ang: dict[int, float] = {}
        for g, value in zip(flat.junctions.gap[flat.junctions.is_end], measured, strict=True):
            ang[int(g)] = min(ang.get(int(g), 90.0), float(value))
        for g in range(linkage.n_gaps):
            sides = linkage.gap_sides[g]
            sides = sides[sides[:, 0] >= 0]
            ring: list[FloatArray] = []
            for t, s in sides:  # the void, traced along the final tiles' top sides
                ring.append(tiles[t, (s + 1) % 4, :2])
                ring.append(tiles[t, s, :2])
            gap_polys.append(np.array(ring))
            gap_vals.append(float(ang.get(g, 0.0)))
        pc = PolyCollection(gap_polys, array=np.array(gap_vals), cmap="viridis", alpha=0.6)
        pc.set_clim(0.0, 90.0)
        ax.add_collection(pc)
        ax.figure.colorbar(pc, ax=ax, label="gap opening angle (deg)", shrink=0.7)
    ax.add_collection(
        PolyCollection(list(tiles[:, 4:, :2]), facecolors="none", edgecolors="0.5", linewidths=0.3)
    )
    ax.add_collection(
        PolyCollection(list(tiles[:, :4, :2]), facecolors=colours, edgecolors="k", linewidths=0.5)
    )
    pts = layout.hinge_points
    top = ~layout.bottom
    ax.plot(pts[top, 0], pts[top, 1], "o", ms=3, color="k", label="top hinge")
    ax.plot(pts[~top, 0], pts[~top, 1], "o", ms=4, mfc="none", mec="r", label="bottom hinge")
    if layout.strategy == "dual" and layout.trims:
        cut = np.array([tr.hinge for tr in layout.trims])
        ax.plot(pts[cut, 0], pts[cut, 1], "x", ms=7, color="m", label="trimmed pair")
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.legend(loc="upper right", fontsize=7)


def draw_lift(ax: Any, lift: LiftPoints, gap_centroids_flat: ArrayLike) -> None:
    """Scatter gaps coloured by basin; mark peaks (black dots) and lift points (red stars).

    Parameters
    ----------
    ax : a matplotlib Axes.
    lift : the selection to draw.
    gap_centroids_flat : (G, 2) float, mm, gap positions in the flat configuration.
    """
    pos = np.asarray(gap_centroids_flat, dtype=np.float64)
    ax.scatter(pos[:, 0], pos[:, 1], c=lift.basin % 20, cmap="tab20", vmin=0, vmax=19, s=14)
    pk = pos[lift.peaks]
    ax.scatter(pk[:, 0], pk[:, 1], c="black", s=28, marker="o", label="peaks")
    lp = pos[lift.lift_gaps]
    ax.scatter(
        lp[:, 0], lp[:, 1], c="red", s=160, marker="*", edgecolors="black", label="lift points"
    )
    ax.set_aspect("equal")


def draw_route(ax: Any, route: Route, gap_centroids_flat: ArrayLike, lift_points: Any = ()) -> None:
    """Draw the closed route polyline and the lift points on a matplotlib Axes.

    Parameters
    ----------
    ax : matplotlib Axes.
    route : the route.
    gap_centroids_flat : (G, 2) float, mm.
    lift_points : gap ids, or an object with a ``lift_gaps`` attribute (``LiftPoints``).
    """
    pos = np.asarray(gap_centroids_flat, dtype=np.float64)[:, :2]
    gaps = np.append(route.gaps, route.gaps[:1])
    ax.plot(pos[gaps, 0], pos[gaps, 1], "-", color="crimson", lw=1.8, label="string", zorder=4)
    ax.plot(pos[route.gaps, 0], pos[route.gaps, 1], ".", color="crimson", ms=4, zorder=4)
    entr = route.gaps[route.labels == NODE_ENTRANCE]
    ax.plot(pos[entr, 0], pos[entr, 1], "o", mfc="none", mec="k", ms=6, label="entrances", zorder=4)
    lifts = np.asarray(getattr(lift_points, "lift_gaps", lift_points), dtype=np.int64)
    if lifts.size:
        ax.scatter(
            pos[lifts, 0],
            pos[lifts, 1],
            s=180,
            marker="*",
            c="red",
            edgecolors="black",
            zorder=5,
            label="lift points",
        )
    ax.set_aspect("equal")
