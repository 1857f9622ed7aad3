"""The assembly guide's pictures: ``assembly-tiles.png`` (where each tile goes),
``assembly-threading.png`` (the threading order) and ``assembly-pull.png`` (what to hold and
lift).  Step numbers and lift-point letters are those of ``assembly.md``
(:func:`~drawstring.output.assembly_order.plan_guide`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.lines import Line2D
from mpl_toolkits.mplot3d.art3d import Poly3DCollection
from numpy.typing import NDArray

from drawstring.cad.paths import route_openings
from drawstring.geometry.core.tile import HingeSide
from drawstring.output import pictures
from drawstring.output.assembly_order import Guide, Stop, plan_guide, stop_positions

#: Top of the legends under the flat-layout pictures, in axes heights below the axes: clear of
#: the x-axis label.
LEGEND_BELOW = -0.15
#: The string in every picture.
RED = pictures.STRING_COLOUR

StopPoints = tuple[NDArray[np.float64] | None, NDArray[np.float64] | None]


@dataclass(frozen=True)
class _Scene:
    """What the three pictures share: the flat tiles, the route in threading order and where
    its lift points are seen from above."""

    tiles_flat: NDArray[np.float64]
    steps: NDArray[np.int64]
    guide: Guide
    #: Per stop of the guide, (3,) float, mm: where the string comes up and goes back down.
    stop_points: list[StopPoints]
    #: Up and down markers at most this far apart (mm) share one label.
    near: float
    #: Font size of the tile and step numbers.
    font: float

    @property
    def top(self) -> NDArray[np.float64]:
        """(T, 4, 2) float, mm: the tiles' top faces seen from above."""
        return self.tiles_flat[:, :4, :2]


def write_pictures(
    out: Path,
    tiles_flat: NDArray[np.float64],
    tiles_assembled: NDArray[np.float64],
    hinges: NDArray[np.int64],
    hinge_side: Sequence[str],
    steps: NDArray[np.int64],
    lifts: NDArray[np.int64],
    cut_hinges: Sequence[int] = (),
) -> list[str]:
    """Three pictures for assembly.md: numbered tiles with hinges (``cut_hinges``, printed
    loose between print jobs, ringed), threading order, pulling.

    ``steps`` (S, 4) is the route, ``lifts`` (L, 2) the lift bores ``(tile, side)``; step numbers
    and lift-point letters are those of :func:`~drawstring.output.assembly_text.write_assembly`
    (:func:`~drawstring.output.assembly_order.plan_guide`).
    """
    guide = plan_guide(steps, lifts)
    top = tiles_flat[:, :4, :2]
    edges = np.linalg.norm(top - np.roll(top, -1, axis=1), axis=2)
    scene = _Scene(
        tiles_flat,
        steps,
        guide,
        [stop_positions(tiles_flat, steps, guide, stop) for stop in guide.stops],
        near=2.5 * float(np.median(edges)) if edges.size else 0.0,
        font=max(4.0, min(10.0, 300.0 / math.sqrt(len(tiles_flat)))),
    )
    part = _components(len(tiles_flat), hinges)
    figures = (
        ("assembly-tiles.png", lambda: _tiles_picture(scene, hinges, hinge_side, cut_hinges)),
        ("assembly-threading.png", lambda: _threading_picture(scene, part)),
        ("assembly-pull.png", lambda: _pull_picture(scene, tiles_assembled)),
    )
    for name, draw in figures:
        pictures.save(draw(), out / name, tight=True)
    return [name for name, _ in figures]


def _base(scene: _Scene, title: str, ax: Any = None) -> tuple[Any, Any]:
    """The tiles seen from above on ``ax`` (a new figure's when None), with room round them
    for labels; the figure (None when ``ax`` was given) and the axes."""
    fig = None
    if ax is None:
        fig, ax = pictures.plt.subplots(figsize=(7, 7.6))
    ax.add_collection(
        PolyCollection(list(scene.top), facecolors="#f7e4c2", edgecolors="#444", lw=0.6)
    )
    ax.set_aspect("equal")
    ax.autoscale_view()
    for axis, (lo, hi) in (("x", ax.get_xlim()), ("y", ax.get_ylim())):
        pad = 0.04 * (hi - lo)  # room for labels outside the layout
        getattr(ax, f"set_{axis}lim")(lo - pad, hi + pad)
    ax.set_title(title)
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    return fig, ax


def _legend(ax: Any, handles: list[Any], columns: int = 2) -> None:
    """The legend under the axes, clear of the x-axis label."""
    ax.legend(
        handles=handles,
        loc="upper center",
        bbox_to_anchor=(0.5, LEGEND_BELOW),
        ncol=columns,
        fontsize=7,
        frameon=False,
    )


def _tiles_picture(
    scene: _Scene,
    hinges: NDArray[np.int64],
    hinge_side: Sequence[str],
    cut_hinges: Sequence[int],
) -> Any:
    """``assembly-tiles.png``: the numbered tiles and their hinges, those between print jobs
    ringed."""
    tiles_flat = scene.tiles_flat
    fig, ax = _base(scene, "Where each tile goes (flat layout, seen from above)")
    for tile, (x, y) in enumerate(scene.top.mean(axis=1)):
        ax.text(x, y, str(tile), ha="center", va="center", fontsize=scene.font)
    points = np.array(
        [
            0.5
            * (
                tiles_flat[a, (0 if s == HingeSide.TOP else 4) + ca, :2]
                + tiles_flat[b, (0 if s == HingeSide.TOP else 4) + cb, :2]
            )
            for (a, ca, b, cb), s in zip(hinges, hinge_side, strict=True)
        ]
    ).reshape(-1, 2)
    pictures.draw_hinges(ax, points, np.array([s != HingeSide.TOP for s in hinge_side], dtype=bool))
    if len(cut_hinges):
        cut = points[np.asarray(cut_hinges, dtype=np.int64)]
        ax.scatter(
            cut[:, 0], cut[:, 1], s=90, facecolors="none", edgecolors="#d62728", linewidths=1.4,
            zorder=6, label="hinge between print jobs: glue its loose pad in",
        )  # fmt: skip
    ax.legend(
        loc="upper center", bbox_to_anchor=(0.5, LEGEND_BELOW), ncol=2, fontsize=7, frameon=False
    )
    fig.tight_layout()
    return fig


def _draw_stops(ax: Any, scene: _Scene, size: float, letters: bool = True) -> list[Any]:
    """Up/down markers and letters of the lift points; the legend entries they need."""
    handles = []
    for stop, (up, down) in zip(scene.guide.stops, scene.stop_points, strict=True):
        for point, marker in ((up, "^"), (down, "v")):
            if point is not None:
                ax.plot(point[0], point[1], marker, ms=size, mfc="k", mec="white", zorder=7)
        for text, where in _stop_labels(stop, up, down, scene.near) if letters else []:
            ax.annotate(
                text,
                (where[0], where[1]),
                xytext=(0, 16),
                textcoords="offset points",
                ha="center",
                fontsize=9,
                fontweight="bold",
                bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": "k", "lw": 0.6},
                zorder=8,
            )
        if up is not None and down is not None and not stop.tails:
            ax.plot([up[0], down[0]], [up[1], down[1]], ":", color=RED, lw=1.2, zorder=6)
    if scene.guide.stops:
        handles += [
            Line2D(
                [],
                [],
                ls="none",
                marker="^",
                ms=size,
                mfc="k",
                mec="white",
                label="string comes up out of the top face",
            ),
            Line2D(
                [],
                [],
                ls="none",
                marker="v",
                ms=size,
                mfc="k",
                mec="white",
                label="string goes back down into the top face",
            ),
        ]
    if any(not s.tails and s.in_step is not None for s in scene.guide.stops):
        handles.append(
            Line2D([], [], ls=":", color=RED, lw=1.2, label="loop standing above the tiles")
        )
    return handles


def _threading_picture(scene: _Scene, part: NDArray[np.int64]) -> Any:
    """``assembly-threading.png``: the route in threading order, its steps numbered."""
    fig, ax = _base(scene, "Threading order: follow the numbers from 1")
    if len(scene.steps):
        entry, exit_, handles = _draw_threading(ax, scene, part)
        _legend(ax, handles)
        fig.tight_layout()
        _place_step_labels(
            fig, ax, entry, exit_, scene.guide, scene.stop_points, scene.near,
            max(4.0, scene.font - 1),
        )  # fmt: skip
    else:
        fig.tight_layout()
    return fig


def _draw_threading(
    ax: Any, scene: _Scene, part: NDArray[np.int64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], list[Any]]:
    """The string through the tiles and the arrows from step to step (dashed from one part to
    another), and the lift points; each step's entry and exit point, and the legend entries."""
    guide = scene.guide
    rows = scene.steps[guide.order]
    entry, exit_, _ = route_openings(scene.tiles_flat, rows)
    ax.add_collection(
        LineCollection(
            [np.array([a[:2], b[:2]]) for a, b in zip(entry, exit_, strict=True)],
            colors=RED,
            lw=1.2,
            zorder=4,
        )
    )
    out_of = {s.out_step: s for s in guide.stops if s.out_step is not None}
    between = False
    for index in range(len(rows) - 1 if len(rows) > 1 else 0):
        if index in out_of:
            continue
        a, b = exit_[index, :2], entry[index + 1, :2]
        apart = part[rows[index, 1]] != part[rows[index + 1, 1]]
        between |= bool(apart)
        ax.annotate(
            "",
            b,
            a,
            arrowprops={
                "arrowstyle": "->",
                "color": RED,
                "lw": 0.8,
                "linestyle": "--" if apart else "-",
            },
            zorder=4,
        )
    handles: list[Any] = [Line2D([], [], color=RED, lw=1.2, label="string, numbered in order")]
    if between:
        handles.append(
            Line2D([], [], color=RED, lw=0.8, ls="--", label="string from one part to another")
        )
    handles += _draw_stops(ax, scene, 7.0, letters=False)
    return entry, exit_, handles


def _pull_picture(scene: _Scene, tiles_assembled: NDArray[np.float64]) -> Any:
    """``assembly-pull.png``: where to hold and lift, on the flat layout, and the arrows on the
    shape it closes into."""
    guide = scene.guide
    fig = pictures.plt.figure(figsize=(11, 6.2))
    flat_ax = fig.add_subplot(1, 2, 1)
    ends = [s.letter for s in guide.stops if s.tails]
    loops = [s.letter for s in guide.stops if not s.tails]
    what = [f"Hold the string ends at {ends[0]}"] if ends else ["Hold the string ends"]
    if loops:
        what.append(f"lift the loop{'s' if len(loops) > 1 else ''} at {' and '.join(loops)}")
    fig.suptitle(f"{', '.join(what)}: pull straight up until the shape closes", fontsize=12)
    _base(scene, "where: the flat layout seen from above", flat_ax)
    if len(scene.steps):
        rows = scene.steps[guide.order]
        entry, exit_, _ = route_openings(scene.tiles_flat, rows)
        path = np.stack([entry, exit_], axis=1).reshape(-1, 3)[:, :2]
        flat_ax.plot(path[:, 0], path[:, 1], "-", color=RED, lw=0.8, alpha=0.6)
    _legend(flat_ax, _draw_stops(flat_ax, scene, 8.0), 2)
    _draw_lift_arrows(fig.add_subplot(1, 2, 2, projection="3d"), scene, tiles_assembled)
    fig.subplots_adjust(left=0.07, right=0.98, bottom=0.2, top=0.88, wspace=0.12)
    return fig


def _draw_lift_arrows(ax3: Any, scene: _Scene, tiles_assembled: NDArray[np.float64]) -> None:
    """The assembled tiles on a 3D axes, an arrow up from each lift point."""
    guide = scene.guide
    # drawn in call order, so the arrows stay in front of the tiles wherever they stand
    # (matplotlib's depth sort can put a lift point behind a tile in front of it)
    ax3.computed_zorder = False
    ax3.add_collection3d(
        Poly3DCollection(
            list(tiles_assembled[:, :4]), facecolors="#f3d3a0", edgecolors="#444", zorder=1
        )
    )
    lows, highs = (
        tiles_assembled.reshape(-1, 3).min(axis=0),
        tiles_assembled.reshape(-1, 3).max(axis=0),
    )
    span = float((highs - lows).max())
    for stop in guide.stops:
        known = [
            p for p in stop_positions(tiles_assembled, scene.steps, guide, stop) if p is not None
        ]
        point = np.mean(known, axis=0)
        ax3.quiver(*point, 0, 0, 0.3 * span, color=RED, arrow_length_ratio=0.2, lw=2, zorder=5)
        ax3.text(
            *(point + [0, 0, 0.36 * span]), stop.letter, fontsize=11, fontweight="bold",
            ha="center", zorder=6,
        )  # fmt: skip
    centre = 0.5 * (lows + highs)
    ax3.set_xlim(centre[0] - 0.5 * span, centre[0] + 0.5 * span)
    ax3.set_ylim(centre[1] - 0.5 * span, centre[1] + 0.5 * span)
    ax3.set_zlim(centre[2] - 0.5 * span, centre[2] + 0.5 * span)
    ax3.set_title("the shape it closes into")


def _stop_labels(
    stop: Stop,
    up: NDArray[np.float64] | None,
    down: NDArray[np.float64] | None,
    near: float,
) -> list[tuple[str, NDArray[np.float64]]]:
    """Label texts and points of a lift point: one between its up and down markers when they
    are at most ``near`` apart (mm), else one at each."""
    role = "ends" if stop.tails else "loop"
    known = [p[:2] for p in (up, down) if p is not None]
    if up is not None and down is not None and np.hypot(*(up[:2] - down[:2])) > near:
        first, last = ("start", "end") if stop.tails else ("down", "up")
        return [(f"{stop.letter}: {last}", up[:2]), (f"{stop.letter}: {first}", down[:2])]
    return [(f"{stop.letter} ({role})", np.mean(known, axis=0))] if known else []


def _place_step_labels(
    fig: Any,
    ax: Any,
    entry: NDArray[np.float64],
    exit_: NDArray[np.float64],
    guide: Guide,
    stop_points: Sequence[StopPoints],
    near: float,
    font: float,
) -> None:
    """Step numbers and lift-point letters of the threading picture, none over another.

    Each label is wanted just outside its step's run (away from the middle of the layout, so
    the string stays visible) and goes to the nearest free spot around there, clear of the other
    labels and of the lift-point markers; a label that had to move gets a leader line to its
    step.  Call after the layout of the figure is final (positions are found in pixels).
    """

    fig.canvas.draw()
    to_px = ax.transData.transform
    scale = fig.dpi / 72.0
    mids = 0.5 * (entry[:, :2] + exit_[:, :2])
    centre = to_px(np.concatenate([entry[:, :2], exit_[:, :2]]).mean(axis=0))
    blocked = []  # each lift-point marker, and the loop between two close ones
    for stop, (up, down) in zip(guide.stops, stop_points, strict=True):
        marks = [p[:2] for p in (up, down) if p is not None]
        if len(marks) == 2 and not stop.tails and np.hypot(*(marks[0] - marks[1])) <= near:
            marks += [marks[0] + t * (marks[1] - marks[0]) for t in (0.25, 0.5, 0.75)]
        for mark in to_px(np.array(marks).reshape(-1, 2)):
            blocked.append(np.concatenate([mark - 6 * scale, mark + 6 * scale]))
    texts, points, sizes, styles = [], [], [], []
    for stop, (up, down) in zip(guide.stops, stop_points, strict=True):
        for text, where in _stop_labels(stop, up, down, near):
            texts.append(text)
            points.append(where[:2])
            sizes.append([0.62 * 9 * len(text) * scale + 8, 1.2 * 9 * scale + 6])
            styles.append(True)
    for g, mid in enumerate(mids):
        texts.append(str(g + 1))
        points.append(mid)
        sizes.append([0.62 * font * len(texts[-1]) * scale + 3, 1.15 * font * scale + 2])
        styles.append(False)
    anchors = to_px(np.array(points).reshape(-1, 2))
    size = np.array(sizes).reshape(-1, 2)
    away = anchors - centre
    away /= np.maximum(np.hypot(away[:, 0], away[:, 1]), 1e-9)[:, None]
    wanted = anchors + away * (0.5 * size.max(axis=1) + 3 * scale)[:, None]
    placed = pictures.place_labels(
        wanted,
        size,
        step=0.5 * size[:, 1].min(),
        rings=8,
        blocked=np.array(blocked).reshape(-1, 4),
        bounds=ax.bbox.extents,
    )
    spots = ax.transData.inverted().transform(placed)
    for text, point, spot, big, want, got in zip(
        texts, points, spots, styles, wanted, placed, strict=True
    ):
        moved = bool(np.hypot(*(got - want)) > 1.0)
        ax.annotate(
            text,
            (point[0], point[1]),
            xytext=(spot[0], spot[1]),
            textcoords="data",
            fontsize=9 if big else font,
            fontweight="bold" if big else "normal",
            color="k" if big else "#7a0010",
            ha="center",
            va="center",
            bbox=(
                {"boxstyle": "round,pad=0.2", "fc": "white", "ec": "k", "lw": 0.6}
                if big
                else {"boxstyle": "round,pad=0.1", "fc": "white", "ec": "none", "alpha": 0.85}
            ),
            arrowprops={"arrowstyle": "-", "color": "0.3", "lw": 0.5} if moved or big else None,
            zorder=9,
        )


def _components(n_tiles: int, hinges: NDArray[np.int64]) -> NDArray[np.int64]:
    """(T,) int, the part (hinge-connected component) of each tile."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    edges = np.asarray(hinges, dtype=np.int64).reshape(-1, 4)[:, [0, 2]]
    graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), (n_tiles, n_tiles))
    return np.asarray(connected_components(graph, directed=False)[1], dtype=np.int64)
