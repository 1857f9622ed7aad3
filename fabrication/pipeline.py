"""The design pipeline: target -> flattening -> tiling -> ... -> output folder.

``design(target, options)`` runs every stage in order, times each one and returns a
:class:`Design`; ``write_design(design, out_dir)`` writes the output folder atomically.  The CLI
and the Python API both go through these two functions::

    from drawstring.fabrication.pipeline import DesignOptions, design, write_design
    result = design("saddle", DesignOptions(tiles=200))
    write_design(result, "saddle-drawstring")
"""

from __future__ import annotations

import json
import logging
import math
import os
import shutil
import sys
import tempfile
import time
import zipfile
import zlib
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, replace
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from threadpoolctl import threadpool_limits

from drawstring.geometry import verify
from drawstring.geometry.assembled import (
    AssembledResult,
)
from drawstring.geometry.errors import InputError, ThicknessError
from drawstring.geometry.flat import FlatResult
from drawstring.geometry.flatten import Flattening, flatten
from drawstring.geometry.hinges import (
    HingeLayout,
    HingeStrategy,
)
from drawstring.geometry.lift import (
    LiftPoints,
    nearby_lift_gaps,
    select_lift_points,
    tile_masses_from_volumes,
)
from drawstring.geometry.linkage import Linkage, gap_centroids
from drawstring.geometry.rigidity import rigidity_report
from drawstring.geometry.route import Route, plan_route, route_metrics
from drawstring.geometry.simulate import (
    SimulationResult,
    route_snap_pairs,
    route_steps,
    simulate_stage,
    split_contact_pairs,
)
from drawstring.geometry.target import Target, load_target
from drawstring.geometry.tiling import Tiling, grid_shape_for, parts_in_place
from drawstring.geometry.tolerances import (
    CAD_PAD_INTERFERENCE_REL,
    FLAT_EDGE_ERROR_TOL_MM,
    FLAT_GAP_ANGLE_TOL_DEG,
    FLAT_INTERPENETRATION_TOL_MM3,
    FLAT_OVERLAP_TOL_MM2,
    HINGE_GAP_TOL_MM,
    MAX_SCALE_FACTOR,
)

from .layout_stage import (
    fabricated_tiles,
    shape_and_layout,
    split_bound,
)
from .profiles import MAX_TILES, MIN_GRID_SIDE, MIN_TILES, Profile, load_profile

#: Mean distance of K3D to the target, as a fraction of the mean tile side, above which the
#: design is flagged (issue 3 quality target).
SURFACE_MEAN_REL = 0.02

#: Largest distance (mm) between a channel's exit and the next tile's entry, assembled pose.
CHANNEL_MATCH_TOL_MM = 0.05

log = logging.getLogger(__name__)

#: Stages in order; ``timings_s`` uses these keys.
STAGES = (
    "target", "flatten", "tiling", "assembled", "flat", "hinges", "lift", "route", "rigidity",
    "simulate",
)  # fmt: skip
HINGE_STRATEGIES: tuple[HingeStrategy, ...] = ("dual", "top")


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
    hinges: HingeStrategy = "dual"
    weights: tuple[float, float, float] = (1e4, 10.0, 0.1)
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    simulate: bool = True
    cad: bool = True
    co_optimize: bool = True
    seed: int = 0

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
        if not 100 <= self.resolution <= 1_000_000:
            raise InputError(
                f"--resolution must be between 100 and 1000000 triangles (got {self.resolution})"
            )
        if self.thickness_mm is not None and not (
            math.isfinite(self.thickness_mm) and self.thickness_mm > 0
        ):
            raise InputError(
                f"--thickness must be a positive number of millimetres (got {self.thickness_mm})"
            )
        if self.min_gap_angle_deg is not None and not 0 <= self.min_gap_angle_deg <= 60:
            # as a profile's tile.min_gap_angle_deg: gaps that open at least theta absorb a tile
            # area ratio of at most 2 / (1 + sin theta), 1.07 at 60 deg, so past that the
            # design falls apart into ever more split parts
            raise InputError(
                f"--min-gap-angle must be in [0, 60] degrees (got {self.min_gap_angle_deg}); "
                "wider gaps leave the flat layout almost no room to absorb the surface's "
                "curvature"
            )
        if len(self.weights) != 3 or not all(math.isfinite(w) and w >= 0 for w in self.weights):
            shown = " ".join(f"{w:g}" for w in self.weights)
            raise InputError(
                f"--weights PLANAR SQUARE SURFACE must be three finite numbers >= 0 (got {shown}); "
                "the paper uses 10000 10 0.1"
            )
        if not any(w > 0 for w in self.weights):
            raise InputError(
                "--weights: at least one of PLANAR SQUARE SURFACE must be positive "
                "(paper: 10000 10 0.1)"
            )
        if self.hinges not in HINGE_STRATEGIES:
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
    weights: tuple[float, float, float]
    up: tuple[float, float, float]
    simulate: bool
    cad: bool
    co_optimize: bool
    seed: int


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
    cad_flat: Any = None
    cad_assembled: Any = None
    simulation: Any = None
    timings_s: dict[str, float] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    problems: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()

    @property
    def tiles_assembled(self) -> NDArray[np.float64]:
        """(T, 8, 3) T3D tiles, mm."""
        return self.assembled.tiles

    @property
    def tiles_flat(self) -> NDArray[np.float64]:
        """(T, 8, 3) T2D tiles after the hinge layout, mm (fabrication pose)."""
        return self.hinge_layout.tiles

    def metrics(self) -> dict[str, Any]:
        """Numbers measured on the output geometry (ARCHITECTURE.md section 4)."""
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
                "size_mm": _round(float(np.ptp(target.vertices, axis=0).max())),
                "bbox_diagonal_mm": _round(target.bbox_diagonal_mm),
                "notes": list(target.notes),
            },
            # --resolution makes the built-ins' triangles; a mesh file is used as it is
            "options": _jsonable(
                asdict(self.options)
                if target.source == "builtin"
                else {**asdict(self.options), "resolution": None}
            ),
            "profile": self.profile.name,
            "linkage": {
                **self.tiling.linkage.counts(),
                "grid": list(self.tiling.linkage.grid_shape),
                "cell_size_mm": _round(self.tiling.cell_size),
                "split_lines": [s.to_json() for s in self.tiling.linkage.splits],
                "tile_cells": self.tiling.linkage.tile_cells.tolist(),
            },
            "metrics": self.metrics(),
            "notes": list(self.notes),
            "problems": list(self.problems),
            "warnings": list(self.warnings),
            "timings_s": {k: round(v, 3) for k, v in self.timings_s.items()},
        }


def _round(value: float, digits: int = 6) -> float:
    return float(round(value, digits))


def _jsonable(value: Any) -> Any:
    """Plain JSON values: numpy scalars and arrays become Python numbers and lists."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple | np.ndarray):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.bool_ | bool):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating | float):
        return float(value) if math.isfinite(value) else None
    return value


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

    def ordered_timings(self) -> dict[str, float]:
        """Timings with the stages in pipeline order, then any others."""
        rank = {name: i for i, name in enumerate(STAGES)}
        return dict(sorted(self.timings.items(), key=lambda kv: rank.get(kv[0], len(rank))))


def resolve_options(options: DesignOptions, profile: Profile) -> ResolvedOptions:
    """Fill profile defaults into the options."""
    options.validate()
    tiles = options.tiles
    if options.grid is None and tiles is None:
        tiles = profile.default_tiles
    return ResolvedOptions(
        profile=profile.name if profile.source.endswith("(shipped)") else profile.source,
        tiles=tiles if options.grid is None else None,
        grid=tuple(options.grid) if options.grid is not None else None,  # type: ignore[arg-type]
        size_mm=options.size_mm if options.size_mm is not None else profile.default_size_mm,
        resolution=options.resolution,
        thickness_mm=options.thickness_mm
        if options.thickness_mm is not None
        else profile.thickness_mm,
        min_gap_angle_deg=options.min_gap_angle_deg
        if options.min_gap_angle_deg is not None
        else profile.min_gap_angle_deg,
        max_scale_factor=options.max_scale_factor,
        corners=options.corners,
        hinges=options.hinges,
        weights=tuple(options.weights),  # type: ignore[arg-type]
        up=tuple(float(c) / math.hypot(*options.up) for c in options.up),  # type: ignore[arg-type]
        simulate=options.simulate,
        cad=options.cad,
        co_optimize=options.co_optimize,
        seed=options.seed,
    )


def check_grid(options: ResolvedOptions, flat_map: Flattening, *, from_profile: bool) -> None:
    """Refuse a tile count that gives this target's flattening a grid too narrow for a string
    route (fewer than :data:`MIN_GRID_SIDE` cells one way), before the costly stages."""
    if options.tiles is None:
        return
    width, height = np.ptp(flat_map.uv, axis=0).tolist()
    n_i, n_j = grid_shape_for(width, height, options.tiles)
    if min(n_i, n_j) >= MIN_GRID_SIDE:
        return
    need = options.tiles
    while need < MAX_TILES and min(grid_shape_for(width, height, need)) < MIN_GRID_SIDE:
        need += 1
    asked = f"the profile's {options.tiles} tiles" if from_profile else f"--tiles {options.tiles}"
    grid = f"--grid {MIN_GRID_SIDE} {MIN_GRID_SIDE}"
    fix = (
        f"use --tiles {need} or more, or {grid}"
        if min(grid_shape_for(width, height, need)) >= MIN_GRID_SIDE
        else f"use {grid} or more (no tile count up to {MAX_TILES} gives such a grid)"
    )
    raise InputError(
        f"with {asked} this target gets a {n_i} x {n_j} grid, but the string route needs at least "
        f"{MIN_GRID_SIDE} tiles each way: {fix}"
    )


def size_refusal(exc: ThicknessError, options: ResolvedOptions) -> InputError | None:
    """The one-line refusal of a size too small for the tile thickness, or None when the
    assembled stage found no thickness that works.

    Tiles turn inside out where the thickness exceeds about the target's radius of curvature,
    which scales with ``--size``: the design at ``size * thickness / advice`` is the one at
    ``--thickness advice`` scaled up, so that size is the one to suggest.
    """
    thickness, advice = exc.thickness, exc.advice
    if not 0 < advice < thickness:
        return None
    wanted = options.size_mm * thickness / advice
    step = 10.0 ** (math.floor(math.log10(wanted)) - 1)  # two significant digits, rounded up
    size = math.ceil(wanted / step - 1e-9) * step
    fewer = "a smaller --grid" if options.grid is not None else "fewer --tiles"
    return InputError(
        f"--size {options.size_mm:g} mm is too small for {thickness:g} mm thick tiles: "
        f"{exc.inverted} tile(s) turn inside out where this target curves tightly; use "
        f"--size {size:g} or more, --thickness {advice:g} or less, or {fewer}"
    )


def channel_turn_assembled(route: Route, tiles_3d: NDArray[np.float64]) -> float:
    """Total turn (rad) of the string along its channels in the assembled state.

    The string runs from the centre of each route tile's entry side face to the centre of its
    exit side face, and on into the next tile through the coinciding face; the turn is summed
    at every such point of the closed polyline.  This is the friction-relevant bend of the
    channels (the issue's ``turn_angle_total_rad`` is measured through the flat gap centroids,
    which zigzag across the boundary ring).
    """
    side = np.array([[0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]])
    tiles = route.tiles
    entry = tiles_3d[tiles[:, None], side[route.enter_side]].mean(axis=1)
    exit_ = tiles_3d[tiles[:, None], side[route.leave_side]].mean(axis=1)
    points = np.stack([entry, exit_], axis=1).reshape(-1, 3)
    keep = np.ones(len(points), dtype=bool)
    keep[1:] = np.linalg.norm(np.diff(points, axis=0), axis=1) > 1e-9  # shared faces
    points = points[keep]
    if len(points) > 1 and np.linalg.norm(points[-1] - points[0]) <= 1e-9:
        points = points[:-1]  # the loop closes on its first point
    incoming = points - np.roll(points, 1, axis=0)
    outgoing = np.roll(points, -1, axis=0) - points
    norms = np.linalg.norm(incoming, axis=1) * np.linalg.norm(outgoing, axis=1)
    valid = norms > 1e-12
    cosine = np.einsum("ki,ki->k", incoming, outgoing)[valid] / norms[valid]
    return float(np.arccos(np.clip(cosine, -1.0, 1.0)).sum())


#: BLAS threads while designing.  A multi-threaded BLAS sums in an order that depends on its
#: thread count; the eq.-1 solve and the layouts amplify that rounding (the 200-tile chair:
#: assembled tiles 0.019 mm apart, flat edge error 0.0009 mm on two threads against 0.49 mm on
#: one), and the BLAS calls here are small enough that one thread costs nothing measurable.
BLAS_THREADS = 1


def design(
    target: str | os.PathLike[str],
    options: DesignOptions | None = None,
    *,
    quiet: bool = True,
    progress: Progress | None = None,
) -> Design:
    """Run the design pipeline on a mesh path or built-in target name.

    BLAS runs on one thread meanwhile (:data:`BLAS_THREADS`), so the result does not depend on
    the machine's core count.

    Raises
    ------
    InputError
        For bad input (the CLI prints its one-line message and exits with status 2).
    """
    with threadpool_limits(limits=BLAS_THREADS, user_api="blas"):
        return _design(target, options, quiet=quiet, progress=progress)


def _design(
    target: str | os.PathLike[str],
    options: DesignOptions | None,
    *,
    quiet: bool,
    progress: Progress | None,
) -> Design:
    options = options or DesignOptions()
    options.validate()
    profile = load_profile(options.profile)
    resolved = resolve_options(options, profile)
    progress = progress or Progress(quiet=quiet)
    notes: list[str] = []

    with progress.stage("target"):
        loaded = load_target(target, size_mm=resolved.size_mm, resolution=resolved.resolution)
    with progress.stage("flatten"):
        flat_map = flatten(
            loaded.vertices, loaded.faces, mode="rectangle", corners=resolved.corners
        )
    check_grid(resolved, flat_map, from_profile=options.tiles is None and options.grid is None)
    try:
        shaped = shape_and_layout(loaded, flat_map, resolved, progress)
    except ThicknessError as exc:
        refusal = size_refusal(exc, resolved)
        if refusal is None:
            raise
        raise refusal from exc
    notes.extend(shaped.notes)
    tiling, assembled, flat = shaped.tiling, shaped.assembled, shaped.flat
    co_block, hinge_layout, linkage = shaped.co_block, shaped.hinge_layout, shaped.tiling.linkage
    masses = tile_masses_from_volumes(
        assembled.tiles, profile.density_kg_m3 * profile.infill_fraction
    )
    # the route is planned with the parts side by side as they meet in the assembled shape
    flat_gap_xy = gap_centroids(
        linkage, parts_in_place(linkage, hinge_layout.tiles[:, :4, :2], tiling.uv)
    )
    fabricated = fabricated_tiles(hinge_layout, assembled.tiles)
    routes: dict[tuple[int, ...], tuple[Route, str | None, NDArray[np.int64]]] = {}
    runs: dict[tuple[int, ...], SimulationResult] = {}

    def route_for(
        lift_gaps: NDArray[np.int64],
    ) -> tuple[Route, str | None, NDArray[np.int64]]:
        key = tuple(int(g) for g in lift_gaps)
        if key not in routes:
            with progress.stage("route"):
                routes[key] = plan_lift_route(linkage, flat_gap_xy, lift_gaps)
        return routes[key]

    def simulated(lift_gaps: NDArray[np.int64]) -> SimulationResult:
        key = tuple(int(g) for g in lift_gaps)
        if key not in runs:
            route_steps, _, served = route_for(lift_gaps)
            with progress.stage("simulate"):
                runs[key] = simulate_stage(
                    linkage,
                    fabricated,
                    assembled.tiles,
                    hinge_layout.hinge_vertices,
                    route_steps,
                    served,
                    resolved.thickness_mm,
                )
        return runs[key]

    deploy_check = None
    if resolved.simulate:
        # The lift-point sweep raises its threshold while the simulated deployment fails
        # (paper sec. 5.2); every lift set is routed and simulated once.
        deploy_check = NamedCheck(
            "projective-dynamics deployment simulation",
            lambda gaps: simulated(gaps).deployed,
        )
    assembled_gap_xyz = gap_centroids(linkage, assembled.tiles[:, :4])
    with progress.stage("lift"):
        lift = select_lift_points(
            linkage,
            assembled.tiles.mean(axis=1),
            masses,
            up=resolved.up,
            gap_positions=assembled_gap_xyz,
            deploy_check=deploy_check,
        )
    if not resolved.simulate and lift.sweep and not any(ok for _, _, ok in lift.sweep):
        notes.append(
            f"lift points: the check '{lift.check_name}' failed for every threshold, so every "
            "energy peak is a lift point (run with the deployment simulation to check the pull)"
        )
    route, route_note, served = route_for(lift.lift_gaps)
    if route_note:
        notes.append(route_note)
    if not np.array_equal(served, lift.lift_gaps):
        lift = replace(lift, lift_gaps=served, positions=assembled_gap_xyz[served])
    measured, problems, warnings = measure_design(
        resolved, profile, tiling, assembled, flat, hinge_layout, lift, route, masses
    )
    measured["co_optimization"] = co_block
    measured["split_bound"] = _round(shaped.split_bound, 6)
    notes.extend(f"flat stage: {p}" for p in flat.problems)
    notes.extend(f"hinge stage: {p}" for p in hinge_layout.problems)
    with progress.stage("rigidity"):
        rigidity = design_rigidity(linkage, assembled.tiles, hinge_layout.hinge_vertices, route)
    measured["rigidity"] = rigidity
    if not rigidity["isostatic"]:
        warnings.append(
            f"the assembled linkage with its string keeps {rigidity['internal_flexes']} internal "
            "flex(es) (metrics.rigidity); it may wobble when the string is tight"
        )
    simulation = None
    if resolved.simulate:
        simulation = simulated(lift.lift_gaps)
        block = _jsonable(simulation.to_json())
        # Wall-clock numbers go to timings_s, so everything else in design.json is reproducible.
        block.pop("time_s", None)
        progress.timings["simulate_per_step"] = float(block.pop("per_step_ms", 0.0)) / 1000.0
        block["runs"] = len(runs)
        measured["simulation"] = block
        if not simulation.deployed:
            warnings.append(
                "the deployment simulation got stuck ("
                f"{len(simulation.open_gaps)} route gaps open, tiles up to "
                f"{simulation.final_max_deviation_mm:.2f} mm from the assembled shape, worst "
                f"tiles {', '.join(str(w['tile']) for w in simulation.worst_tiles(3))}) with "
                f"every lift-point set the sweep tried ({len(runs)}); see design.json "
                "metrics.simulation"
            )
    result = Design(
        options=resolved,
        profile=profile,
        target=loaded,
        flattening=flat_map,
        tiling=tiling,
        assembled=assembled,
        flat=flat,
        hinge_layout=hinge_layout,
        lift=lift,
        route=route,
        simulation=simulation,
        measured=measured,
        timings_s=progress.ordered_timings(),
        notes=tuple(notes),
        problems=tuple(problems),
        warnings=tuple(warnings),
    )
    if resolved.cad:
        result = with_cad(result, progress)
    return result


def with_cad(result: Design, progress: Progress) -> Design:
    """Build the solids (flat and assembled pose) and measure them; the export stage writes
    them out in :func:`write_design`."""
    from .cad_stage import build_cad, measure_cad

    with progress.stage("cad"):
        cad_flat, cad_assembled = build_cad(result)
        measured = measure_cad(result, cad_flat)
    problems = [*result.problems, *cad_problems(measured)]
    warnings = [*result.warnings, *cad_warnings(measured, result.profile)]
    notes = [*result.notes, *(f"cad: {n}" for n in cad_flat.notes)]
    return replace(
        result,
        cad_flat=cad_flat,
        cad_assembled=cad_assembled,
        # the mass of the tiles as cut plus the hinge parts replaces the uncut tiles' estimate
        measured={**result.measured, "cad": measured, "mass_g": measured["mass_g"]},
        problems=tuple(problems),
        warnings=tuple(warnings),
        notes=tuple(notes),
        timings_s=progress.ordered_timings(),
    )


def cad_warnings(measured: dict[str, Any], profile: Profile) -> list[str]:
    """What the solids lack without failing (:func:`~.cad_stage.measure_cad`)."""
    warnings = []
    broken = measured.get("magnet_pockets_breaking_out", 0)
    if broken:
        warnings.append(
            f"{broken} of {measured['magnet_pairs']} magnet pockets break out of their side "
            "faces, so those magnets show and sit loose (the cad notes list the tiles); use "
            f"smaller magnets than {profile.magnet_diameter_mm:g} mm (magnet.diameter_mm in a "
            "profile of your own) or thicker tiles (--thickness)"
        )
    return warnings


def cad_problems(measured: dict[str, Any]) -> list[str]:
    """Hard faults of the solids, from their measures (:func:`~.cad_stage.measure_cad`)."""
    problems = []
    if not measured["solids_valid"]:
        bad = measured.get("tiles_not_valid", [])
        which = f": tiles {', '.join(str(t) for t in bad)}" if bad else ""
        problems.append(
            "some tile or hinge solids are not valid B-rep solids or miss a feature the CAD "
            f"kernel failed on{which} (metrics.cad.tiles_not_valid and the notes)"
        )
    pockets = measured.get("magnet_pockets_missing", 0)
    if pockets:
        problems.append(f"{pockets} magnet pocket(s) were not cut (metrics.cad)")
    overlap = measured["interference_tiles_max_mm3"]
    if overlap > FLAT_INTERPENETRATION_TOL_MM3:
        problems.append(f"tile solids interfere in the print pose ({overlap} mm^3)")
    sunk = measured["interference_tiles_pads_max_rel"]
    if sunk > CAD_PAD_INTERFERENCE_REL:
        problems.append(
            f"a hinge part has {100 * sunk:.3g} % of its volume inside a tile in the print pose "
            "(a recess or pin hole was not cut)"
        )
    apart = measured["channel_opening_distance_max_mm"]
    missing = measured["channel_openings_missing"]
    if missing or apart > CHANNEL_MATCH_TOL_MM:
        faults = [
            link
            for link in measured.get("channel_worst_links", [])
            if link["distance_mm"] is None or link["distance_mm"] > CHANNEL_MATCH_TOL_MM
        ]
        where = "; ".join(
            f"tiles {a} -> {b}: "
            + ("an opening is missing on the solids" if d is None else f"{d:.3g} mm apart")
            for (a, b), d in ((link["tiles"], link["distance_mm"]) for link in faults)
        )
        counts = []
        if missing:
            counts.append(f"{missing} opening(s) missing")
        if apart > CHANNEL_MATCH_TOL_MM:
            counts.append(f"up to {apart} mm apart")
        problems.append(
            "string channels do not line up between consecutive tiles in the assembled pose "
            f"({', '.join(counts)}; {where}; metrics.cad.channel_worst_links)"
        )
    return problems


@dataclass(frozen=True)
class NamedCheck:
    """A deployment check ``check(lift_gaps) -> bool`` with the name design.json reports."""

    name: str
    check: Callable[[NDArray[np.int64]], bool]

    def __call__(self, lift_gaps: NDArray[np.int64]) -> bool:
        return bool(self.check(lift_gaps))


#: Hops (between gaps that share a tile) a lift point the string cannot reach may move to a
#: gap it can reach.
LIFT_MOVE_HOPS = 2

#: Candidate gaps tried with a new route each (gaps the route already passes cost nothing).
LIFT_MOVE_TRIES = 3


def _route_relaxing_splits(
    linkage: Linkage, flat_gap_xy: NDArray[np.float64], lift_gaps: NDArray[np.int64]
) -> tuple[Route, str | None]:
    route = plan_route(linkage, flat_gap_xy, lift_gaps)
    if len(route.lifts_missed):
        # The paper's rule keeps the string off split gaps except between boundary tiles; in a
        # narrow part that can leave a lift point unreachable.  Passing a split gap between two
        # tiles on the same side of the cut does not cross it.
        relaxed = plan_route(linkage, flat_gap_xy, lift_gaps, split_rule="same-component")
        if len(relaxed.lifts_missed) < len(route.lifts_missed):
            return relaxed, (
                "route: reached every lift point by letting the string pass split gaps "
                "between tiles on the same side of a cut"
                if not len(relaxed.lifts_missed)
                else "route: reached more lift points by letting the string pass split gaps "
                "between tiles on the same side of a cut"
            )
    return route, None


def plan_lift_route(
    linkage: Linkage, flat_gap_xy: NDArray[np.float64], lift_gaps: NDArray[np.int64]
) -> tuple[Route, str | None, NDArray[np.int64]]:
    """The string route through the boundary and the lift gaps, a note on what it had to
    relax, and the lift gaps it serves.

    A lift gap the route cannot reach (a narrow part, where a detour to it would need a gap or
    tile twice) moves to the nearest interior gap of its part within ``LIFT_MOVE_HOPS`` that
    the route passes anyway, or else that a new route reaches: a lift point next to the energy
    peak lifts nearly as well, one the string misses does not lift at all.
    """
    lifts = np.asarray(lift_gaps, dtype=np.int64)
    route, note = _route_relaxing_splits(linkage, flat_gap_xy, lifts)
    moves: list[str] = []
    for gap in route.lifts_missed.tolist():
        used = lifts.tolist()
        options = [
            int(c)
            for c in nearby_lift_gaps(linkage, gap, flat_gap_xy, LIFT_MOVE_HOPS)
            if int(c) not in used
        ]
        passed = set(route.gaps.tolist())
        pick = next((c for c in options if c in passed), None)
        if pick is not None:
            route = replace(route, lifts_missed=route.lifts_missed[route.lifts_missed != gap])
        else:
            for option in options[:LIFT_MOVE_TRIES]:
                trial = np.array([option if g == gap else g for g in used], dtype=np.int64)
                new_route, new_note = _route_relaxing_splits(linkage, flat_gap_xy, trial)
                if option not in new_route.lifts_missed.tolist() and len(
                    new_route.lifts_missed
                ) < len(route.lifts_missed):
                    route, note, pick = new_route, new_note, option
                    break
        if pick is None:
            continue
        lifts = np.array([pick if g == gap else g for g in lifts.tolist()], dtype=np.int64)
        hops = "one tile" if pick in nearby_lift_gaps(linkage, gap, flat_gap_xy, 1) else "two tiles"
        moves.append(f"gap {gap} to gap {pick} ({hops} away)")
    if moves:
        moved = (
            "lift points: the string cannot reach the energy peak's gap under the routing rules, "
            f"so the lift point moved: {'; '.join(moves)}"
        )
        note = f"{note}; {moved}" if note else moved
    return route, note, lifts


def design_rigidity(
    linkage: Linkage,
    tiles_3d: NDArray[np.float64],
    hinge_vertices: NDArray[np.int64],
    route: Route,
) -> dict[str, Any]:
    """Infinitesimal rigidity of the assembled linkage held by its string (paper Theorem 5.1).

    Joints: the hinges (ball joints).  Contacts: consecutive tiles along the route touch at
    their shared side faces, and tiles across a split are held by their magnets.  A null space
    of dimension 6 (rigid-body motions only) means the tight string locks the shape.
    """
    string_pairs, _ = route_snap_pairs(route_steps(route))
    magnet_pairs = split_contact_pairs(linkage)
    report = rigidity_report(
        tiles_3d, hinge_vertices, np.vstack([string_pairs, magnet_pairs]), contact="midpoint"
    )
    block: dict[str, Any] = {
        "null_dimension": report.null_dimension,
        "internal_flexes": report.internal_flexes,
        "isostatic": report.isostatic,
        "contacts": {"string": len(string_pairs), "magnets": len(magnet_pairs)},
        "joints": len(hinge_vertices),
        "smallest_nonzero_singular_value": _round(
            float(report.to_json()["smallest_nonzero_singular_value"]),
            12,
        ),
    }
    if report.internal_flexes:
        # Per flex, the tiles that move most (twist magnitude), so a person can find them.
        twists = report.flexes.reshape(len(tiles_3d), 6, -1)
        motion = np.linalg.norm(twists, axis=1)  # (T, flexes)
        block["flex_tiles"] = [
            np.argsort(-motion[:, k], kind="stable")[:5].tolist()
            for k in range(min(report.internal_flexes, 5))
        ]
    return block


def measure_design(
    options: ResolvedOptions,
    profile: Profile,
    tiling: Tiling,
    assembled: AssembledResult,
    flat: FlatResult,
    hinge_layout: HingeLayout,
    lift: LiftPoints,
    route: Route,
    masses: NDArray[np.float64],
) -> tuple[dict[str, Any], list[str], list[str]]:
    """Measure the output geometry (not the optimizers' beliefs) and list unmet targets.

    Returns the ``metrics`` entries of design.json, the *problems* (targets whose failure makes
    the part unbuildable: overlapping tiles, gaps outside their angle bounds, an invalid route,
    a scale range no layout can absorb) and the *warnings* (accuracy targets not met: the flat
    edge error and the hinge gap, which rigid tiles cannot in general bring to zero because the
    flat linkage is over-determined: 3 degrees of freedom per tile against about 4 hinge
    equations per tile).
    """
    linkage = tiling.linkage
    a = assembled.metrics
    metrics: dict[str, Any] = {
        key: _round(float(a[key]), 9)
        for key in (
            "planarity_max_mm",
            "planarity_max_before_mm",
            "contact_gap_max_mm",
            "contact_angle_max_deg",
            "surface_distance_max_mm",
            "surface_distance_mean_mm",
            "tile_side_mean_mm",
            "tile_side_spread",
            "thickness_min_mm",
            "thickness_max_mm",
        )
        if key in a
    }
    clash = verify.assembled_overlap(assembled.tiles, linkage)
    metrics.update(
        {k: _round(v, 9) if isinstance(v, float) else v for k, v in clash.to_json().items()}
    )
    tiles_2d = hinge_layout.tiles
    top_2d = tiles_2d[:, :4, :2]
    _, overlapping, areas = verify.flat_overlap(top_2d)
    # A trimmed pair's top faces overlap only inside its trim (the tops are coplanar in the
    # flat pose and the trim is the pair's whole 3D overlap); the interpenetration after the
    # trims below checks that independently.
    trimmed_pairs = {
        tuple(sorted(int(t) for t in linkage.hinges[trim.hinge, [0, 2]]))
        for trim in hinge_layout.trims
    }
    kept = [k for k, (a, b) in enumerate(overlapping.tolist()) if (a, b) not in trimmed_pairs]
    overlap_area = float(areas[kept].sum())
    trims = [(trim.tile, trim.vertices) for trim in hinge_layout.trims]
    volume, _, _ = verify.interpenetration(tiles_2d, trims=trims)
    edge_error = float(verify.flat_edge_errors(top_2d, assembled.tiles[:, :4]).max(initial=0.0))
    # Each slit end measured on the face that carries its hinge (top or bottom).
    angles = verify.gap_opening_angles_deg(linkage, tiles_2d, hinge_layout.bottom)
    # Hinge gap measured on the tiles as fabricated (rigid copies of T3D, before merging).
    fabricated = fabricated_tiles(hinge_layout, assembled.tiles)
    gaps = verify.hinge_gaps(fabricated, hinge_layout.hinge_vertices)
    hinge_gap = float(gaps.max(initial=0.0))
    in_plane = verify.hinge_gaps(fabricated, hinge_layout.hinge_vertices, in_plane=True)
    metrics.update(
        {
            "flat_overlap_area_mm2": _round(overlap_area, 9),
            "flat_interpenetration_mm3": _round(volume, 9),
            "flat_edge_error_max_mm": _round(edge_error, 9),
            "flat_gap_angle_min_deg": _round(float(angles.min(initial=90.0)), 6),
            "flat_gap_angle_max_deg": _round(float(angles.max(initial=0.0)), 6),
            "hinge_gap_max_mm": _round(hinge_gap, 9),
            "hinge_gap_in_plane_max_mm": _round(float(in_plane.max(initial=0.0)), 9),
            "hinges_bottom": int(np.count_nonzero(hinge_layout.bottom)),
            "mass_g": _round(float(masses.sum()) * 1000.0, 3),
        }
    )
    # top hinges trim every overlapping pair; dual ones only pairs that clear on neither face
    metrics["contact_area_lost_mm2"] = _round(hinge_layout.contact_area_lost_mm2, 6)
    metrics["lift_points"] = lift.to_json()
    assembled_gaps = gap_centroids(linkage, assembled.tiles[:, :4])
    flat_gaps = gap_centroids(linkage, parts_in_place(linkage, top_2d, tiling.uv))
    metrics["route"] = _jsonable(
        route_metrics(route, linkage, flat_gaps, assembled_gaps, profile.friction_coefficient)
    )
    # the string's length along its channels on the fabricated tiles, as every other output
    # reports it (not the planning polyline through the gap centres)
    from drawstring.cad.paths import route_lengths

    from .cad_stage import lift_exits, route_steps

    flat_length, assembled_length = route_lengths(
        fabricated, assembled.tiles, route_steps(route), lift_exits(route, lift.lift_gaps)
    )
    metrics["route"]["length_mm"] = {"flat": flat_length, "assembled": assembled_length}
    channel_turn = channel_turn_assembled(route, assembled.tiles)
    metrics["route"]["turn_angle_channels_assembled_rad"] = _round(channel_turn, 6)
    metrics["route"]["capstan_factor_channels_assembled"] = _round(
        math.exp(profile.friction_coefficient * channel_turn), 6
    )
    problems: list[str] = []
    warnings: list[str] = []
    folded = len(clash.nonconvex_top) + len(clash.nonconvex_bottom)
    if folded:
        problems.append(f"{folded} assembled tile faces are folded (non-convex)")
    if clash.depth_max_mm > verify.ASSEMBLED_OVERLAP_DEPTH_TOL_MM:
        problems.append(
            f"assembled tiles interpenetrate up to {clash.depth_max_mm:.3g} mm "
            f"({len(clash.pairs)} pairs)"
        )
    if overlap_area > FLAT_OVERLAP_TOL_MM2:
        problems.append(f"flat tiles overlap by {overlap_area:.3g} mm^2")
    if volume > FLAT_INTERPENETRATION_TOL_MM3:
        problems.append(f"flat tiles interpenetrate by {volume:.3g} mm^3")
    if edge_error > FLAT_EDGE_ERROR_TOL_MM:
        warnings.append(
            f"flat edge error {edge_error:.2g} mm exceeds {FLAT_EDGE_ERROR_TOL_MM:g} mm: a "
            "curved target's tiles cannot all keep their assembled shape with every hinge "
            "meeting in the plane; the printed tiles are exact copies of the assembled ones, "
            "and more tiles shrink the error"
        )
    low = options.min_gap_angle_deg - FLAT_GAP_ANGLE_TOL_DEG
    if angles.size and (angles.min() < low or angles.max() > 90 + FLAT_GAP_ANGLE_TOL_DEG):
        problems.append(
            f"gap angles {angles.min():.2f}..{angles.max():.2f} deg leave "
            f"[{options.min_gap_angle_deg:g}, 90]"
        )
    side = float(a.get("tile_side_mean_mm", 0.0))
    mean_distance = float(a.get("surface_distance_mean_mm", 0.0))
    if side > 0 and mean_distance > SURFACE_MEAN_REL * side:
        warnings.append(
            f"tiles sit {mean_distance:.2f} mm from the target on average, more than "
            f"{100 * SURFACE_MEAN_REL:g} % of the mean tile side; raise the surface weight "
            "(--weights 1e4 1 100 fits closely) or use more tiles"
        )
    in_plane_gap = float(in_plane.max(initial=0.0))
    if hinge_gap > HINGE_GAP_TOL_MM:
        if in_plane_gap <= HINGE_GAP_TOL_MM:
            cause = (
                f"seen from above the hinges meet to {in_plane_gap:.2g} mm; the rest is the "
                "tiles' thickness difference (the quad mesh is not conical), which the hinge "
                "parts bridge"
            )
        else:
            cause = (
                "the hinge parts bridge it; more tiles shrink it, and --hinges top reaches "
                "1e-3 mm on most built-ins"
            )
        warnings.append(f"hinge gap {hinge_gap:.2g} mm exceeds {HINGE_GAP_TOL_MM:g} mm: {cause}")
    if tiling.scale_factor_max > split_bound(options):
        problems.append(
            f"scale factor {tiling.scale_factor_max:.2f} exceeds {split_bound(options):.3g}"
        )
    problems.extend(route_problems(route, linkage))
    if not profile.size_min_mm <= options.size_mm <= profile.size_max_mm:
        warnings.append(
            f"--size {options.size_mm:g} mm is outside the {profile.size_min_mm:g}-"
            f"{profile.size_max_mm:g} mm that the {profile.name} profile suits (its tile "
            "thickness, hinge parts and machine are made for that range); choose a profile "
            "for this size (drawstring profiles --size ...) or a size within it"
        )
    if len(route.lifts_missed):
        warnings.append(
            f"the string route cannot reach lift gap(s) {route.lifts_missed.tolist()} under the "
            "routing rules; pull at the other lift points"
        )
    return metrics, problems, warnings


def route_problems(route: Route, linkage: Linkage) -> list[str]:
    """Hard faults of a string route, measured on the route itself: it crosses itself, misses
    boundary tiles, or leaves a split part unvisited (that part would never be pulled)."""
    problems = []
    if route.crossings:
        problems.append(f"the string route crosses itself {route.crossings} time(s)")
    if not route.boundary_tiles_covered:
        problems.append("the string route misses some boundary tiles")
    visited = np.unique(linkage.tile_component[route.tiles])
    missed = np.setdiff1d(np.arange(linkage.n_components), visited)
    if missed.size:
        first = [int(np.flatnonzero(linkage.tile_component == c)[0]) for c in missed]
        problems.append(
            f"the string route reaches {visited.size} of {linkage.n_components} split parts; "
            f"the {missed.size} part(s) holding tiles {first} would not be pulled into shape "
            "(the string reaches only parts that touch the outer boundary; other --corners "
            "or --tiles give other splits)"
        )
    return problems


def default_out_dir(target: str | os.PathLike[str]) -> Path:
    """``./NAME-drawstring`` for a built-in name or a mesh file's stem."""
    return Path.cwd() / f"{Path(str(target)).stem}-drawstring"


def check_out_dir(out_dir: str | os.PathLike[str]) -> Path:
    """Refuse an output path that cannot become the design folder, before any work is done."""
    out = Path(out_dir).absolute()
    if out.exists() and not out.is_dir():
        raise InputError(f"output path {out} exists and is a file; choose another --out")
    if out.is_dir() and any(out.iterdir()) and not (out / "design.json").is_file():
        raise InputError(
            f"output folder {out} exists and is not a drawstring design; choose another --out"
        )
    parent = out.parent
    probe = parent
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir():
        raise InputError(f"cannot write into {probe}: not a folder; choose another --out")
    # Make and remove a folder there rather than ask os.access, which answers yes to root
    # everywhere (on /proc, on a read-only mount) and the run would fail only at the end.
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".drawstring-probe-", dir=probe))
    except OSError as exc:
        raise InputError(
            f"cannot write into {probe} ({exc.strerror or type(exc).__name__}); choose a "
            "writable --out folder"
        ) from None
    if out.is_dir():
        _probe_rename(out)
    return out


def _probe_rename(out: Path) -> None:
    """Refuse a folder that cannot be renamed (immutable, a mount point, a sticky parent owned
    by someone else): :func:`write_design` renames it aside to replace it, at the very end.
    The probe renames it to a unique sibling name and straight back."""
    aside = out.parent / f".{out.name}.{os.getpid()}.{time.monotonic_ns()}.probe"
    try:
        os.rename(out, aside)
    except OSError as exc:
        raise _placement_error(out, exc) from None
    try:
        os.rename(aside, out)
    except OSError as exc:
        raise InputError(
            f"cannot rename {aside} back to {out} ({exc.strerror or exc}); rename it by hand"
        ) from None


def _placement_error(out: Path, exc: OSError) -> InputError:
    """The one-line refusal for an OSError while writing or placing the output folder."""
    reason = exc.strerror or type(exc).__name__
    if exc.filename is not None and Path(exc.filename) != out:
        reason = f"{reason}: {exc.filename}"
    return InputError(
        f"cannot write the design to {out} ({reason}); choose another --out, or make {out} "
        "and its parent folder writable"
    )


Writer = Callable[[Design, Path], list[str]]


def write_design(
    result: Design,
    out_dir: str | os.PathLike[str],
    writers: tuple[Writer, ...] | None = None,
) -> Path:
    """Write the output folder atomically.

    Everything is written into a temporary sibling folder, which replaces ``out_dir`` only when
    every file was written.  On any failure the temporary folder is removed and ``out_dir`` is
    left as it was.
    """
    from .outputs import DEFAULT_WRITERS
    from .report import write_report

    out = check_out_dir(out_dir)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    except OSError as exc:
        raise _placement_error(out, exc) from None
    try:
        files: list[str] = []
        for writer in writers or DEFAULT_WRITERS:
            files.extend(writer(result, staging))
        document = result.to_json()
        document["files"] = sorted([*files, "design.json", "report.html"])
        (staging / "design.json").write_text(
            json.dumps(document, indent=2, allow_nan=False) + "\n", encoding="utf-8"
        )
        write_report(staging)  # last: it reads every other file of the folder
        os.chmod(staging, 0o755)
        _place(staging, out)
    except OSError as exc:
        shutil.rmtree(staging, ignore_errors=True)
        raise _placement_error(out, exc) from None
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return out


def _place(staging: Path, out: Path) -> None:
    """Rename the finished ``staging`` folder to ``out``, replacing an earlier folder there.

    The earlier folder is first renamed into a temporary sibling, removed only once the new
    one is in place; when a rename fails it is renamed back and the temporary sibling removed,
    so an :class:`OSError` leaves ``out`` as it was (the caller removes ``staging``).
    """
    if not out.exists():
        os.rename(staging, out)
        return
    retired = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".old", dir=out.parent))
    aside = retired / out.name
    try:
        os.rename(out, aside)
    except OSError:
        shutil.rmtree(retired, ignore_errors=True)
        raise
    try:
        os.rename(staging, out)
    except OSError as exc:
        try:
            os.rename(aside, out)
        except OSError:
            raise InputError(
                f"cannot write the design to {out} ({exc.strerror or exc}), nor put the earlier "
                f"folder back: it is now {aside}; rename it by hand"
            ) from None
        shutil.rmtree(retired, ignore_errors=True)
        raise
    shutil.rmtree(retired, ignore_errors=True)


def with_options(options: DesignOptions, **changes: Any) -> DesignOptions:
    """A copy of ``options`` with some fields changed (for scripts and tests)."""
    return replace(options, **changes)


def simulate_folder(folder: str | os.PathLike[str], *, quiet: bool = True) -> Path:
    """Run the deployment simulation on a design folder written by :func:`write_design`.

    Reads ``design.json`` (options, linkage cells and splits, lift points), ``tiles.npz`` (the
    tiles at full precision), ``hinges.json`` and ``route.json``, so that a design's own run is
    repeated exactly; writes ``deploy.npz`` and ``deploy.gif``,
    the ``simulation`` metrics and timing into ``design.json``, and rewrites ``report.html``.
    Every file is written next to its final name first and renamed into place.
    """
    from .outputs import save_deployment
    from .report import write_report

    root = Path(folder)
    design_path = root / "design.json"
    if not design_path.is_file():
        raise InputError(f"{root} is not a drawstring design folder (no design.json)")
    needed = ("tiles.npz", "hinges.json", "route.json")
    missing = [name for name in needed if not (root / name).is_file()]
    if missing:
        raise InputError(f"{root} lacks {', '.join(missing)}; run drawstring design again")
    try:
        doc, linkage, assembled, fabricated, hinge_vertices, steps, lift_gaps = _read_design(
            root, design_path
        )
        thickness = float(doc["options"]["thickness_mm"])
    except InputError:
        raise
    except (
        OSError,
        EOFError,
        ValueError,
        KeyError,
        TypeError,
        IndexError,
        zipfile.BadZipFile,
        zlib.error,
    ) as exc:
        what = exc.strerror if isinstance(exc, OSError) and exc.strerror else type(exc).__name__
        raise InputError(
            f"{root}: the design files cannot be read ({what}); run drawstring design again"
        ) from exc
    if assembled.shape != (linkage.n_tiles, 8, 3) or fabricated.shape != assembled.shape:
        raise InputError(f"{root}: tiles.npz does not match design.json; run design again")
    in_range = (
        np.all((steps[:, 0] >= 0) & (steps[:, 0] < linkage.n_gaps))
        and np.all((steps[:, 1] >= 0) & (steps[:, 1] < linkage.n_tiles))
        and np.all((steps[:, 2:] >= 0) & (steps[:, 2:] <= 4))
        and np.all((hinge_vertices >= 0) & (hinge_vertices < 8 * linkage.n_tiles))
        and np.all((lift_gaps >= 0) & (lift_gaps < linkage.n_gaps))
    )
    if not in_range:
        raise InputError(
            f"{root}: route.json, hinges.json or the lift points do not match design.json; "
            "run drawstring design again"
        )
    progress = Progress(quiet=quiet)
    with progress.stage("simulate"):
        simulation = simulate_stage(
            linkage,
            fabricated,
            assembled,
            hinge_vertices,
            steps,
            lift_gaps,
            thickness,
        )
    result_block = _jsonable(simulation.to_json())
    # the lift sweep's count is the design's; a design made without simulating has run once now
    runs = doc.get("metrics", {}).get("simulation", {}).get("runs")
    result_block["runs"] = runs if isinstance(runs, int) else 1
    result_block.pop("time_s", None)
    per_step = float(result_block.pop("per_step_ms", 0.0)) / 1000.0
    doc.setdefault("metrics", {})["simulation"] = result_block
    doc.setdefault("timings_s", {})["simulate"] = round(progress.timings["simulate"], 3)
    doc["timings_s"]["simulate_per_step"] = round(per_step, 3)
    try:
        staging = Path(tempfile.mkdtemp(prefix=f".{root.name}.", suffix=".tmp", dir=root.parent))
    except OSError as exc:
        raise InputError(
            f"cannot write beside {root} ({exc.strerror}); check the folder's permissions"
        ) from exc
    try:
        written = save_deployment(simulation, steps, staging)
        doc["files"] = sorted(set(doc.get("files", [])) | set(written))
        (staging / "design.json").write_text(
            json.dumps(doc, indent=2, allow_nan=False) + "\n", encoding="utf-8"
        )
        for name in [*written, "design.json"]:
            os.replace(staging / name, root / name)
        write_report(root)
    except OSError as exc:
        raise InputError(
            f"cannot write into {root} ({exc.strerror}); check the folder's permissions and "
            "free space"
        ) from exc
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return root


def _read_design(
    root: Path, design_path: Path
) -> tuple[
    dict[str, Any],
    Linkage,
    NDArray[np.float64],
    NDArray[np.float64],
    NDArray[np.int64],
    NDArray[np.int64],
    NDArray[np.int64],
]:
    """What :func:`simulate_folder` reads from a design folder (raises what the readers
    raise on damaged files)."""
    from drawstring.geometry.linkage import Split, build_linkage

    doc = json.loads(design_path.read_text(encoding="utf-8"))
    block = doc.get("linkage", {})
    if "tile_cells" not in block:
        raise InputError(
            f"{design_path} predates 'drawstring simulate'; run drawstring design again"
        )
    grid = tuple(block["grid"])
    cells = np.zeros(grid, dtype=bool)
    tile_cells = np.asarray(block["tile_cells"], dtype=np.int64).reshape(-1, 2)
    cells[tile_cells[:, 0], tile_cells[:, 1]] = True
    splits = tuple(
        Split(s["axis"], int(s["line"]), int(s["lo"]), int(s["hi"]))
        for s in block.get("split_lines", [])
    )
    linkage = build_linkage(cells, splits)
    with np.load(root / "tiles.npz") as stored:
        assembled, fabricated = stored["assembled"], stored["fabricated"]
    hinges = json.loads((root / "hinges.json").read_text(encoding="utf-8"))["hinges"]
    hinge_vertices = np.array([h["vertices"] for h in hinges], dtype=np.int64).reshape(-1, 2)
    route_doc = json.loads((root / "route.json").read_text(encoding="utf-8"))
    steps = np.array(
        [[s["gap"], s["tile"], s["enter_side"], s["leave_side"]] for s in route_doc["steps"]],
        dtype=np.int64,
    ).reshape(-1, 4)
    points = doc.get("metrics", {}).get("lift_points", {}).get("points", [])
    lift_gaps = np.array([p["gap"] for p in points], dtype=np.int64)
    return doc, linkage, assembled, fabricated, hinge_vertices, steps, lift_gaps
