"""The design record and what every stage shares: options, progress, the writer protocol.

This module is the leaf of the pipeline package: the stages (:mod:`.layout_stage`,
:mod:`.measure`, :mod:`.cad_stage`, ...), the output folder and the command line import their
shared types from here, and it imports nothing of theirs.
"""

from __future__ import annotations

import logging
import math
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from numpy.typing import NDArray

from drawstring.fabrication.printers import Printer
from drawstring.fabrication.profiles import (
    MAX_SIZE_MM,
    MAX_TILES,
    MAX_WEIGHT,
    MIN_GRID_SIDE,
    MIN_TILES,
    SCHEMA,
    Profile,
)
from drawstring.geometry.assembled.shape import AssembledResult
from drawstring.geometry.core.errors import InputError
from drawstring.geometry.core.tile import HingeStrategy
from drawstring.geometry.core.tolerances import (
    FLAT_EDGE_ERROR_TOL_MM,
    HINGE_GAP_TOL_MM,
    MAX_SCALE_FACTOR,
)
from drawstring.geometry.flat.layout import FlatResult
from drawstring.geometry.flatten.conformal import Flattening
from drawstring.geometry.hinges.placement import HingeLayout
from drawstring.geometry.route.lift import LiftPoints
from drawstring.geometry.route.result import Route
from drawstring.geometry.target.surface import Target
from drawstring.geometry.tiling.grid import Tiling

if TYPE_CHECKING:  # the solids' type: build123d is loaded only where solids are built
    from drawstring.cad.design import CadResult
    from drawstring.geometry.simulate import SimulationResult

log = logging.getLogger(__name__)


def rounded(value: float, digits: int = 6) -> float:
    """``value`` as a plain float rounded to ``digits`` decimals (design.json's numbers)."""
    return float(round(value, digits))


def above(value: float, bound: float) -> str:
    """``value`` with two significant digits, or as many more (up to six) as it takes to read
    above ``bound`` (a hinge gap of 0.001005 mm reads 0.001005, not 0.001, against a 0.001 mm
    bound)."""
    for digits in range(2, 7):
        text = f"{value:.{digits}g}"
        if float(text) > bound:
            return text
    return text


def jsonable(value: Any) -> Any:
    """Plain JSON values: numpy scalars and arrays become Python numbers and lists."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple | np.ndarray):
        return [jsonable(v) for v in value]
    if isinstance(value, np.bool_ | bool):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating | float):
        return float(value) if math.isfinite(value) else None
    return value


#: Stages in order; ``timings_s`` uses these keys.
STAGES = (
    "target", "flatten", "tiling", "assembled", "flat", "hinges", "lift", "route", "rigidity",
    "simulate",
)  # fmt: skip
HINGE_STRATEGIES: tuple[HingeStrategy, ...] = tuple(HingeStrategy)
#: ``--fit``: the closest assembled shape every layout target allows, or the paper's eq. 1
FitChoice = Literal["close", "paper"]
FIT_CHOICES: tuple[FitChoice, ...] = ("close", "paper")
#: ``--thickness`` bounds, mm: those of a profile's ``tile.thickness_mm``.
MIN_THICKNESS_MM = SCHEMA["thickness_mm"].low or 0.5
MAX_THICKNESS_MM = SCHEMA["thickness_mm"].high or 500.0
#: Smallest ``--size``, mm: a part below it cannot be made, and far below it the arithmetic
#: underflows (at 1e-300 mm a sound mesh's faces have zero area).
MIN_SIZE_MM = 1.0


@dataclass(frozen=True)
class DesignOptions:
    """Every option of ``drawstring design``; ``None`` means "take the profile's default"."""

    profile: str = "fdm-dual"
    tiles: int | None = None
    grid: tuple[int, int] | None = None
    size_mm: float | None = None
    resolution: int = 10_000
    thickness_mm: float | None = None
    min_gap_angle_deg: float | None = None
    max_scale_factor: float = MAX_SCALE_FACTOR
    corners: tuple[int, int, int, int] | None = None
    #: None: dual, and all on top instead where the dual layout misses the profile's
    #: fabrication tolerance and the top one meets it (:func:`~.run.hinges_chosen`)
    hinges: HingeStrategy | None = None
    #: eq. 1's weights; None: the paper's, which ``fit`` builds on
    weights: tuple[float, float, float] | None = None
    fit: FitChoice = "close"
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    simulate: bool = True
    cad: bool = True
    co_optimize: bool = True
    seed: int = 0
    repair: bool = False
    #: a printer preset name or .toml path (None: the profile's ``machine.printer``)
    printer: str | None = None
    #: slice each print job with PrusaSlicer (when it is installed) for the printing time and
    #: filament, instead of drawstring's estimate
    slice: bool = False

    def validate(self) -> None:
        """Refuse values out of range with a one-line :class:`InputError`."""
        if self.tiles is not None and not MIN_TILES <= self.tiles <= MAX_TILES:
            why = (
                f"the string route needs a grid of at least {MIN_GRID_SIDE} x {MIN_GRID_SIDE} tiles"
                if self.tiles < MIN_TILES
                else "designs that large are not supported (1600 tiles already take minutes)"
            )
            raise InputError(
                f"--tiles must be between {MIN_TILES} and {MAX_TILES} (got {self.tiles}); {why}"
            )
        if self.grid is not None and (
            len(self.grid) != 2
            or min(self.grid) < MIN_GRID_SIDE
            or self.grid[0] * self.grid[1] > MAX_TILES
        ):
            shown = " ".join(str(n) for n in self.grid)
            raise InputError(
                f"--grid I J needs two whole numbers >= {MIN_GRID_SIDE} with I*J <= {MAX_TILES} "
                f"(got {shown}); the string route needs at least {MIN_GRID_SIDE} tiles each way"
            )
        if self.size_mm is not None and not (math.isfinite(self.size_mm) and self.size_mm > 0):
            raise InputError(
                f"--size must be a positive number of millimetres (got {self.size_mm})"
            )
        if self.size_mm is not None and self.size_mm > MAX_SIZE_MM:
            raise InputError(
                f"--size {self.size_mm:g} mm is above the {MAX_SIZE_MM:g} mm that drawstring's "
                "1e-3 mm accuracy checks hold for; design a part of at most that size, or split "
                "the structure into several designs"
            )
        if not 100 <= self.resolution <= 1_000_000:
            raise InputError(
                f"--resolution must be between 100 and 1000000 triangles (got {self.resolution})"
            )
        if self.size_mm is not None and self.size_mm < MIN_SIZE_MM:
            raise InputError(f"--size must be at least {MIN_SIZE_MM:g} mm (got {self.size_mm:g})")
        if self.thickness_mm is not None and not (
            math.isfinite(self.thickness_mm) and self.thickness_mm > 0
        ):
            raise InputError(
                f"--thickness must be a positive number of millimetres (got {self.thickness_mm})"
            )
        if self.thickness_mm is not None and not (
            MIN_THICKNESS_MM <= self.thickness_mm <= MAX_THICKNESS_MM
        ):
            raise InputError(
                f"--thickness must be from {MIN_THICKNESS_MM:g} to {MAX_THICKNESS_MM:g} mm, as a "
                f"profile's tile.thickness_mm (got {self.thickness_mm:g})"
            )
        if self.min_gap_angle_deg is not None and not 0 <= self.min_gap_angle_deg <= 60:
            # as a profile's tile.min_gap_angle_deg: gaps that open at least theta absorb a tile
            # area ratio of at most 2 / (1 + sin theta), 1.07 at 60 deg, so past that the
            # design falls apart into ever more split parts
            if self.min_gap_angle_deg > 60:
                why = "wider gaps leave the flat layout almost no room to absorb the curvature"
            elif self.min_gap_angle_deg < 0:
                why = "it is the least angle a gap opens to, so it cannot be negative"
            else:
                why = "give a number of degrees; the shipped profiles use 12 to 15"
            raise InputError(
                f"--min-gap-angle must be in [0, 60] degrees (got {self.min_gap_angle_deg}); {why}"
            )
        if self.fit not in FIT_CHOICES:
            raise InputError(f"--fit must be close or paper (got {self.fit!r})")
        if self.weights is None:
            pass
        elif len(self.weights) != 3 or not all(0 <= w <= MAX_WEIGHT for w in self.weights):
            shown = " ".join(f"{w:g}" for w in self.weights)
            most = f"{MAX_WEIGHT:.0e}".replace("e+0", "e")
            raise InputError(
                f"--weights PLANAR SQUARE SURFACE must be three numbers from 0 to {most} "
                f"(got {shown}); the paper uses 10000 10 0.1"
            )
        elif not any(w > 0 for w in self.weights):
            raise InputError(
                "--weights: at least one of PLANAR SQUARE SURFACE must be positive "
                "(paper: 10000 10 0.1)"
            )
        if self.hinges is not None and self.hinges not in HINGE_STRATEGIES:
            raise InputError(f"--hinges must be dual or top (got {self.hinges!r})")
        if (
            len(self.up) != 3
            or not all(math.isfinite(c) for c in self.up)
            or math.hypot(*self.up) < 1e-9
        ):
            raise InputError(
                f"--up needs three finite numbers, not all zero, e.g. 0 0 1 (got {self.up})"
            )
        if not (math.isfinite(self.max_scale_factor) and 1 < self.max_scale_factor <= 2):
            raise InputError(
                f"--max-scale-factor must be in (1, 2] (got {self.max_scale_factor}); "
                "a quad linkage expands at most 2x"
            )


@dataclass(frozen=True)
class ResolvedOptions:
    """Options with every default filled in from the profile; written to design.json."""

    profile: str
    tiles: int | None
    grid: tuple[int, int] | None
    size_mm: float
    resolution: int
    thickness_mm: float
    min_gap_angle_deg: float
    max_scale_factor: float
    corners: tuple[int, int, int, int] | None
    hinges: HingeStrategy
    #: the paper's eq.-1 weights, or ``--weights``: the shape of ``--fit paper`` (and of
    #: ``close`` where the close shape is not kept), and the co-optimization's surface weight
    weights: tuple[float, float, float]
    #: ``--fit`` as given (``--weights`` overrides it: ``metrics.fit.used``)
    fit: FitChoice
    up: tuple[float, float, float]
    simulate: bool
    cad: bool
    co_optimize: bool
    seed: int
    repair: bool
    #: the printer preset (a shipped name or the file's path); None where nothing is printed
    printer: str | None
    slice: bool


@dataclass(frozen=True)
class Design:
    """Everything the pipeline computed."""

    options: ResolvedOptions
    profile: Profile
    target: Target
    flattening: Flattening
    tiling: Tiling
    assembled: AssembledResult
    flat: FlatResult
    hinge_layout: HingeLayout
    lift: LiftPoints
    route: Route
    measured: dict[str, Any] = field(default_factory=dict)
    #: the solids in the fabrication pose and the assembled pose (None with ``--no-cad``)
    cad_flat: CadResult | None = None
    cad_assembled: CadResult | None = None
    #: the simulated deployment of the chosen route (None with ``--no-simulate``)
    simulation: SimulationResult | None = None
    timings_s: dict[str, float] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    problems: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()
    #: the printer the tiles are printed on (None where nothing is printed)
    printer: Printer | None = None
    #: design.json's ``quality`` (:func:`~drawstring.pipeline.quality.quality_levels`)
    quality: dict[str, Any] = field(default_factory=dict)

    @property
    def tiles_assembled(self) -> NDArray[np.float64]:
        """(T, 8, 3) T3D tiles, mm."""
        return self.assembled.tiles

    @property
    def tiles_flat(self) -> NDArray[np.float64]:
        """(T, 8, 3) T2D tiles after the hinge layout, mm (fabrication pose)."""
        return self.hinge_layout.tiles

    def layout_misses(self) -> list[str]:
        """The flat-layout accuracy targets this design misses, one line each.

        These are the flat edge error and the hinge gap, both at most ``1e-3`` mm: what the
        flat layout, the co-optimization and the hinge layout control; quality levels, which
        the CLI turns into exit status 4 (:data:`~drawstring.app.status.EXIT_WARNINGS`) with
        ``--strict`` (over the profile's fabrication tolerance they are problems).  A hinge
        gap that meets the target seen from above but not in 3D (the thickness difference of
        two tiles at a bottom hinge, where the conical co-optimization and tighter tilings
        could not close it) is named as such: ``--hinges top`` closes it.  The surface
        distance stays a plain warning.
        """
        misses = []
        measured = self.measured
        edge = measured.get("flat_edge_error_max_mm")
        if isinstance(edge, int | float) and edge > FLAT_EDGE_ERROR_TOL_MM:
            misses.append(
                f"flat edge error {above(edge, FLAT_EDGE_ERROR_TOL_MM)} mm exceeds "
                f"{FLAT_EDGE_ERROR_TOL_MM:g} mm"
            )
        in_plane = measured.get("hinge_gap_in_plane_max_mm")
        whole = measured.get("hinge_gap_max_mm")
        tol = HINGE_GAP_TOL_MM
        if isinstance(in_plane, int | float) and in_plane > tol:
            misses.append(f"hinge gap seen from above {above(in_plane, tol)} mm exceeds {tol:g} mm")
        elif isinstance(whole, int | float) and whole > tol:
            misses.append(
                f"hinge gap {above(whole, tol)} mm exceeds {tol:g} mm in depth (the tiles' "
                "thickness difference at bottom hinges)"
            )
        return misses

    def metrics(self) -> dict[str, Any]:
        """Numbers measured on the output geometry (``metrics`` in docs/output.md)."""
        return {
            "scale_factor_max": round(self.tiling.scale_factor_max, 6),
            "scale_factor_max_before_splits": round(self.tiling.scale_factor_max_unsplit, 6),
            **self.measured,
        }

    def to_json(self) -> dict[str, Any]:
        target = self.target
        return {
            "drawstring_version": _version(),
            "target": {
                "name": target.name,
                "source": target.source,
                "vertices": int(len(target.vertices)),
                "faces": int(len(target.faces)),
                "size_mm": rounded(float(np.ptp(target.vertices, axis=0).max())),
                "bbox_diagonal_mm": rounded(target.bbox_diagonal_mm),
                # the rectangle's corners as ids of the mesh as read: --corners keeps them
                "corners": input_vertex_ids(target, self.flattening.corners),
                "notes": list(target.notes),
            },
            # --resolution makes the built-ins' triangles; a mesh file is used as it is
            "options": jsonable(
                asdict(self.options)
                if target.source == "builtin"
                else {**asdict(self.options), "resolution": None}
            ),
            "profile": self.profile.name,
            "linkage": {
                **self.tiling.linkage.counts(),
                "grid": list(self.tiling.linkage.grid_shape),
                "cell_size_mm": rounded(self.tiling.cell_size),
                "split_lines": [s.to_json() for s in self.tiling.linkage.splits],
                "tile_cells": self.tiling.linkage.tile_cells.tolist(),
            },
            "metrics": self.metrics(),
            "quality": self.quality,
            "notes": list(self.notes),
            "problems": list(self.problems),
            "warnings": list(self.warnings),
            "timings_s": {k: round(v, 3) for k, v in self.timings_s.items()},
        }


Writer = Callable[[Design, Path], list[str]]


def _version() -> str:
    try:
        return metadata.version("drawstring")
    except metadata.PackageNotFoundError:  # running from a checkout without install
        return "0+unknown"


class Progress:
    """Stage progress on stderr; silent when quiet or piped.

    Stages may nest (the lift-point sweep routes and simulates each lift set it tries): a
    stage's time excludes its nested stages', and a stage run several times adds up.
    """

    def __init__(self, quiet: bool = False) -> None:
        self.enabled = not quiet and sys.stderr.isatty()
        self.timings: dict[str, float] = {}
        self._open: list[list[float]] = []  # per open stage: [nested time]
        self._line_open = False

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        start = time.perf_counter()
        if self.enabled:
            if self._line_open:
                print(file=sys.stderr)
            print(f"  {name} ...", end="", file=sys.stderr, flush=True)
            self._line_open = True
        self._open.append([0.0])
        try:
            yield
        except BaseException:
            if self.enabled and self._line_open:  # an error or Ctrl-C starts on its own line
                print(file=sys.stderr, flush=True)
                self._line_open = False
            raise
        finally:
            nested = self._open.pop()[0]
            elapsed = time.perf_counter() - start
            if self._open:
                self._open[-1][0] += elapsed
            self.timings[name] = self.timings.get(name, 0.0) + elapsed - nested
        if self.enabled:
            if not self._line_open:
                print(f"  {name}", end="", file=sys.stderr)
            print(f" {elapsed:.1f} s", file=sys.stderr, flush=True)
            self._line_open = False
        log.info("stage %s took %.3f s", name, elapsed)

    def absorb(self, timings: dict[str, float], waited: float) -> None:
        """Account for stages that ran in another process (``timings``, its own stage times)
        while this one waited ``waited`` seconds for them: the wait is shared among those
        stages in proportion to their times, so the timings add up to this process's wall
        clock."""
        total = sum(timings.values())
        for name, seconds in timings.items():
            share = waited * seconds / total if total > 0 else 0.0
            self.timings[name] = self.timings.get(name, 0.0) + share
        if self._open:  # the wait happened inside an open stage: not its own time
            self._open[-1][0] += waited
        stages = ", ".join(name for name in timings if timings[name] > 0)
        if self.enabled:
            if self._line_open:
                print(file=sys.stderr)
                self._line_open = False
            print(f"  {stages} (second process) {waited:.1f} s", file=sys.stderr, flush=True)
        log.info("waited %.3f s for stages run in another process (%s)", waited, stages)

    def ordered_timings(self) -> dict[str, float]:
        """Timings with the stages in pipeline order, then any others."""
        rank = {name: i for i, name in enumerate(STAGES)}
        return dict(sorted(self.timings.items(), key=lambda kv: rank.get(kv[0], len(rank))))


def input_vertex_ids(target: Target, ids: NDArray[np.int64] | None) -> list[int] | None:
    """Vertex ids of the loaded ``target`` as ids of the mesh as read (the first input vertex
    each came from), as ``--corners`` takes them; None without ids."""
    if ids is None:
        return None
    where = target.vertex_of_input
    if where is None:
        return [int(v) for v in ids]
    return [int(np.flatnonzero(where == v)[0]) for v in ids]
