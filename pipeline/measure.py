"""Measurements of a finished design, and the targets it misses.

:func:`measure_design` measures the output geometry (not the optimizers' beliefs) for the
``metrics`` of design.json and lists its *problems* and *warnings*; :func:`cad_problems` and
:func:`cad_warnings` do the same for the solids' measures, :func:`design_rigidity` checks that
the tight string locks the assembled shape.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from drawstring.fabrication.profiles import Profile
from drawstring.geometry.assembled.rigidity import rigidity_report
from drawstring.geometry.assembled.shape import AssembledResult
from drawstring.geometry.core.tile import HingeStrategy
from drawstring.geometry.core.tolerances import (
    CAD_PAD_INTERFERENCE_REL,
    CAPSTAN_FACTOR_WARN,
    FLAT_EDGE_ERROR_TOL_MM,
    FLAT_GAP_ANGLE_TOL_DEG,
    FLAT_INTERPENETRATION_TOL_MM3,
    FLAT_OVERLAP_TOL_MM2,
    HINGE_GAP_TOL_MM,
)
from drawstring.geometry.flat import verify
from drawstring.geometry.flat.layout import FlatResult
from drawstring.geometry.hinges.placement import HingeLayout
from drawstring.geometry.route.lift import LiftPoints
from drawstring.geometry.route.result import Route, route_metrics
from drawstring.geometry.simulate.inputs import route_snap_pairs, route_steps, split_contact_pairs
from drawstring.geometry.target.surface import Target
from drawstring.geometry.tiling.grid import Tiling, parts_in_place
from drawstring.geometry.tiling.linkage import Linkage, gap_centroids
from drawstring.pipeline.fit_quality import (
    fit_warnings,
    surface_distance_metrics,
    surface_distances,
)
from drawstring.pipeline.layout_stage import absorbable_ratio, fabricated_tiles, split_bound
from drawstring.pipeline.record import ResolvedOptions, above, jsonable, rounded

#: Largest distance (mm) between a channel's exit and the next tile's entry, assembled pose.
CHANNEL_MATCH_TOL_MM = 0.05


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


def cad_warnings(measured: dict[str, Any], profile: Profile) -> list[str]:
    """What the solids lack without failing (:func:`~.cad_stage.measure_cad`)."""
    warnings = []
    broken = measured.get("magnet_pockets_breaking_out", 0)
    if broken:
        warnings.append(
            f"{broken} of {measured['magnet_pairs']} magnet pairs have pockets breaking out of "
            "their side faces, so those magnets show and sit loose (the cad notes list the "
            "tiles); use "
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
    closer = measured.get("tile_pairs_closer")
    if closer:
        problems.append(
            f"{closer} pairs of printed tiles come closer than the nozzle width "
            f"({measured['print_clearance_mm']:g} mm; down to {measured['tile_gap_min_mm']} mm): "
            "a slicer would join them and weld their hinges shut (the cad notes name the tiles "
            "left unrelieved)"
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
        "smallest_nonzero_singular_value": rounded(
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
    *,
    target_diagonal_mm: float = 0.0,
    target: Target | None = None,
    fit: dict[str, Any] | None = None,
    top_tried: bool = False,
) -> tuple[dict[str, Any], list[str], list[str]]:
    """Measure the output geometry (not the optimizers' beliefs) and list unmet targets
    (``target_diagonal_mm``: the target's bounding-box diagonal, for the surface distance;
    ``target``: the target as the design approximates it, whose distance from the top faces
    is measured over each face; ``fit``: what ``--fit`` did, ``metrics.fit``; ``top_tried``:
    a layout with every hinge on top was made too, so the warnings do not suggest it).

    Returns the ``metrics`` entries of design.json, the *problems* (targets whose failure makes
    the part unbuildable: overlapping tiles, gaps outside their angle bounds, an invalid route,
    a scale range no layout can absorb) and the *warnings* (accuracy targets not met: the flat
    edge error and the hinge gap, which rigid tiles cannot in general bring to zero because the
    flat linkage is over-determined: 3 degrees of freedom per tile against about 4 hinge
    equations per tile).
    """
    linkage = tiling.linkage
    clash = verify.assembled_overlap(assembled.tiles, linkage)
    flat_pose = _measure_flat(linkage, assembled, hinge_layout)
    channel_turn = channel_turn_assembled(route, assembled.tiles)
    metrics: dict[str, Any] = {
        **_assembled_metrics(assembled.metrics, clash),
        **flat_pose.to_json(),
        "hinges_bottom": int(np.count_nonzero(hinge_layout.bottom)),
        "mass_g": rounded(float(masses.sum()) * 1000.0, 3),
        # top hinges trim every overlapping pair; dual ones only pairs that clear on neither
        # face
        "contact_area_lost_mm2": rounded(hinge_layout.contact_area_lost_mm2, 6),
        "lift_points": lift.to_json(),
        "route": _route_metrics(
            route, tiling, assembled, hinge_layout, flat_pose.fabricated, lift, profile,
            channel_turn,
        ),
    }  # fmt: skip
    if target is not None:  # over every top face, not only the corners (stays in its place)
        metrics.update(surface_distance_metrics(surface_distances(assembled.tiles, target)))
    problems = _shape_problems(clash, flat_pose, options)
    warnings = [
        *_edge_error_warnings(flat_pose),
        *fit_warnings(metrics, target_diagonal_mm, fit, options, top_tried=top_tried),
        *_hinge_gap_warnings(flat_pose, options, top_tried=top_tried),
    ]
    scale_problems, scale_warnings = _scale_findings(
        tiling, options, flat_pose, shape_ok=not problems
    )
    problems.extend(scale_problems)
    warnings.extend(scale_warnings)
    problems.extend(route_problems(route, linkage))
    capstan = float(metrics["route"]["capstan_factor_channels_assembled"])
    warnings.extend(_string_warnings(options, profile, lift, route, channel_turn, capstan))
    return metrics, problems, warnings


def _assembled_metrics(measured: dict[str, Any], clash: verify.AssembledOverlap) -> dict[str, Any]:
    """design.json's metrics of the assembled tiles: the assembled stage's own measures
    (``measured``) and how far the tiles clash (``clash``)."""
    metrics: dict[str, Any] = {
        key: rounded(float(measured[key]), 9)
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
        if key in measured
    }
    metrics.update(
        {k: rounded(v, 9) if isinstance(v, float) else v for k, v in clash.to_json().items()}
    )
    return metrics


@dataclass(frozen=True)
class _FlatPose:
    """The flat tiles (after the hinge layout) as measured: how they overlap, how far they are
    from the assembled tiles' shapes, how their gaps open and how their hinges meet."""

    overlap_area_mm2: float
    interpenetration_mm3: float
    edge_error_mm: float
    #: (G,) each slit end's opening angle, measured on the face that carries its hinge
    gap_angles_deg: NDArray[np.float64]
    #: the whole hinge gap, and the one seen from above
    hinge_gap_mm: float
    hinge_gap_in_plane_mm: float
    merge_shift_mm: float
    #: (T, 8, 3) the tiles as fabricated (:func:`~.layout_stage.fabricated_tiles`)
    fabricated: NDArray[np.float64]

    def to_json(self) -> dict[str, float]:
        """The ``flat_*`` and ``hinge_gap_*`` metrics of design.json."""
        angles = self.gap_angles_deg
        return {
            "flat_overlap_area_mm2": rounded(self.overlap_area_mm2, 9),
            "flat_interpenetration_mm3": rounded(self.interpenetration_mm3, 9),
            "flat_edge_error_max_mm": rounded(self.edge_error_mm, 9),
            "flat_gap_angle_min_deg": rounded(float(angles.min(initial=90.0)), 6),
            "flat_gap_angle_max_deg": rounded(float(angles.max(initial=0.0)), 6),
            "hinge_gap_max_mm": rounded(self.hinge_gap_mm, 9),
            "hinge_gap_in_plane_max_mm": rounded(self.hinge_gap_in_plane_mm, 9),
            # flat.obj holds the merged tiles: how far merging moved a vertex off its rigid
            # copy of the assembled tile (about the largest hinge gap at most: a pair merges at
            # its midpoint moved sideways onto the plane that separates its tiles)
            "flat_merge_shift_max_mm": rounded(self.merge_shift_mm, 9),
        }


def _measure_flat(
    linkage: Linkage, assembled: AssembledResult, hinge_layout: HingeLayout
) -> _FlatPose:
    """The flat pose of ``hinge_layout`` measured against the ``assembled`` tiles."""
    tiles_2d = hinge_layout.tiles
    top_2d = tiles_2d[:, :4, :2]
    _, overlapping, areas = verify.flat_overlap(top_2d)
    # A trimmed pair's top faces overlap only inside its trim (the tops are coplanar in the
    # flat pose and the trim is the pair's whole 3D overlap); the interpenetration after the
    # trims below checks that independently.
    trimmed_pairs = {(trim.other, trim.tile) for trim in hinge_layout.trims}
    kept = [k for k, (a, b) in enumerate(overlapping.tolist()) if (a, b) not in trimmed_pairs]
    trims = [(trim.tile, trim.vertices) for trim in hinge_layout.trims]
    volume, _, _ = verify.interpenetration(tiles_2d, trims=trims)
    edge_error = float(verify.flat_edge_errors(top_2d, assembled.tiles[:, :4]).max(initial=0.0))
    # Hinge gap measured on the tiles as fabricated (rigid copies of T3D, before merging).
    fabricated = fabricated_tiles(hinge_layout, assembled.tiles)
    gaps = verify.hinge_gaps(fabricated, hinge_layout.hinge_vertices)
    in_plane = verify.hinge_gaps(fabricated, hinge_layout.hinge_vertices, in_plane=True)
    return _FlatPose(
        overlap_area_mm2=float(areas[kept].sum()),
        interpenetration_mm3=volume,
        edge_error_mm=edge_error,
        gap_angles_deg=verify.gap_opening_angles_deg(linkage, tiles_2d, hinge_layout.bottom),
        hinge_gap_mm=float(gaps.max(initial=0.0)),
        hinge_gap_in_plane_mm=float(in_plane.max(initial=0.0)),
        merge_shift_mm=float(
            np.linalg.norm(hinge_layout.tiles - fabricated, axis=2).max(initial=0.0)
        ),
        fabricated=fabricated,
    )


def _route_metrics(
    route: Route,
    tiling: Tiling,
    assembled: AssembledResult,
    hinge_layout: HingeLayout,
    fabricated: NDArray[np.float64],
    lift: LiftPoints,
    profile: Profile,
    channel_turn: float,
) -> dict[str, Any]:
    """design.json's ``metrics.route``: the planned route's measures, the string's length
    along its channels and how much the channels bend in the assembled pose (``channel_turn``,
    :func:`channel_turn_assembled`)."""
    linkage = tiling.linkage
    assembled_gaps = gap_centroids(linkage, assembled.tiles[:, :4])
    flat_gaps = gap_centroids(
        linkage, parts_in_place(linkage, hinge_layout.tiles[:, :4, :2], tiling.uv)
    )
    block: dict[str, Any] = jsonable(
        route_metrics(route, linkage, flat_gaps, assembled_gaps, profile.friction_coefficient)
    )
    # the string's length along its channels on the fabricated tiles, as every other output
    # reports it (not the planning polyline through the gap centres)
    from drawstring.cad.paths import route_lengths
    from drawstring.pipeline.cad_stage import lift_exits, route_steps

    flat_length, assembled_length = route_lengths(
        fabricated, assembled.tiles, route_steps(route), lift_exits(route, lift.lift_gaps)
    )
    block["length_mm"] = {"flat": flat_length, "assembled": assembled_length}
    block["turn_angle_channels_assembled_rad"] = rounded(channel_turn, 6)
    block["capstan_factor_channels_assembled"] = rounded(
        math.exp(profile.friction_coefficient * channel_turn), 6
    )
    return block


def _shape_problems(
    clash: verify.AssembledOverlap, flat_pose: _FlatPose, options: ResolvedOptions
) -> list[str]:
    """Problems of the tiles' shapes: folded or clashing assembled tiles, overlapping flat
    tiles, gaps that open outside their angle bounds."""
    problems = []
    folded = len(clash.nonconvex_top) + len(clash.nonconvex_bottom)
    if folded:
        problems.append(f"{folded} assembled tile faces are folded (non-convex)")
    if clash.depth_max_mm > verify.ASSEMBLED_OVERLAP_DEPTH_TOL_MM:
        problems.append(
            f"assembled tiles interpenetrate up to {clash.depth_max_mm:.3g} mm "
            f"({len(clash.pairs)} pairs)"
        )
    overlap_area, volume = flat_pose.overlap_area_mm2, flat_pose.interpenetration_mm3
    if overlap_area > FLAT_OVERLAP_TOL_MM2:
        problems.append(f"flat tiles overlap by {overlap_area:.3g} mm^2")
    if volume > FLAT_INTERPENETRATION_TOL_MM3:
        problems.append(f"flat tiles interpenetrate by {volume:.3g} mm^3")
    angles = flat_pose.gap_angles_deg
    low = options.min_gap_angle_deg - FLAT_GAP_ANGLE_TOL_DEG
    if angles.size and (angles.min() < low or angles.max() > 90 + FLAT_GAP_ANGLE_TOL_DEG):
        problems.append(
            f"gap angles {angles.min():.2f}..{angles.max():.2f} deg leave "
            f"[{options.min_gap_angle_deg:g}, 90]"
        )
    return problems


def _edge_error_warnings(flat_pose: _FlatPose) -> list[str]:
    """A warning where the flat tiles miss the assembled tiles' shapes (the flat edge error)."""
    edge_error = flat_pose.edge_error_mm
    if edge_error <= FLAT_EDGE_ERROR_TOL_MM:
        return []
    return [
        f"flat edge error {above(edge_error, FLAT_EDGE_ERROR_TOL_MM)} mm exceeds "
        f"{FLAT_EDGE_ERROR_TOL_MM:g} mm: a "
        "curved target's tiles cannot all keep their assembled shape with every hinge "
        "meeting in the plane; the printed tiles are exact copies of the assembled ones, "
        "and more tiles shrink the error"
    ]


def _hinge_gap_warnings(
    flat_pose: _FlatPose, options: ResolvedOptions, *, top_tried: bool
) -> list[str]:
    """A warning where the hinged corners of the fabricated tiles do not meet, with its cause
    and what closes it (not top hinges where ``top_tried``)."""
    hinge_gap, in_plane_gap = flat_pose.hinge_gap_mm, flat_pose.hinge_gap_in_plane_mm
    if hinge_gap <= HINGE_GAP_TOL_MM:
        return []
    if in_plane_gap <= HINGE_GAP_TOL_MM:
        cause = (
            f"seen from above the hinges meet to {in_plane_gap:.2g} mm; the rest is the "
            "tiles' thickness difference at bottom hinges (the quad mesh is not conical)"
        )
        if not top_tried:
            cause += "; --hinges top puts every hinge on the top faces, where it closes"
    elif not options.co_optimize:
        cause = (
            "without the co-optimization (--no-co-optimize) the flat layout only "
            "approximates the assembled tiles; drop that option to close it"
        )
    elif options.hinges == HingeStrategy.DUAL and not top_tried:
        cause = "more tiles shrink it, and --hinges top reaches 1e-3 mm on most built-ins"
    else:
        cause = "more tiles shrink it"
    return [
        f"hinge gap {above(hinge_gap, HINGE_GAP_TOL_MM)} mm exceeds {HINGE_GAP_TOL_MM:g} mm: "
        f"{cause}"
    ]


def _scale_findings(
    tiling: Tiling, options: ResolvedOptions, flat_pose: _FlatPose, *, shape_ok: bool
) -> tuple[list[str], list[str]]:
    """A problem (or, where the flat layout keeps its gaps and meets its targets anyway, a
    warning) for a part whose area scale exceeds the split bound; ``shape_ok``: the tiles'
    shapes have no problem (:func:`_shape_problems`)."""
    bound = split_bound(options)
    if tiling.scale_factor_max <= bound:
        return [], []
    absorbable = absorbable_ratio(options.min_gap_angle_deg)
    if options.max_scale_factor < absorbable:
        bound_fix = f"a --max-scale-factor up to {absorbable:.3g}"
    else:
        bound_fix = "a smaller --min-gap-angle (the bound is 2 / (1 + sin of it))"
    excess = (
        f"scale factor {tiling.scale_factor_max:.3f} exceeds {bound:.6g} "
        "in a part no split can divide (see the notes)"
    )
    fixes = (
        "use more tiles, which gives splits more places to go, other --corners, "
        f"{bound_fix} or a flatter target"
    )
    # The bound predicts gaps the flat layout cannot keep within their angles; it is read
    # off the target's conformal map, not the assembled tiles.  Where the flat layout,
    # measured, keeps every gap within its bounds and meets its targets, it is a warning.
    angles = flat_pose.gap_angles_deg
    layout_met = (
        shape_ok
        and angles.size > 0
        and flat_pose.edge_error_mm <= FLAT_EDGE_ERROR_TOL_MM
        and flat_pose.hinge_gap_in_plane_mm <= HINGE_GAP_TOL_MM
    )
    if not layout_met:
        return [f"{excess}; {fixes}"], []
    return [], [
        f"{excess}, yet the flat layout keeps every gap within "
        f"[{options.min_gap_angle_deg:g}, 90] deg ({angles.min():.1f}.."
        f"{angles.max():.1f}) and meets its targets in the plane (the bound is read "
        f"off the target's conformal map, not the tiles); if it does not deploy, {fixes}"
    ]


def _string_warnings(
    options: ResolvedOptions,
    profile: Profile,
    lift: LiftPoints,
    route: Route,
    channel_turn: float,
    capstan: float,
) -> list[str]:
    """Warnings on the part as made and pulled: a size the profile does not suit, channels
    that bend so much (``channel_turn``, rad, giving the ``capstan`` factor) that the pull may
    not close the far tiles, lift gaps the string cannot reach."""
    warnings = []
    if not profile.size_min_mm <= options.size_mm <= profile.size_max_mm:
        warnings.append(
            f"--size {options.size_mm:g} mm is outside the {profile.size_min_mm:g}-"
            f"{profile.size_max_mm:g} mm that the {profile.name} profile suits (its tile "
            "thickness, hinge parts and machine are made for that range); choose a profile "
            "for this size (drawstring profiles --size ...) or a size within it"
        )
    if capstan > CAPSTAN_FACTOR_WARN:
        warnings.append(
            f"the string's channels bend {channel_turn:.3g} rad in all, so with friction "
            f"{profile.friction_coefficient:g} the pull needs {capstan:.3g} times the tension "
            f"that reaches the far end (over {CAPSTAN_FACTOR_WARN:g}): the far tiles may not "
            "close; a slicker string and channel (a profile with a lower "
            "friction_coefficient) lowers it"
        )
    if len(route.lifts_missed):
        missed = route.lifts_missed.tolist()
        if len(missed) < len(lift.lift_gaps):
            pull = "pull at the other lift points"
        else:
            pull = (
                "no lift point is left to pull at; more tiles or other --corners give the "
                "route other ways"
            )
        warnings.append(
            f"the string route cannot reach lift gap(s) {missed} under the routing rules; {pull}"
        )
    return warnings


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
