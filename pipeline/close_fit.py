"""``--fit``: the assembled shape as close to the target as every layout target allows.

The paper's eq.-1 weights (planar 1e4, square 10, surface 0.1) keep the tiles square and
planar but let the assembled shape drift off the target.  A closer eq.-1 shape lays out flat
within the 1e-3 mm targets where the co-optimization can keep it *conical* next to the bottom
hinges (there the side face under a hinged edge must bisect its two tiles' dihedral angle, or
the hinge misses in depth); where the close shape is far from conical there, its layout
misses.  So ``close`` (:func:`fitted_layout`), once the paper's shape on the first tiling
has passed the check that refuses a design (:func:`~.shapes.refusing_shape`):

1. solves eq. 1 on the first tiling with ``policy.close_fit``: the surface weight raised and
   the quads' centres and edge midpoints pulled to the target too;
2. where its mean conical defect next to the bottom hinges (:func:`conical_defect_deg`) is
   within ``policy.close_conical_defect_max_deg``, lays the design out on it (co-optimization
   with the paper's surface weight, its conical ladder, tighter tilings, hinges) and keeps it
   when its flat edge error and hinge gap meet the 1e-3 mm targets;
3. otherwise (and where the close shape turns a tile inside out, or with CAD leaves a
   boundary tile too narrow for the string channel) lays out the paper's shape, with a note
   saying why.

``metrics.fit.close`` records the close shape's weights and conical defect and, where it was
laid out, its accuracy (the larger of flat edge error and hinge gap) and its surface distance
over the top faces, kept or not: one point of the fit frontier.

``paper`` is the layout of the paper's weights alone; ``--weights`` overrides both.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from drawstring.geometry.assembled.shape import AssembledResult
from drawstring.geometry.assembled.top import Eq1Weights
from drawstring.geometry.core.errors import ThicknessError
from drawstring.geometry.core.tolerances import FLAT_EDGE_ERROR_TOL_MM, HINGE_GAP_TOL_MM
from drawstring.geometry.core.types import BoolArray, IntArray
from drawstring.geometry.flat.conical import vertex_stars
from drawstring.geometry.flatten.conformal import Flattening
from drawstring.geometry.hinges.sides import dual_hinge_faces
from drawstring.geometry.target.surface import Target
from drawstring.geometry.tiling.grid import Tiling, tile_surface
from drawstring.geometry.tiling.linkage import Linkage
from drawstring.pipeline.cad_stage import FeatureShortfall
from drawstring.pipeline.fit_quality import surface_distances
from drawstring.pipeline.layout_stage import ShapedLayout, shape_and_layout, split_bound
from drawstring.pipeline.policy import LayoutPolicy
from drawstring.pipeline.record import Progress, ResolvedOptions, rounded
from drawstring.pipeline.shapes import FirstCheck, ShapeCache, refusing_shape


def fitted_layout(
    loaded: Target,
    flat_map: Flattening,
    options: ResolvedOptions,
    progress: Progress,
    *,
    policy: LayoutPolicy,
    weights_given: bool,
    check_first: FirstCheck | None = None,
) -> ShapedLayout:
    """Stages tiling to hinges (:func:`~.layout_stage.shape_and_layout`) on the assembled
    shape ``--fit`` asks for; ``weights_given``: ``--weights`` was given, and its eq. 1 is
    laid out whatever ``--fit`` says.  The result's ``fit`` is ``metrics.fit``.

    The design is refused (raising) by :func:`~.shapes.refusing_shape` alone, asked first:
    the first tiling's shape with the paper's weights (or ``--weights``) turning a tile inside
    out, or failing ``check_first`` (with CAD, the boundary channel check).  The retry search
    asks the same, so its ``retry with:`` is not refused again.  The close shape is only
    tried: where it folds or fails ``check_first``, the paper's shape is laid out."""
    paper = Eq1Weights.of(options.weights)
    paper_shapes = ShapeCache()
    with progress.stage("tiling"):
        first_tiling = tile_surface(
            loaded.vertices, loaded.faces, flat_map.uv, tiles=options.tiles, grid=options.grid,
            max_scale_factor=split_bound(options),
        )  # fmt: skip
    refusing_shape(first_tiling, loaded, options, progress, paper_shapes, check_first)
    if options.fit == "paper" or weights_given:
        laid_out = shape_and_layout(
            loaded, flat_map, options, progress, policy=policy, shapes=paper_shapes,
            first_tiling=first_tiling,
        )  # fmt: skip
        used = "weights" if weights_given else "paper"
        return replace(laid_out, fit={"used": used, "eq1": paper.to_json()})
    close = policy.close_fit
    tried: dict[str, Any] = {"eq1": close.to_json()}
    trial, reason = _close_trial(
        loaded, flat_map, options, progress, policy, ShapeCache(close), first_tiling,
        check_first, tried,
    )  # fmt: skip
    if trial is not None:
        return replace(trial, fit={"used": "close", "eq1": close.to_json(), "close": tried})
    laid_out = shape_and_layout(
        loaded, flat_map, options, progress, policy=policy, shapes=paper_shapes,
        first_tiling=first_tiling,
    )  # fmt: skip
    note = (
        f"fit: the close assembled shape (eq. 1 surface weight {close.surface:g}, face samples "
        f"{close.samples:g}) was not kept: {reason}; the paper's weights were used"
    )
    return replace(
        laid_out,
        notes=(*laid_out.notes, note),
        fit={"used": "paper", "eq1": paper.to_json(), "close": {**tried, "refused": reason}},
    )


def _close_trial(
    loaded: Target,
    flat_map: Flattening,
    options: ResolvedOptions,
    progress: Progress,
    policy: LayoutPolicy,
    shapes: ShapeCache,
    first_tiling: Tiling,
    check_first: FirstCheck | None,
    tried: dict[str, Any],
) -> tuple[ShapedLayout | None, str]:
    """The close shape laid out, where it is kept, or None and why not; what was measured on
    the way goes into ``tried``.  What would refuse the paper's shape only sets it aside."""
    try:
        start = refusing_shape(first_tiling, loaded, options, progress, shapes, check_first)
    except ThicknessError:
        return None, "some of its tiles turn inside out at this thickness"
    except FeatureShortfall as short:
        return None, f"its {short}"
    defect = conical_defect_deg(
        start, first_tiling.linkage, options.min_gap_angle_deg, options.hinges
    )
    tried["conical_defect_deg"] = round(defect, 3)
    if defect > policy.close_conical_defect_max_deg:
        return None, (
            f"it is {defect:.1f} deg from conical next to the bottom hinges on average (more "
            f"than {policy.close_conical_defect_max_deg:g}), where they would not meet in depth"
        )
    trial = shape_and_layout(
        loaded, flat_map, options, progress, policy=policy, shapes=shapes,
        first_tiling=first_tiling,
    )  # fmt: skip
    accuracy = trial.accuracy_mm
    distances = surface_distances(trial.assembled.tiles, loaded)
    tried.update(
        accuracy_mm=rounded(accuracy, 9),
        surface_distance_mean_mm=rounded(distances.mean, 9),
        surface_distance_max_mm=rounded(distances.max, 9),
    )
    if accuracy <= min(FLAT_EDGE_ERROR_TOL_MM, HINGE_GAP_TOL_MM) and trial.hinge_layout is not None:
        return trial, ""
    return None, (
        f"its flat tiles met their hinges with their assembled shapes only to {accuracy:.2g} mm"
    )


def bottom_side_edges(linkage: Linkage, quads: IntArray, bottom: BoolArray) -> IntArray:
    """Per assembled vertex, how many of its edges carry a ``bottom`` hinge (at either end).

    A bottom hinge at the end ``v`` of the edge ``v w`` between tiles ``a`` and ``b`` meets in
    depth only when the bottom vertex under ``v`` lies as deep under ``a``'s top face as under
    ``b``'s, on the plane bisecting their dihedral angle; the side face under the edge holds
    that plane's line ``v w`` and the bottom vertex, so it is that bisector."""
    h = linkage.hinges[np.asarray(bottom, dtype=bool)]
    q = np.asarray(quads, dtype=np.int64)
    v = q[h[:, 0], h[:, 1]]
    after = q[h[:, 0], (h[:, 1] + 1) % 4]
    before = q[h[:, 0], (h[:, 1] + 3) % 4]
    w = np.where(np.any(q[h[:, 2]] == after[:, None], axis=1), after, before)
    n = int(q.max()) + 1
    return np.asarray(np.bincount(v, minlength=n) + np.bincount(w, minlength=n))


def conical_defect_deg(
    assembled: AssembledResult, linkage: Linkage, min_gap_angle_deg: float, hinges: str
) -> float:
    """Mean ``|a0 - a1 + a2 - a3|`` (deg) of the assembled top at the regular inner vertices
    with a bottom-hinged edge (the hinge faces as ``dual`` puts them on these tiles), 0 where
    there is none.  The co-optimization makes the top conical there
    (:class:`~drawstring.geometry.flat.conical.VertexStars`) so that the bottom hinges meet
    in depth; the further from conical the start, the further it must move.  At surface
    weight 10 with face samples, 200 tiles, the built-ins whose layout met every target had
    0 (dome), 1.3 (chair) and 3.1 deg (saddle); those that missed in depth 14 (peanut), 16
    (seashell), 26 (wave), 34 (three-shell) and 37 deg (cloud)."""
    if hinges != "dual":
        return 0.0
    faces = dual_hinge_faces(linkage, assembled.tiles, min_gap_angle_deg)
    if not faces.bottom.any():
        return 0.0
    stars = vertex_stars(assembled.quads)
    near = bottom_side_edges(linkage, assembled.quads, faces.bottom)[stars.members[:, 0]] >= 1
    if not near.any():
        return 0.0
    sums, _ = stars.angle_sums(assembled.top)
    return float(np.degrees(np.abs(sums[near])).mean())
