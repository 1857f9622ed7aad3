"""PNG pictures of a design, drawn with matplotlib's Agg backend (no screen needed): the
conventions every picture shares (colours, hinge markers, fixed PNG metadata), the pictures of
the target and the assembled shape, and the placing of labels that must not overlap.

``flat.png`` is drawn by :mod:`~drawstring.output.flat_picture`, ``fit.png`` by
:mod:`~drawstring.output.fit_picture`, ``lift.png`` by
:mod:`~drawstring.output.lift_picture`, the assembly guide's by
:mod:`~drawstring.output.assembly_pictures`.
"""

from __future__ import annotations

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

from drawstring.geometry.core.tile import TILE_FACES  # noqa: E402

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from drawstring.geometry.target.surface import Target
    from drawstring.geometry.tiling.grid import Tiling
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


def equal_3d(ax: Axes, points: NDArray[np.float64]) -> None:
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
    equal_3d(ax, target.vertices)
    ax.view_init(elev=32, azim=-60)
    ax.set_title(
        f"{target.name}: {tiling.linkage.n_tiles} tiles lifted onto the target", fontsize=10
    )
    fig.tight_layout()
    save(fig, path)


def shade(normals: NDArray[np.float64], base: NDArray[np.float64]) -> NDArray[np.float64]:
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
        list(polys), facecolors=shade(normal, base), edgecolors="k", linewidths=0.15
    )
    ax.add_collection3d(coll)  # type: ignore[attr-defined]
    equal_3d(ax, tiles.reshape(-1, 3))


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
