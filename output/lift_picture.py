"""``lift.png``: the gaps by energy basin, the energy peaks and the chosen lift points over the
flat layout.
"""

from __future__ import annotations

import textwrap
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.collections import PolyCollection
from numpy.typing import NDArray

from drawstring.output.flat_picture import open_gaps
from drawstring.output.pictures import STRING_COLOUR, plt, save

if TYPE_CHECKING:
    from matplotlib.axes import Axes

    from drawstring.geometry.route.lift import LiftPoints
    from drawstring.geometry.tiling.linkage import Linkage
    from drawstring.pipeline.record import Design


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
