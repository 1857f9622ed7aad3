"""PNG pictures of a design, drawn with matplotlib's Agg backend (no screen needed)."""

from __future__ import annotations

import textwrap
from pathlib import Path
from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection, PolyCollection  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from drawstring.fabrication.pipeline import Design
    from drawstring.geometry.target import Target
    from drawstring.geometry.tiling import Tiling

#: PNG metadata without version strings, so pictures are byte-identical across runs.
PNG_METADATA = {"Software": None}
COMPONENT_COLOURS = ("#f2b872", "#8fc1e3", "#a8d5a2", "#e3a1c9", "#d9d27a", "#b7a6e0")


def save(fig: Figure, path: Path, dpi: int = 110) -> None:
    """Write a figure as PNG with fixed metadata and close it."""
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


# Faces of an 8-vertex tile (top, bottom, four sides), outward.
_TILE_FACES = ((0, 1, 2, 3), (4, 7, 6, 5), (0, 4, 5, 1), (1, 5, 6, 2), (2, 6, 7, 3), (3, 7, 4, 0))


def _shade(normals: NDArray[np.float64], base: NDArray[np.float64]) -> NDArray[np.float64]:
    """Lambert shading of RGB colours ``base`` (k, 3) by unit face normals (k, 3)."""
    light = np.array([0.35, -0.45, 0.82])
    light /= np.linalg.norm(light)
    intensity = 0.35 + 0.65 * np.clip(normals @ light, 0.0, 1.0)
    return np.clip(base * intensity[:, None], 0.0, 1.0)


def draw_tiles_3d(ax: Axes, tiles: NDArray[np.float64], component: NDArray[np.int64]) -> None:
    """Shaded frustum tiles on a 3D axes, coloured by component."""
    from matplotlib.colors import to_rgb

    faces = np.array(_TILE_FACES)
    polys = tiles[:, faces].reshape(-1, 4, 3)
    normal = np.cross(polys[:, 2] - polys[:, 0], polys[:, 3] - polys[:, 1])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    base = np.array(
        [to_rgb(COMPONENT_COLOURS[c % len(COMPONENT_COLOURS)]) for c in component]
    ).repeat(len(faces), axis=0)
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


def save_flat(result: Design, path: Path) -> None:
    """Flat layout: tiles by component, gaps by opening, hinges top/bottom, route, lift points."""
    from drawstring.geometry.hinges import draw_flat
    from drawstring.geometry.linkage import gap_centroids
    from drawstring.geometry.route import draw_route

    linkage = result.tiling.linkage
    extent = np.ptp(result.tiles_flat[..., :2].reshape(-1, 2), axis=0)
    width = 9.0
    height = float(np.clip(width * extent[1] / max(extent[0], 1e-9), 4.0, 12.0)) + 0.8
    fig, ax = plt.subplots(figsize=(width, height))
    draw_flat(ax, linkage, result.hinge_layout, result.flat)
    centres = gap_centroids(linkage, result.tiles_flat[:, :4, :2])
    draw_route(ax, result.route, centres, result.lift)
    # again, so the route's entries are listed too; below the plot, clear of the tiles
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.06), ncol=6, fontsize=7)
    ax.set_aspect("equal")
    ax.autoscale_view()
    m = result.metrics()
    ax.set_title(
        f"flat layout: {linkage.n_tiles} tiles, gaps {m['flat_gap_angle_min_deg']:.1f}"
        f"..{m['flat_gap_angle_max_deg']:.1f} deg, overlap {m['flat_overlap_area_mm2']:.2g} mm²\n"
        "hinges: dot top, red ring bottom; string route, black rings its boundary entrances; "
        "lift points starred",
        fontsize=9,
    )
    fig.tight_layout()
    save(fig, path)


def save_lift(result: Design, path: Path) -> None:
    """Gap potential energy basins, peaks and the chosen lift points over the flat layout."""
    from drawstring.geometry.lift import draw_lift
    from drawstring.geometry.linkage import gap_centroids

    linkage = result.tiling.linkage
    fig, ax = plt.subplots(figsize=(8, 6))
    polys = result.tiles_flat[:, :4, :2]
    ax.add_collection(PolyCollection(list(polys), facecolors="0.9", edgecolors="0.6", lw=0.3))
    draw_lift(ax, result.lift, gap_centroids(linkage, polys))
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_title(
        f"lift points (stars): {len(result.lift.lift_gaps)} of {len(result.lift.peaks)} energy "
        f"peaks; gaps coloured by basin; coupling threshold {result.lift.tau:g}\n"
        + "\n".join(textwrap.wrap(f"deployment check: {result.lift.check_name}", 90)),
        fontsize=9,
    )
    fig.tight_layout()
    save(fig, path)
