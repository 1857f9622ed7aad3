"""``fit.png``: the assembled tiles coloured by how far their top faces sit from the target,
with a scale bar in mm on which the quality level is marked."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from drawstring.geometry.core.tile import TILE_FACES
from drawstring.geometry.core.tolerances import SURFACE_MAX_REL, SURFACE_MEAN_REL
from drawstring.output.pictures import equal_3d, plt, save, shade

if TYPE_CHECKING:
    from drawstring.geometry.assembled.fit import TopFaceDistances
    from drawstring.pipeline.record import Design

#: The colour map of the distance, here and in the report's 3D view (``report.js``'s
#: ``FIT_STOPS`` are its colours at 0, 1/4, 1/2, 3/4 and 1).
FIT_COLOURMAP = "viridis"


def save_fit(result: Design, distances: TopFaceDistances, path: Path) -> None:
    """The assembled tiles, each coloured by the mean distance of its top face from the target
    (``distances``, :func:`~drawstring.pipeline.fit_quality.surface_distances`); the scale
    runs from 0 to the largest tile's mean, or to the quality level where that is larger, and
    marks the quality level of the mean (``SURFACE_MEAN_REL`` of the mean tile side)."""
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    tiles = result.tiles_assembled
    metrics = result.metrics()
    side = float(metrics.get("tile_side_mean_mm", 0.0))
    level = SURFACE_MEAN_REL * side
    top = float(distances.tile_mean.max(initial=0.0))
    norm = Normalize(0.0, max(top, level, 1e-6))
    cmap = colormaps[FIT_COLOURMAP]
    polys = tiles[:, TILE_FACES].reshape(-1, 4, 3)
    normal = np.cross(polys[:, 2] - polys[:, 0], polys[:, 3] - polys[:, 1])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    base = cmap(norm(distances.tile_mean))[:, :3].repeat(len(TILE_FACES), axis=0)
    fig = plt.figure(figsize=(7.6, 6))
    ax = fig.add_subplot(projection="3d")
    coll = Poly3DCollection(
        list(polys), facecolors=shade(normal, base), edgecolors="k", linewidths=0.15
    )
    ax.add_collection3d(coll)
    equal_3d(ax, tiles.reshape(-1, 3))
    ax.view_init(elev=32, azim=-60)
    ax.set_axis_off()
    bar = fig.colorbar(
        ScalarMappable(norm=norm, cmap=cmap), ax=ax, shrink=0.7, pad=0.02,
        label="distance of the tile's top face from the target, mean over the face (mm)",
    )  # fmt: skip
    if level > 0:
        bar.ax.axhline(level, color="crimson", linewidth=1.5)
        bar.ax.text(
            -0.3, level, f"{100 * SURFACE_MEAN_REL:g} % of a side", color="crimson",
            fontsize=7, ha="right", va="center", transform=bar.ax.get_yaxis_transform(),
        )  # fmt: skip
    diagonal = result.target.bbox_diagonal_mm
    ax.set_title(
        f"{result.target.name}: distance from the target, {distances.mean:.2f} mm on average "
        f"({100 * distances.mean / side if side else 0.0:.1f} % of a tile side; quality level "
        f"{100 * SURFACE_MEAN_REL:g} %)\nlargest {distances.max:.2f} mm "
        f"({100 * distances.max / diagonal if diagonal else 0.0:.2f} % of the target's "
        f"diagonal; quality level {100 * SURFACE_MAX_REL:g} %)",
        fontsize=9,
    )
    fig.tight_layout()
    save(fig, path)
