"""The assembly guide under ``DIR/fabrication/``: ``assembly.md`` and its pictures
(``assembly-tiles.png``, ``assembly-threading.png``, ``assembly-pull.png``).

The threading starts at a lift point, so that the string's two ends stand up there; every lift
point is named in the steps where the string comes up out of a top face and goes back down.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from drawstring.cad.paths import SIDE_TOP_FACE, lift_path, route_openings
from drawstring.fabrication.profiles import Process, Profile, print_clearance_mm, string_is_cable
from drawstring.fabrication.record import ExportRecord, GuideInputs
from drawstring.geometry.tiling.linkage import id_runs
from drawstring.output import pictures

if TYPE_CHECKING:  # panels load the CAD kernel, which a --no-cad report never needs
    from drawstring.fabrication.panels import Panel

#: Top of the legends under the flat-layout pictures, in axes heights below the axes: clear of
#: the x-axis label (at -0.09 the legend covered it).
LEGEND_BELOW = -0.15


def _beds_text(stem: str, jobs: Sequence[dict[str, Any]]) -> str:
    """How the print jobs share the beds, and which file prints each bed."""
    beds = max((int(job.get("bed", 1)) for job in jobs), default=1)
    if beds <= 1:
        return " Print them together: they share one bed." if len(jobs) > 1 else ""
    return (
        f" The jobs fill {beds} beds, side by side in that file (the first on the plate); "
        f"`{stem}-bed1.3mf` to `{stem}-bed{beds}.3mf` hold one bed each, on the plate: "
        "print them one after the other."
    )


def _on_bed(job: dict[str, Any], jobs: Sequence[dict[str, Any]]) -> str:
    """`` (bed 2)`` where the jobs fill more than one bed."""
    several = len({int(j.get("bed", 1)) for j in jobs}) > 1
    return f" (bed {job['bed']})" if several and "bed" in job else ""


def _unnumbered_text(unlabelled: Sequence[int]) -> str:
    """The guide's word on tiles too small for an engraved number (empty when there are
    none)."""
    if not unlabelled:
        return ""
    which = id_runs(unlabelled)
    return (
        f" {_count(len(unlabelled), 'tile')} too small for the digits carry no number "
        f"(tile{'s' if len(unlabelled) > 1 else ''} {which}): mark them by hand as they come "
        "off the bed, matching each outline to the placement template or the tile picture "
        "below; a larger --size makes room for the numbers."
    )


def _trimmed_text(trimmed: Sequence[int]) -> str:
    """The plywood guide's word on tiles whose overlap with a neighbour must be cut away (the
    panels make whole boxes; empty when there are none)."""
    if not trimmed:
        return ""
    return (
        f" {_count(len(trimmed), 'tile')} overlap a hinged neighbour in the flat pose "
        f"(tile{'s' if len(trimmed) > 1 else ''} {id_runs(trimmed)}; `hinges.json` trims): "
        "the panels make whole boxes, so once each is glued, saw or sand its overlap off as "
        "`flat.step` shows that tile, or the flat sheet will not lie flat."
    )


def _count(number: int, noun: str) -> str:
    """``1 sheet``, ``3 sheets``."""
    return f"{number} {noun}" if number == 1 else f"{number} {noun}s"


# --------------------------------------------------------------------------------------------
# pictures


def _figure_png(fig: Any, path: Path) -> None:
    # "tight": the legends below the axes are kept whole, however many rows they take
    fig.savefig(path, dpi=110, metadata={"Software": None}, bbox_inches="tight", pad_inches=0.15)


@dataclass(frozen=True)
class _Stop:
    """A lift point of the assembly guide: the string comes up out of a top face and goes back
    down into the next tile's top face.

    Step indices count guide steps (threading order).  ``out_step`` leaves its tile through the
    top face (up the lift bore from side ``out_side``, or ``SIDE_TOP_FACE`` straight), and
    ``in_step`` comes back down into its tile (the bore to side ``in_side``); either is None
    when the route has no such step.  At the ``tails`` stop the string's two ends stand up.
    """

    letter: str
    out_step: int | None
    out_side: int
    in_step: int | None
    in_side: int
    tails: bool


@dataclass(frozen=True)
class _Guide:
    """The threading order of the assembly guide.

    ``order[g]`` is the route step (``route.json`` index) threaded as guide step ``g + 1``; the
    closed route is started at a lift point, so that both string ends stand up there.
    ``spare`` lists lift bores ``(tile, side)`` the string does not pass.
    """

    order: list[int]
    stops: list[_Stop]
    spare: list[tuple[int, int]]


def _guide(steps: NDArray[np.int64], lifts: NDArray[np.int64]) -> _Guide:
    """Where the string leaves the top faces, and the threading order starting at one of them.

    A route step may leave or enter through the top face itself (``SIDE_TOP_FACE``), or a lift
    bore ``(tile, side)`` joins the side the step leaves by (entering by, for the next step) to
    the top face: the string goes up out of one tile and back down into the next.
    """
    count = len(steps)
    bores = {(int(t), int(s)) for t, s in lifts}
    used: set[tuple[int, int]] = set()
    raw: list[tuple[int | None, int, int | None, int]] = []
    back_in: set[int] = set()
    for i in range(count):
        j = (i + 1) % count
        _, tile, enter, leave = (int(v) for v in steps[i])
        _, after, after_enter, after_leave = (int(v) for v in steps[j])
        if leave == SIDE_TOP_FACE:
            out_side = SIDE_TOP_FACE
        elif (tile, leave) in bores and count > 1:
            out_side = leave
            used.add((tile, leave))
        else:
            continue
        in_step: int | None = None
        in_side = -1
        if after_enter == SIDE_TOP_FACE:
            in_step, in_side = j, SIDE_TOP_FACE
        elif (after, after_enter) in bores:
            in_step, in_side = j, after_enter
            used.add((after, after_enter))
        if in_step is not None:
            back_in.add(in_step)
        raw.append((i, out_side, in_step, in_side))
    for j in range(count):
        if int(steps[j, 2]) == SIDE_TOP_FACE and j not in back_in:
            raw.append((None, -1, j, SIDE_TOP_FACE))
    starts = sorted(s for _, _, s, _ in raw if s is not None)
    first = 0 if not starts or 0 in starts else starts[0]
    order = [(first + g) % count for g in range(count)]

    def guide_step(index: int | None) -> int | None:
        return None if index is None else (index - first) % count

    moved = [(guide_step(o), out_side, guide_step(s), in_side) for o, out_side, s, in_side in raw]
    moved.sort(key=lambda m: (m[2] != 0, m[0] if m[0] is not None else -1))
    stops = [
        _Stop(_stop_label(k), o, out_side, s, in_side, tails=s == 0)
        for k, (o, out_side, s, in_side) in enumerate(moved)
    ]
    spare = sorted(bores - used)
    return _Guide(order, stops, spare)


def _stop_label(index: int) -> str:
    """A, B, ..., Z, AA, AB, ...: the name of stop ``index`` (from 0)."""
    label = ""
    index += 1
    while index:
        index, rest = divmod(index - 1, 26)
        label = chr(ord("A") + rest) + label
    return label


def _stop_points(
    tiles: NDArray[np.float64], steps: NDArray[np.int64], guide: _Guide, stop: _Stop
) -> tuple[NDArray[np.float64] | None, NDArray[np.float64] | None]:
    """(3,) float, mm: where the string comes up at ``stop`` and where it goes back down."""
    points: list[NDArray[np.float64] | None] = []
    for index, side, column in ((stop.out_step, stop.out_side, 2), (stop.in_step, stop.in_side, 3)):
        if index is None:
            points.append(None)
            continue
        row = steps[guide.order[index]]
        bore = int(row[column]) if side == SIDE_TOP_FACE else side
        points.append(lift_path(tiles[int(row[1])], bore).arc[2])
    return points[0], points[1]


def _components(n_tiles: int, hinges: NDArray[np.int64]) -> NDArray[np.int64]:
    """(T,) int, the part (hinge-connected component) of each tile."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    edges = np.asarray(hinges, dtype=np.int64).reshape(-1, 4)[:, [0, 2]]
    graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), (n_tiles, n_tiles))
    return np.asarray(connected_components(graph, directed=False)[1], dtype=np.int64)


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
    and lift-point letters are those of :func:`_write_assembly` (:func:`_guide`).
    """
    from matplotlib.collections import LineCollection, PolyCollection
    from matplotlib.lines import Line2D

    plt = pictures.plt
    names = []
    top = tiles_flat[:, :4, :2]
    centres = top.mean(axis=1)
    font = max(4.0, min(10.0, 300.0 / math.sqrt(len(tiles_flat))))
    guide = _guide(steps, lifts)
    part = _components(len(tiles_flat), hinges)
    red = pictures.STRING_COLOUR

    def base(title: str, ax: Any = None) -> tuple[Any, Any]:
        fig = None
        if ax is None:
            fig, ax = plt.subplots(figsize=(7, 7.6))
        ax.add_collection(
            PolyCollection(list(top), facecolors="#f7e4c2", edgecolors="#444", lw=0.6)
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

    def legend(ax: Any, handles: list[Any], columns: int = 2) -> None:
        ax.legend(
            handles=handles,
            loc="upper center",
            bbox_to_anchor=(0.5, LEGEND_BELOW),
            ncol=columns,
            fontsize=7,
            frameon=False,
        )

    fig, ax = base("Where each tile goes (flat layout, seen from above)")
    for tile, (x, y) in enumerate(centres):
        ax.text(x, y, str(tile), ha="center", va="center", fontsize=font)
    points = np.array(
        [
            0.5
            * (
                tiles_flat[a, (0 if s == "top" else 4) + ca, :2]
                + tiles_flat[b, (0 if s == "top" else 4) + cb, :2]
            )
            for (a, ca, b, cb), s in zip(hinges, hinge_side, strict=True)
        ]
    ).reshape(-1, 2)
    pictures.draw_hinges(ax, points, np.array([s != "top" for s in hinge_side], dtype=bool))
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
    _figure_png(fig, out / "assembly-tiles.png")
    plt.close(fig)
    names.append("assembly-tiles.png")

    stop_points = [_stop_points(tiles_flat, steps, guide, stop) for stop in guide.stops]
    edges = np.linalg.norm(top - np.roll(top, -1, axis=1), axis=2)
    near = 2.5 * float(np.median(edges)) if edges.size else 0.0  # one label for both markers

    def draw_stops(ax: Any, size: float, letters: bool = True) -> list[Any]:
        """Up/down markers and letters of the lift points; the legend entries they need."""
        handles = []
        for stop, (up, down) in zip(guide.stops, stop_points, strict=True):
            for point, marker in ((up, "^"), (down, "v")):
                if point is not None:
                    ax.plot(point[0], point[1], marker, ms=size, mfc="k", mec="white", zorder=7)
            for text, where in _stop_labels(stop, up, down, near) if letters else []:
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
                ax.plot([up[0], down[0]], [up[1], down[1]], ":", color=red, lw=1.2, zorder=6)
        if guide.stops:
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
        if any(not s.tails and s.in_step is not None for s in guide.stops):
            handles.append(
                Line2D([], [], ls=":", color=red, lw=1.2, label="loop standing above the tiles")
            )
        return handles

    fig, ax = base("Threading order: follow the numbers from 1")
    if len(steps):
        rows = steps[guide.order]
        entry, exit_, _ = route_openings(tiles_flat, rows)
        ax.add_collection(
            LineCollection(
                [np.array([a[:2], b[:2]]) for a, b in zip(entry, exit_, strict=True)],
                colors=red,
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
                    "color": red,
                    "lw": 0.8,
                    "linestyle": "--" if apart else "-",
                },
                zorder=4,
            )
        handles: list[Any] = [Line2D([], [], color=red, lw=1.2, label="string, numbered in order")]
        if between:
            handles.append(
                Line2D([], [], color=red, lw=0.8, ls="--", label="string from one part to another")
            )
        handles += draw_stops(ax, 7.0, letters=False)
        legend(ax, handles)
        fig.tight_layout()
        _place_step_labels(fig, ax, entry, exit_, guide, stop_points, near, max(4.0, font - 1))
    else:
        fig.tight_layout()
    _figure_png(fig, out / "assembly-threading.png")
    plt.close(fig)
    names.append("assembly-threading.png")

    fig = plt.figure(figsize=(11, 6.2))
    flat_ax = fig.add_subplot(1, 2, 1)
    ends = [s.letter for s in guide.stops if s.tails]
    loops = [s.letter for s in guide.stops if not s.tails]
    what = [f"Hold the string ends at {ends[0]}"] if ends else ["Hold the string ends"]
    if loops:
        what.append(f"lift the loop{'s' if len(loops) > 1 else ''} at {' and '.join(loops)}")
    fig.suptitle(f"{', '.join(what)}: pull straight up until the shape closes", fontsize=12)
    base("where: the flat layout seen from above", flat_ax)
    if len(steps):
        rows = steps[guide.order]
        entry, exit_, _ = route_openings(tiles_flat, rows)
        path = np.stack([entry, exit_], axis=1).reshape(-1, 3)[:, :2]
        flat_ax.plot(path[:, 0], path[:, 1], "-", color=red, lw=0.8, alpha=0.6)
    legend(flat_ax, draw_stops(flat_ax, 8.0), 2)
    ax3 = fig.add_subplot(1, 2, 2, projection="3d")
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    # drawn in call order, so the arrows stay in front of the tiles wherever they stand
    # (matplotlib's depth sort hid a lift point behind the chair's back)
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
        known = [p for p in _stop_points(tiles_assembled, steps, guide, stop) if p is not None]
        point = np.mean(known, axis=0)
        ax3.quiver(*point, 0, 0, 0.3 * span, color=red, arrow_length_ratio=0.2, lw=2, zorder=5)
        ax3.text(
            *(point + [0, 0, 0.36 * span]), stop.letter, fontsize=11, fontweight="bold",
            ha="center", zorder=6,
        )  # fmt: skip
    centre = 0.5 * (lows + highs)
    ax3.set_xlim(centre[0] - 0.5 * span, centre[0] + 0.5 * span)
    ax3.set_ylim(centre[1] - 0.5 * span, centre[1] + 0.5 * span)
    ax3.set_zlim(centre[2] - 0.5 * span, centre[2] + 0.5 * span)
    ax3.set_title("the shape it closes into")
    fig.subplots_adjust(left=0.07, right=0.98, bottom=0.2, top=0.88, wspace=0.12)
    _figure_png(fig, out / "assembly-pull.png")
    plt.close(fig)
    names.append("assembly-pull.png")
    return names


def _stop_labels(
    stop: _Stop,
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
    guide: _Guide,
    stop_points: Sequence[tuple[NDArray[np.float64] | None, NDArray[np.float64] | None]],
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


def _write_assembly(
    path: Path,
    profile: Profile,
    design_name: str,
    record: ExportRecord,
    hinges: NDArray[np.int64],
    sides: Sequence[str],
    steps: NDArray[np.int64],
    lifts: NDArray[np.int64],
    magnets: Sequence[Any],
    panels: Sequence[Panel],
    pictures: Sequence[str],
) -> None:
    """``assembly.md``: make the parts, place the tiles, magnets, thread the string, pull.

    Sections are numbered as they are written.  Every lift point (the string up out of a top
    face and back down into the next tile's) is named in the two steps where it happens; the
    threading starts at one of them, so that the string's two ends stand up there.
    """
    est = record.estimates
    section = itertools.count(1)
    # each end to hold while pulling (bom.csv's string rule)
    tail = float(est["string_tail_mm"])
    lines = [
        f"# Assembling {design_name} ({profile.name})",
        "",
        f"Parts: see `bom.csv`. String: **{est['string_length_mm'] / 1000:.2f} m** of "
        f"{profile.string_material} ({est['string_rule']}).",
        "",
    ]
    if profile.process == Process.FDM_DUAL:
        lines += [f"## {next(section)}. Print", ""]
        lines.append(
            f"`print.3mf` holds {len(record.jobs)} object(s), one per print job. Tiles are "
            f"assigned to extruder 1 ({profile.tile_material}), hinge pads to extruder 2 "
            f"({profile.hinge_material}); PrusaSlicer, Bambu Studio and OrcaSlicer read the "
            "assignment from the file. Each job lies top faces down (the tops share one plane, "
            "the bottoms follow each tile's thickness), so every tile starts on the first "
            "layer; turn the printed sheet over before you thread it. Each tile's number is "
            "engraved in its bottom face (it reads as printed, and from below once turned). "
            f"Hinged tiles print {print_clearance_mm(profile):g} mm apart, joined only by "
            "their pads (each tile is cut back that little along its hinge edges): before "
            "you thread the sheet, bend every hinge once, and cut any stray strand of "
            f"{profile.tile_material} across one."
            + _unnumbered_text(record.unlabelled)
            + _beds_text("print", record.jobs)
        )
        lines.append("")
        for job in record.jobs:
            kind = (
                "loose hinge pads"
                if job.get("loose")
                else f"{len(job['tiles'])} tiles ({id_runs(job['tiles'])})"
            )
            lines.append(
                f"- job {job['job']}: {kind}, {len(job['pads'])} pads{_on_bed(job, record.jobs)}"
            )
        cut = est.get("cut_hinges", [])
        if cut:
            lines += [
                "",
                "The layout is larger than the bed, so it was split along rows of hinges. "
                "Join the jobs with the loose hinge pads (their jobs lay them out in rows, "
                "left to right, then row after row, in the order of this list; "
                "`assembly-tiles.png` rings these hinges in red): press each pad's pins "
                "into the holes of both tiles and glue it into the recess (CA glue):",
                "",
            ]
            for h in cut:
                a, _, b, _ = hinges[h]
                lines.append(f"- hinge {h}: tile {a} to tile {b} ({sides[h]} faces)")
        lines.append("")
    else:
        lines += [f"## {next(section)}. Make the parts", ""]
        if profile.process == Process.LASER_EPDM:
            beds = len(record.jobs)
            text = (
                "Print the tiles from `tiles.3mf` (single material). They print loose, top "
                "faces down (tiles differ in thickness by a little, their top faces are "
                "flat), each turned about the vertical to take the least room, nested on "
                f"{_count(beds, 'bed')} of {profile.bed_x_mm:g} x {profile.bed_y_mm:g} mm"
            )
            if beds > 1:
                text += (
                    ", one object per bed, side by side in that file (the first on the plate); "
                    f"`tiles-bed1.3mf` to `tiles-bed{beds}.3mf` hold one bed each, on the plate"
                )
            lines.append(
                text + ". Each tile's number is engraved in its bottom face; the placement "
                "template (below) shows where it goes." + _unnumbered_text(record.unlabelled)
            )
            if beds > 1:
                lines.append("")
                lines += [
                    f"- bed {job['bed']}: tiles {id_runs(job['tiles'])}" for job in record.jobs
                ]
            lines.append("")  # the list ends before the next paragraph
        else:
            panel_sheets = _count(record.sheets["panels"]["sheets"], "sheet")
            lines.append(
                f"Cut the panels from `panels.dxf` ({panel_sheets}) "
                "with "
                "the inner face up: engraved labels (tile number + face: S0..S3 sides, T top, "
                "B bottom) end up inside the box. Glue each tile's six panels together; "
                "`cutlist.csv` gives each edge's dihedral and bevel angle (sand or bevel proud "
                "edges flush). Glue a channel tube through each pair of cable holes (each "
                "tube's tile, route step or lift bore and length in `manifest.json` "
                "channel_tubes). Layers: ENGRAVE green first, CUT_INNER blue (holes, the "
                "magnet holes in the side panels among them), CUT_OUTER black; DRILL magenta: "
                "drill these at the diameter drawn (the pilot holes of the hinge strips' "
                f"screws, and round holes narrower than the {profile.tool_diameter_mm:g} mm "
                "tool)." + _trimmed_text(record.trimmed)
            )
        strip_sheets = _count(record.sheets["hinges"]["sheets"], "sheet")
        lines.append(
            f"Cut the hinge strips from `hinges.dxf` ({strip_sheets}; "
            "layers: ENGRAVE green first, CUT_INNER blue, CUT_OUTER black; SHEET red holds only "
            "each sheet's outline and its name below it, not to be cut). Each half of a strip "
            "is engraved with the number of the tile it joins."
        )
        lines.append("")
        width, height = est.get("placement_size_mm", (0.0, 0.0))
        # the numbers are engraved in the bottom faces (laser) or inside the boxes (plywood)
        on_top = (
            "by number (read each tile's number in its bottom face before you lay it down)"
            if profile.process == Process.LASER_EPDM
            else "matching their outlines (the engraved numbers are inside the boxes: pencil "
            "each box's number on its bottom as you glue it)"
        )
        text = (
            f"Print `placement.svg` at 100 % (1:1; it is {width:g} x {height:g} mm: on a large-"
            "format printer, or tiled over several sheets taped together), lay the tiles on it "
            f"top faces up {on_top}, and fix each strip where the template shows it (blue, "
            "marked with a circle: on the top faces; orange, marked with a square: on the "
            "bottom faces)."
        )
        if any(side != "top" for side in sides):
            # laser tiles carry their numbers in their bottom faces; plywood boxes inside
            by_number = (
                "by the numbers in their bottom faces"
                if profile.process == Process.LASER_EPDM
                else "by the numbers pencilled on their bottoms"
            )
            text += (
                " The bottom faces' strips go on first, from below: print "
                "`placement-bottom.svg` too (the layout seen from below, mirrored, with only "
                f"those strips), lay the tiles on it top faces down, {by_number}, and fix the "
                "orange strips; then turn the pieces over onto `placement.svg`, top faces up, "
                "and fix the blue ones."
            )
        lines.append(text)
        lines.append("")
    lines += [
        f"## {next(section)}. Where each tile goes",
        "",
        f"![tiles]({pictures[0]})",
        "",
        "Blue circles: hinges on the top faces; orange squares: hinges on the bottom faces.",
        "",
    ]
    if magnets:
        lines += [
            f"## {next(section)}. Magnets",
            "",
            (
                "Press the magnets into their holes in the side panels, flush with the outer "
                "face, and glue them from inside, with these poles facing out:"
                if profile.process == Process.PLYWOOD_CNC
                else "Glue the magnets into their pockets with these poles facing out:"
            ),
            "",
        ]
        for m in magnets:
            lines.append(
                f"- tile {m.tile_a} side {m.side_a}: {m.polarity_a} out; "
                f"tile {m.tile_b} side {m.side_b}: {m.polarity_b} out"
            )
        lines.append("")
    lines += _threading_text(next(section), steps, lifts, pictures[1], tail)
    lines += _pull_text(next(section), steps, lifts, pictures[2], string_is_cable(profile))
    if record.notes:
        lines += ["## Notes", ""] + [f"- {n}" for n in record.notes] + [""]
    del panels
    path.write_text("\n".join(lines), encoding="utf-8")


def _threading_text(
    number: int, steps: NDArray[np.int64], lifts: NDArray[np.int64], picture: str, tail: float
) -> list[str]:
    """The threading section of assembly.md, one line per step (see :func:`_guide`)."""
    guide = _guide(steps, lifts)
    lines = [
        f"## {number}. Thread the string",
        "",
        f"![threading]({picture})",
        "",
        "Follow the route step by step: tile, the side the string goes in by, the side it "
        "comes out by. Sides are numbered as the tiles lie in the pictures: 0 bottom, "
        "1 right, 2 top, 3 left; the *top face* is the face that is up on the table. "
        "Through a side the string runs in the tile's channel; through the top face it runs "
        "in a lift bore, which meets the channel at a side's hole.",
        "",
    ]
    if not len(steps):
        return lines + ["The design has no string route.", ""]
    first = guide.order[0]
    if guide.stops:
        lines.append(
            f"The string comes up out of the top faces at {len(guide.stops)} lift "
            f"point{'s' if len(guide.stops) != 1 else ''}, marked ▲ (up) and ▼ (back down) "
            "in the picture:"
        )
        lines.append("")
        for stop in guide.stops:
            out = (
                f"up out of tile {steps[guide.order[stop.out_step], 1]} in step {stop.out_step + 1}"
                if stop.out_step is not None
                else None
            )
            back = (
                f"down into tile {steps[guide.order[stop.in_step], 1]} in step {stop.in_step + 1}"
                if stop.in_step is not None
                else None
            )
            what = "the two string ends" if stop.tails else "a loop to pull"
            lines.append(f"- **{stop.letter}** ({what}): " + ", ".join(w for w in (out, back) if w))
        lines.append("")
    if first:
        lines += [
            f"The route is a closed loop; step 1 here is step {first + 1} of `route.json` "
            f"(the steps are counted from lift point {guide.stops[0].letter}, so that both "
            "string ends stand up there).",
            "",
        ]
    out_of = {s.out_step: s for s in guide.stops if s.out_step is not None}
    into = {s.in_step: s for s in guide.stops if s.in_step is not None}
    for g, index in enumerate(guide.order):
        _, tile, enter, leave = (int(v) for v in steps[index])
        stop_in, stop_out = into.get(g), out_of.get(g)
        start = ""
        if stop_in is None:
            came = f"in {enter}"
            if g == 0:
                start = f"start here, with a tail of {tail:.0f} mm left outside side {enter}; "
        else:
            came = f"**in through the top face ▼ at lift point {stop_in.letter}**"
            if enter != SIDE_TOP_FACE:
                came += (
                    f": down the lift bore to the hole in side {enter}, and on into the channel "
                    f"from side {enter}"
                )
            if g == 0:
                start = f"start here, with a tail of {tail:.0f} mm left standing up; "
        if stop_out is None:
            went = f"out {leave}"
        elif leave == SIDE_TOP_FACE:
            went = f"**out through the top face ▲ at lift point {stop_out.letter}**"
        else:
            went = (
                f"out {leave}, then back into that hole and up its lift bore: **out through "
                f"the top face ▲ at lift point {stop_out.letter}**"
            )
        if stop_out is not None:
            if stop_out.tails:
                went += f" (the other end: leave a tail of {tail:.0f} mm standing up)"
            elif stop_out.in_step is not None:
                went += " (leave a loop a hand wide standing up, to pull on)"
        lines.append(f"{g + 1}. tile {tile}: {start}{came}, {went}")
    if not any(s.tails for s in guide.stops):
        lines.append("")
        lines.append(
            f"After the last step the string is back at side {int(steps[first, 2])} of tile "
            f"{int(steps[first, 1])}, next to the first tail: leave a tail of {tail:.0f} mm."
        )
    if guide.spare:
        spare = "; ".join(f"tile {t} side {s}" for t, s in guide.spare)
        lines += ["", f"Lift bores the string does not pass (leave them empty): {spare}."]
    lines.append("")
    return lines


def _pull_text(
    number: int,
    steps: NDArray[np.int64],
    lifts: NDArray[np.int64],
    picture: str,
    cable: bool = False,
) -> list[str]:
    """The pull section of assembly.md: what to hold and lift, where, and how to finish
    (``cable``: a wire cable, crimped rather than knotted)."""
    join = (
        "join the two ends with the crimp ferrule (or two wire-rope clips), pulled tight,"
        if cable
        else "knot the two ends together"
    )
    guide = _guide(steps, lifts)
    lines = [f"## {number}. Pull", "", f"![pull]({picture})", ""]
    ends = [s for s in guide.stops if s.tails]
    loops = [s for s in guide.stops if not s.tails]

    def tiles_of(stop: _Stop) -> str:
        found = [
            int(steps[guide.order[g], 1]) for g in (stop.out_step, stop.in_step) if g is not None
        ]
        if len(found) == 2 and found[0] != found[1]:
            return f"tiles {found[0]} and {found[1]}"
        return f"tile {found[0]}" if found else "the top faces"

    if ends:
        held = f"the two string ends at lift point {ends[0].letter} ({tiles_of(ends[0])})"
        finish = f"{join} on top of {tiles_of(ends[0])}"
    elif len(steps):
        tile = int(steps[guide.order[0], 1])
        held = f"the two string ends at tile {tile}"
        finish = f"{join} at tile {tile}"
    else:
        held, finish = "the string", "tie it off"
    grip = "Hold " + held
    if loops:
        names = " and ".join(s.letter for s in loops)
        grip += " in one hand and hook a finger of the other through the " + (
            f"loop at {names}" if len(loops) == 1 else f"loops at {names}"
        )
    lines.append(
        "Lay the flat linkage on a table, top faces up. "
        + grip
        + ". Lift them straight up together, slowly and evenly, as the arrows show: the "
        "string draws the tiles together, they rotate about the hinges and close into the "
        "shape. When every gap has closed, pull the ends until "
        + (
            f"the loop{'s lie' if len(loops) > 1 else ' lies'} tight on the top faces, and "
            if loops
            else "the string is tight, and "
        )
        + finish
        + "."
    )
    lines.append("")
    return lines


def write_guide(out: Path, inputs: GuideInputs) -> list[str]:
    """The assembly guide of a fabrication folder: its pictures and ``assembly.md``."""
    pictures = write_pictures(
        out, inputs.tiles_flat, inputs.tiles_assembled, inputs.hinges, inputs.sides,
        inputs.steps, inputs.lifts,
        cut_hinges=[int(h) for h in inputs.record.estimates.get("cut_hinges", [])],
    )  # fmt: skip
    _write_assembly(
        out / "assembly.md",
        inputs.profile,
        inputs.design_name,
        inputs.record,
        inputs.hinges,
        inputs.sides,
        inputs.steps,
        inputs.lifts,
        inputs.magnets,
        inputs.panels,
        pictures,
    )
    return [*pictures, "assembly.md"]
