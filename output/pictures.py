"""PNG pictures of a design, drawn with matplotlib's Agg backend (no screen needed)."""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection, PolyCollection  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from drawstring.geometry.tiling.linkage import TILE_FACES  # noqa: E402

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from drawstring.geometry.hinges.placement import HingeLayout
    from drawstring.geometry.route.lift import LiftPoints
    from drawstring.geometry.route.result import Route
    from drawstring.geometry.target.surface import Target
    from drawstring.geometry.tiling.grid import Tiling
    from drawstring.geometry.tiling.linkage import Linkage
    from drawstring.pipeline.record import Design

#: PNG metadata without version strings, so pictures are byte-identical across runs.
PNG_METADATA = {"Software": None}
COMPONENT_COLOURS = ("#f2b872", "#8fc1e3", "#a8d5a2", "#e3a1c9", "#d9d27a", "#b7a6e0")
#: The string in every picture.
STRING_COLOUR = "crimson"
#: Hinge markers in every picture (flat.png, assembly-tiles.png): shape and colour both tell
#: top from bottom (Okabe-Ito blue and orange: apart for every kind of colour vision and in
#: grey), and neither is the string's red.
TOP_HINGE = {"marker": "o", "colour": "#0072B2", "edge": "black", "label": "hinge on the top faces"}
BOTTOM_HINGE = {
    "marker": "s",
    "colour": "#E69F00",
    "edge": "black",
    "label": "hinge on the bottom faces",
}


def save(fig: Figure, path: Path, dpi: int = 110, tight: bool = False) -> None:
    """Write a figure as PNG with fixed metadata and close it; ``tight``: the canvas grows or
    shrinks to everything drawn (a legend below the axes, a title of several lines), which a
    fixed figure size cuts off where the layout is tall."""
    if tight:
        fig.savefig(path, dpi=dpi, metadata=PNG_METADATA, bbox_inches="tight", pad_inches=0.15)
    else:
        fig.savefig(path, dpi=dpi, metadata=PNG_METADATA)
    plt.close(fig)


def draw_splits(ax: Axes, tiling: Tiling) -> None:
    """Draw the split lines of a tiling on a flat-domain axes."""
    cell = tiling.cell_size
    origin = tiling.uv[0] - cell * tiling.linkage.vertex_ij[0]
    segments = []
    for s in tiling.linkage.splits:
        if s.axis == "x":
            a = origin + cell * np.array([s.line, s.lo])
            b = origin + cell * np.array([s.line, s.hi])
        else:
            a = origin + cell * np.array([s.lo, s.line])
            b = origin + cell * np.array([s.hi, s.line])
        segments.append([a, b])
    if segments:
        ax.add_collection(LineCollection(segments, colors="crimson", linewidths=2.5, zorder=5))


def save_scale_factor(tiling: Tiling, path: Path) -> None:
    """Per-tile conformal area scale over the flat domain, with the grid and the splits."""
    fig, ax = plt.subplots(figsize=(7, 5.5))
    polys = tiling.uv[tiling.quads]
    scale = tiling.tile_area_scale
    coll = PolyCollection(list(polys), array=scale, cmap="viridis", edgecolors="k", linewidths=0.3)
    ax.add_collection(coll)
    draw_splits(ax, tiling)
    fig.colorbar(coll, ax=ax, label="tile area scale (3D area / flat cell area)")
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("u (mm)")
    ax.set_ylabel("v (mm)")
    n_split = len(tiling.linkage.splits)
    ax.set_title(
        f"conformal scale over the flat domain: max/min {tiling.scale_factor_max:.2f} per part"
        f"\n({tiling.scale_factor_max_unsplit:.2f} before splits; {n_split} split(s) in red)",
        fontsize=10,
    )
    fig.tight_layout()
    save(fig, path)


def _equal_3d(ax: Axes, points: NDArray[np.float64]) -> None:
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre, half = (lo + hi) / 2, (hi - lo).max() / 2
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(centre[2] - half, centre[2] + half)  # type: ignore[attr-defined]
    ax.set_box_aspect((1, 1, 1))  # type: ignore[arg-type]


def save_lifted(target: Target, tiling: Tiling, path: Path) -> None:
    """The lifted quad grid (M3D) drawn over the target surface."""
    fig = plt.figure(figsize=(7, 6))
    ax = fig.add_subplot(projection="3d")
    tris = target.vertices[target.faces]
    surface = Poly3DCollection(list(tris), facecolors="0.85", edgecolors="none", alpha=0.35)
    ax.add_collection3d(surface)
    quads = tiling.vertices[tiling.quads]
    edges = np.concatenate([quads[:, [k, (k + 1) % 4]] for k in range(4)])
    colours = [COMPONENT_COLOURS[c % len(COMPONENT_COLOURS)] for c in tiling.linkage.tile_component]
    tiles = Poly3DCollection(list(quads), facecolors=colours, edgecolors="none", alpha=0.55)
    ax.add_collection3d(tiles)
    ax.add_collection3d(Line3DCollection(list(edges), colors="k", linewidths=0.4))
    _equal_3d(ax, target.vertices)
    ax.view_init(elev=32, azim=-60)
    ax.set_title(
        f"{target.name}: {tiling.linkage.n_tiles} tiles lifted onto the target", fontsize=10
    )
    fig.tight_layout()
    save(fig, path)


def _shade(normals: NDArray[np.float64], base: NDArray[np.float64]) -> NDArray[np.float64]:
    """Lambert shading of RGB colours ``base`` (k, 3) by unit face normals (k, 3)."""
    light = np.array([0.35, -0.45, 0.82])
    light /= np.linalg.norm(light)
    intensity = 0.35 + 0.65 * np.clip(normals @ light, 0.0, 1.0)
    return np.clip(base * intensity[:, None], 0.0, 1.0)


def draw_tiles_3d(ax: Axes, tiles: NDArray[np.float64], component: NDArray[np.int64]) -> None:
    """Shaded frustum tiles on a 3D axes, coloured by component."""
    from matplotlib.colors import to_rgb

    polys = tiles[:, TILE_FACES].reshape(-1, 4, 3)
    normal = np.cross(polys[:, 2] - polys[:, 0], polys[:, 3] - polys[:, 1])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    base = np.array(
        [to_rgb(COMPONENT_COLOURS[c % len(COMPONENT_COLOURS)]) for c in component]
    ).repeat(len(TILE_FACES), axis=0)
    coll = Poly3DCollection(
        list(polys), facecolors=_shade(normal, base), edgecolors="k", linewidths=0.15
    )
    ax.add_collection3d(coll)  # type: ignore[attr-defined]
    _equal_3d(ax, tiles.reshape(-1, 3))


def save_assembled(result: Design, path: Path) -> None:
    """Shaded render of the assembled tiles T3D, coloured by component."""
    fig = plt.figure(figsize=(7, 6))
    ax = fig.add_subplot(projection="3d")
    draw_tiles_3d(ax, result.tiles_assembled, result.tiling.linkage.tile_component)
    ax.view_init(elev=32, azim=-60)
    ax.set_axis_off()
    m = result.metrics()
    ax.set_title(
        f"{result.target.name}: assembled, {result.tiling.linkage.n_tiles} tiles, "
        f"{result.options.thickness_mm:g} mm thick\nplanarity {m['planarity_max_mm']:.1e} mm, "
        f"contact gap {m['contact_gap_max_mm']:.1e} mm, "
        f"surface distance {m['surface_distance_mean_mm']:.2f} mm mean",
        fontsize=9,
    )
    fig.tight_layout()
    save(fig, path)


def _lighten(colour: str, amount: float) -> tuple[float, float, float]:
    """``colour`` blended towards white by ``amount`` (0: unchanged, 1: white)."""
    from matplotlib.colors import to_rgb

    rgb = np.array(to_rgb(colour))
    r, g, b = (rgb + amount * (1.0 - rgb)).tolist()
    return (r, g, b)


def draw_hinges(
    ax: Axes, points: NDArray[np.float64], bottom: NDArray[np.bool_], size: float = 4.0
) -> None:
    """Hinge markers in the one convention of every picture (:data:`TOP_HINGE`,
    :data:`BOTTOM_HINGE`), labelled for the legend."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, np.shape(points)[-1])[:, :2]
    low = np.asarray(bottom, dtype=bool)
    for mask, style in ((~low, TOP_HINGE), (low, BOTTOM_HINGE)):
        if not mask.any():  # no legend entry for a kind of hinge the design does not have
            continue
        ax.plot(
            pts[mask, 0],
            pts[mask, 1],
            linestyle="none",
            marker=style["marker"],
            ms=size,
            mfc=style["colour"],
            mec=style["edge"],
            mew=0.5,
            label=style["label"],
            zorder=6,
        )


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
    from drawstring.geometry.route.rules import NODE_ENTRANCE
    from drawstring.geometry.tiling.linkage import gap_centroids

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


def flat_gap_angles(
    linkage: Linkage, tiles: NDArray[np.float64], bottom: NDArray[np.bool_]
) -> NDArray[np.float64]:
    """(G,) float, deg: the smallest opening angle at the slit ends of each gap, measured on the
    face that carries each hinge; NaN where a gap has no hinged slit end."""
    from drawstring.geometry.flat.layout import gap_junctions
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
    from matplotlib.collections import PolyCollection
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
    trimmed = (
        [tr.hinge for tr in layout.trims if tr.hinge >= 0] if layout.strategy == "dual" else []
    )
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
    # has shrunk the axes (an axes-relative offset covered the label on wide layouts).
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


def draw_lift_basins(
    ax: Axes,
    lift: LiftPoints,
    linkage: Linkage,
    corners: NDArray[np.float64],
    max_listed: int = 8,
) -> None:
    """Gaps coloured by energy basin, the peaks and the numbered lift points, with a legend.

    Each gap drains uphill to one energy peak: its basin.  Peaks whose basins are lifted
    together form a cluster, lifted at one lift point.  Gaps between parts (not opening in the
    flat layout, see :func:`open_gaps`) are drawn hollow.
    """
    from matplotlib import colormaps
    from matplotlib.lines import Line2D

    from drawstring.geometry.tiling.linkage import gap_centroids

    pos = gap_centroids(linkage, corners)
    cmap = colormaps["tab20"]
    colour = [cmap(int(b) % 20) for b in lift.basin]
    inside = open_gaps(linkage)
    ax.scatter(pos[inside, 0], pos[inside, 1], c=np.array(colour)[inside], s=16, zorder=3)
    ax.scatter(
        pos[~inside, 0],
        pos[~inside, 1],
        facecolors="none",
        edgecolors=[c for c, keep in zip(colour, inside, strict=True) if not keep],
        s=16,
        zorder=3,
    )
    pk = pos[lift.peaks]
    ax.scatter(pk[:, 0], pk[:, 1], c="black", s=30, marker="o", zorder=4)
    lp = pos[lift.lift_gaps]
    ax.scatter(lp[:, 0], lp[:, 1], c=STRING_COLOUR, s=200, marker="*", edgecolors="k", zorder=5)
    for number, (x, y) in enumerate(lp[:, :2], start=1):
        ax.annotate(
            str(number),
            (x, y),
            xytext=(7, 7),
            textcoords="offset points",
            fontsize=9,
            fontweight="bold",
            zorder=6,
        )
    handles: list[Line2D] = [
        Line2D(
            [], [], ls="none", marker="*", ms=12, mfc=STRING_COLOUR, mec="k", label="lift point"
        ),
        Line2D([], [], ls="none", marker="o", ms=6, color="k", label="energy peak"),
    ]
    for k, gap in enumerate(lift.peaks[:max_listed]):
        cluster = int(lift.clusters[k]) if k < len(lift.clusters) else -1
        where = f", lifted at {cluster + 1}" if 0 <= cluster < len(lift.lift_gaps) else ""
        handles.append(
            Line2D(
                [],
                [],
                ls="none",
                marker="o",
                ms=5,
                color=cmap(k % 20),
                label=f"basin of peak {k + 1} (gap {int(gap)}){where}",
            )
        )
    if len(lift.peaks) > max_listed:
        handles.append(
            Line2D([], [], ls="none", label=f"... {len(lift.peaks) - max_listed} more basins")
        )
    if not inside.all():
        handles.append(
            Line2D(
                [],
                [],
                ls="none",
                marker="o",
                ms=5,
                mfc="none",
                mec="0.3",
                label="gap between parts",
            )
        )
    ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=2, fontsize=7)
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")


def save_lift(result: Design, path: Path) -> None:
    """Gap potential energy basins, peaks and the chosen lift points over the flat layout."""
    linkage = result.tiling.linkage
    fig, ax = plt.subplots(figsize=(8, 7.5))
    polys = result.tiles_flat[:, :4, :2]
    ax.add_collection(PolyCollection(list(polys), facecolors="0.9", edgecolors="0.6", lw=0.3))
    draw_lift_basins(ax, result.lift, linkage, polys)
    lift = result.lift
    ax.set_title(
        f"{len(lift.lift_gaps)} lift point(s) (stars) for {len(lift.peaks)} energy peak(s) "
        f"(black); coupling threshold {lift.tau:g}\n"
        "each gap is coloured by its basin: the energy peak it climbs to\n"
        + "\n".join(textwrap.wrap(f"deployment check: {lift.check_name}", 90)),
        fontsize=9,
    )
    fig.tight_layout()
    save(fig, path, tight=True)


def place_labels(
    anchors: NDArray[np.float64],
    sizes: NDArray[np.float64],
    step: float | None = None,
    rings: int = 6,
    directions: int = 16,
    blocked: NDArray[np.float64] | None = None,
    bounds: Sequence[float] | None = None,
) -> NDArray[np.float64]:
    """Centres (n, 2) for n labels such that no two label boxes overlap.

    Works in any unit shared by the arguments (display pixels in practice).  Label ``i`` of size
    ``sizes[i]`` (width, height) is centred on ``anchors[i]`` when that box is free, else at the
    nearest free spot on rings of radius ``k * step`` (``k = 1 .. rings``, default step: the
    label height) around it; labels are placed in order, each avoiding those before it and the
    ``blocked`` boxes ``(m, 4)`` ``(x0, y0, x1, y1)``, and inside ``bounds`` ``(x0, y0, x1, y1)``
    when given.  A label with no free spot stays on its anchor.  Draw a leader line to every
    label moved off its anchor.
    """
    anchors = np.asarray(anchors, dtype=np.float64).reshape(-1, 2)
    sizes = np.broadcast_to(np.asarray(sizes, dtype=np.float64), anchors.shape)
    boxes: list[NDArray[np.float64]] = [
        np.asarray(b, dtype=np.float64) for b in (blocked if blocked is not None else [])
    ]
    angles = np.linspace(0.0, 2.0 * np.pi, directions, endpoint=False)
    placed = anchors.copy()
    for i, (anchor, size) in enumerate(zip(anchors, sizes, strict=True)):
        radius = float(step) if step is not None else float(size[1])
        offsets = [np.zeros(2)] + [
            k * radius * np.array([np.cos(a), np.sin(a)])
            for k in range(1, rings + 1)
            for a in angles
        ]
        for offset in offsets:
            centre = anchor + offset
            box = np.concatenate([centre - 0.5 * size, centre + 0.5 * size])
            if bounds is not None and (
                box[0] < bounds[0] or box[1] < bounds[1] or box[2] > bounds[2] or box[3] > bounds[3]
            ):
                continue
            if not any(
                box[0] < b[2] and b[0] < box[2] and box[1] < b[3] and b[1] < box[3] for b in boxes
            ):
                placed[i] = centre
                boxes.append(box)
                break
    return placed
