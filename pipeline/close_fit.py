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
3. otherwise, with ``--hinges`` left unset, lays out the closer shape of
   ``policy.close_fit_top`` (square weight lowered, surface and face samples raised) with
   every hinge on the top faces, which ask nothing of the shape in depth, and keeps it when it
   meets the 1e-3 mm targets; where it is not kept (a tile of it turns inside out, or its
   layout misses), the shape of step 1 with top hinges (``--hinges top`` lays out these two
   as the close ones);
4. otherwise lays out the shapes of ``policy.close_fit_rungs``, between the close ones and
   the paper's (the surface weight stepped down), closest first, with the hinges of step 3
   (top where ``--hinges`` is unset), and keeps the first that meets the 1e-3 mm targets;
5. otherwise (and where every one of those turns a tile inside out, or with CAD leaves tiles
   too small for the profile's features) lays out the paper's shape, with a note saying
   why.

A close design's assembled shape is moved rigidly onto the target (:func:`rigidly_fitted`)
where that lowers its mean distance and not its largest, and it is kept only where its top
faces then sit no farther from the target, on average and at most, than the paper's shape's.
A top-hinged close design that misses the fit level while its eq.-1 shape sits near it is laid
out again with the co-optimization pulling it to the target (:meth:`_CloseTrial.pulled_layout`),
each such layout then polished on its own tiling with a tenth of that pull
(:meth:`_CloseTrial.polished`), and kept only where it meets the 1e-3 mm targets and sits
closer.

``metrics.fit.close`` (and ``close_top``) records the close shape's weights and conical defect
and, where it was laid out, its accuracy (the larger of flat edge error and hinge gap), its
rigid fit's move and its surface distance over the top faces, kept or not: one point of the
fit frontier.

``paper`` is the layout of the paper's weights alone; ``--weights`` overrides both.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from drawstring.geometry.assembled.fit import TopFaceDistances, rigid_fit
from drawstring.geometry.assembled.shape import AssembledResult
from drawstring.geometry.assembled.top import Eq1Weights
from drawstring.geometry.core.errors import ThicknessError
from drawstring.geometry.core.tile import HingeStrategy
from drawstring.geometry.core.tolerances import (
    FLAT_EDGE_ERROR_TOL_MM,
    HINGE_GAP_TOL_MM,
)
from drawstring.geometry.core.types import BoolArray, IntArray
from drawstring.geometry.flat.conical import vertex_stars
from drawstring.geometry.flatten.conformal import Flattening
from drawstring.geometry.hinges.sides import dual_hinge_faces
from drawstring.geometry.target.surface import Target
from drawstring.geometry.tiling.grid import Tiling, tile_surface
from drawstring.geometry.tiling.linkage import Linkage
from drawstring.pipeline.cad_stage import FeatureShortfall
from drawstring.pipeline.fit_quality import meets_fit_level, surface_distances
from drawstring.pipeline.layout_stage import (
    ShapedLayout,
    shape_and_layout,
    shape_on_tiling,
    split_bound,
)
from drawstring.pipeline.policy import LayoutPolicy
from drawstring.pipeline.record import Progress, ResolvedOptions, rounded
from drawstring.pipeline.shapes import FirstCheck, ShapeCache, mesh_key, refusing_shape


def fitted_layout(
    loaded: Target,
    flat_map: Flattening,
    options: ResolvedOptions,
    progress: Progress,
    *,
    policy: LayoutPolicy,
    weights_given: bool,
    check_first: FirstCheck | None = None,
    top_allowed: bool = False,
    refused: dict[str, Any] | None = None,
) -> tuple[ShapedLayout, ResolvedOptions]:
    """Stages tiling to hinges (:func:`~.layout_stage.shape_and_layout`) on the assembled
    shape ``--fit`` asks for; ``weights_given``: ``--weights`` was given, and its eq. 1 is
    laid out whatever ``--fit`` says; ``top_allowed``: ``--hinges`` was left unset, so a close
    shape refused with dual hinges is laid out with top hinges before the paper's shape;
    ``refused``: the ``metrics.fit`` of an earlier call on this design whose close shapes were
    all refused (none is laid out again).  Returns the layout and the options it was made
    with (top hinges where the close shape was kept with them); the layout's ``fit`` is
    ``metrics.fit``.

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
    paper_start = refusing_shape(first_tiling, loaded, options, progress, paper_shapes, check_first)
    if options.fit == "paper" or weights_given or refused is not None:
        laid_out = shape_and_layout(
            loaded, flat_map, options, progress, policy=policy, shapes=paper_shapes,
            first_tiling=first_tiling,
        )  # fmt: skip
        if refused is not None:
            return replace(laid_out, fit=refused), options
        used = "weights" if weights_given else "paper"
        return replace(laid_out, fit={"used": used, "eq1": paper.to_json()}), options
    with progress.stage("assembled"):
        paper_distances = surface_distances(paper_start.tiles, loaded)
    trial = _CloseTrial(loaded, flat_map, progress, policy, first_tiling, check_first)
    kept, close, tried, reason = _first_kept(trial, options, paper_distances)
    if kept is not None:
        return replace(kept, fit={"used": "close", "eq1": close.to_json(), "close": tried}), options
    fit: dict[str, Any] = {
        "used": "paper",
        "eq1": paper.to_json(),
        "close": {**tried, "refused": reason},
    }
    notes = [
        f"fit: the close assembled shape (eq. 1 surface weight {close.surface:g}, face samples "
        f"{close.samples:g}) was not kept: {reason}"
    ]
    if top_allowed and options.hinges == HingeStrategy.DUAL:
        top_options = replace(options, hinges=HingeStrategy.TOP)
        kept, top, top_tried, top_reason = _first_kept(trial, top_options, paper_distances)
        if kept is not None:
            note = (
                f"{notes[0]}; with every hinge on the top faces (no depth condition) the close "
                f"shape of eq. 1 weights square {top.square:g}, surface {top.surface:g}, face "
                f"samples {top.samples:g} keeps every layout target, so the design has top "
                "hinges (--hinges dual keeps the bottom ones, --fit paper the paper's shape)"
            )
            return replace(
                kept,
                notes=(*kept.notes, note),
                fit={**fit, "used": "close", "eq1": top.to_json(), "close_top": top_tried},
            ), top_options
        fit["close_top"] = {**top_tried, "refused": top_reason}
        notes.append(f"with top hinges the close shape was not kept either: {top_reason}")
        options_between = top_options
    else:
        options_between = options
    between = _between(trial, options_between, paper_distances, fit, notes)
    if between is not None:
        return between
    laid_out = shape_and_layout(
        loaded, flat_map, options, progress, policy=policy, shapes=paper_shapes,
        first_tiling=first_tiling,
    )  # fmt: skip
    return _closer_of_two(laid_out, trial, options, fit, notes)


def _between(
    trial: _CloseTrial,
    options: ResolvedOptions,
    paper: TopFaceDistances,
    fit: dict[str, Any],
    notes: list[str],
) -> tuple[ShapedLayout, ResolvedOptions] | None:
    """The first shape of ``policy.close_fit_rungs`` (between the close ones and the paper's)
    kept with ``options``, as :func:`fitted_layout` returns it, or None, with why in ``fit``
    (``between``) and ``notes``."""
    if not trial.policy.close_fit_rungs:
        return None
    kept, rung, tried, reason = _first_kept(trial, options, paper, trial.policy.close_fit_rungs)
    if kept is None:
        fit["between"] = {**tried, "refused": reason}
        notes.append(f"nor a shape between it and the paper's: {reason}")
        return None
    note = (
        f"{'; '.join(notes)}; the shape of eq. 1 weights square {rung.square:g}, surface "
        f"{rung.surface:g}, face samples {rung.samples:g}, between the close one and the "
        f"paper's, keeps every layout target with {options.hinges} hinges, so the design has "
        "it (--fit paper keeps the paper's shape)"
    )
    return replace(
        kept,
        notes=(*kept.notes, note),
        fit={**fit, "used": "close", "eq1": rung.to_json(), "between": tried},
    ), options


def _closer_of_two(
    laid_out: ShapedLayout,
    trial: _CloseTrial,
    options: ResolvedOptions,
    fit: dict[str, Any],
    notes: list[str],
) -> tuple[ShapedLayout, ResolvedOptions]:
    """The paper's design ``laid_out``, or a close shape set aside on the first tiling's
    distances (:meth:`_CloseTrial.closer_than`) where it sits no farther from the target than
    this laid-out paper design, on average and at most: the paper's shape moves in its own
    layout too, and the comparison of the two designs is the one that counts."""
    with trial.progress.stage("assembled"):
        paper = surface_distances(laid_out.assembled.tiles, trial.loaded)
    fit["paper_laid_out"] = {
        "surface_distance_mean_mm": rounded(paper.mean, 9),
        "surface_distance_max_mm": rounded(paper.max, 9),
    }
    closer = trial.closer_than(paper)
    if closer is None:
        note = "; ".join(notes) + "; the paper's weights were used"
        return replace(laid_out, notes=(*laid_out.notes, note), fit=fit), options
    kept, weights, kept_options, distances = closer
    note = (
        f"fit: the close shape of eq. 1 weights square {weights.square:g}, surface "
        f"{weights.surface:g}, face samples {weights.samples:g} with {kept_options.hinges} "
        f"hinges sits {distances.mean:.2f} mm from the target on average and up to "
        f"{distances.max:.2f} mm, no farther than the paper's laid-out design ({paper.mean:.2f} "
        f"and {paper.max:.2f} mm), so it is kept (--fit paper keeps the paper's shape)"
    )
    fit.update(used="close", eq1=weights.to_json())
    return replace(kept, notes=(*kept.notes, note), fit=fit), kept_options


def close_weights(hinges: str, policy: LayoutPolicy) -> tuple[Eq1Weights, ...]:
    """The eq.-1 weights of the close shapes tried with ``hinges``, closest first:
    ``policy.close_fit`` with dual hinges, whose bottom hinges ask the shape to stay near
    conical; with every hinge on top the closer ``policy.close_fit_top``, then
    ``policy.close_fit`` where that one is not kept."""
    if hinges == HingeStrategy.TOP and policy.close_fit_top != policy.close_fit:
        return (policy.close_fit_top, policy.close_fit)
    if hinges == HingeStrategy.TOP:
        return (policy.close_fit_top,)
    return (policy.close_fit,)


def _first_kept(
    trial: _CloseTrial,
    options: ResolvedOptions,
    paper: TopFaceDistances,
    ladder: tuple[Eq1Weights, ...] | None = None,
) -> tuple[ShapedLayout | None, Eq1Weights, dict[str, Any], str]:
    """The first shape of ``ladder`` (the close shapes of :func:`close_weights` for
    ``options``' hinges) that is kept: the layout (None where none is), its weights, what was
    measured on it and why it was not kept (empty where it was).  Shapes set aside before it
    are listed in the measures' ``earlier`` (their ``eq1`` and why)."""
    earlier: list[dict[str, Any]] = []
    for weights in close_weights(options.hinges, trial.policy) if ladder is None else ladder:
        tried: dict[str, Any] = {"eq1": weights.to_json()}
        if earlier:
            tried["earlier"] = list(earlier)
        kept, reason = trial.laid_out(options, weights, paper, tried)
        if kept is not None:
            return kept, weights, tried, ""
        earlier.append({"eq1": weights.to_json(), "refused": reason})
    return None, weights, tried, reason


class _CloseTrial:
    """The close shapes of one design laid out on its first tiling, kept or not."""

    def __init__(
        self,
        loaded: Target,
        flat_map: Flattening,
        progress: Progress,
        policy: LayoutPolicy,
        first_tiling: Tiling,
        check_first: FirstCheck | None,
    ) -> None:
        self.loaded, self.flat_map, self.progress = loaded, flat_map, progress
        self.policy, self.first_tiling, self.check_first = policy, first_tiling, check_first
        #: close shapes whose layout met the 1e-3 mm targets but that were set aside for
        #: sitting no closer than the paper's shape on the first tiling: their layout, weights,
        #: options and distances (:meth:`closer_than`)
        self.set_aside: list[tuple[ShapedLayout, Eq1Weights, ResolvedOptions, TopFaceDistances]]
        self.set_aside = []

    def laid_out(
        self,
        options: ResolvedOptions,
        weights: Eq1Weights,
        paper: TopFaceDistances,
        tried: dict[str, Any],
    ) -> tuple[ShapedLayout | None, str]:
        """The close shape of eq.-1 ``weights`` laid out with ``options``, where it is kept,
        or None and why not; what was measured on the way goes into ``tried``.  What would
        refuse the paper's shape only sets it aside.  It is kept where its flat edge error and
        hinge gap meet the 1e-3 mm targets and its top faces sit no further from the target,
        on average and at most, than those of the paper's shape (``paper``: their distances
        on the first tiling, before its layout)."""
        loaded, progress, policy = self.loaded, self.progress, self.policy
        shapes = ShapeCache(weights)
        try:
            start = refusing_shape(
                self.first_tiling, loaded, options, progress, shapes, self.check_first
            )
        except ThicknessError:
            return None, "some of its tiles turn inside out at this thickness"
        except FeatureShortfall as short:
            return None, f"its {short}"
        # only bottom hinges ask the shape to be conical
        dual = options.hinges == HingeStrategy.DUAL
        defect = conical_defect_deg(
            start, self.first_tiling.linkage, options.min_gap_angle_deg, options.hinges
        )
        if dual:
            tried["conical_defect_deg"] = round(defect, 3)
        if dual and defect > policy.close_conical_defect_max_deg:
            return None, (
                f"it is {defect:.1f} deg from conical next to the bottom hinges on average "
                f"(more than {policy.close_conical_defect_max_deg:g}), where they would not "
                "meet in depth"
            )
        trial = shape_and_layout(
            loaded, self.flat_map, options, progress, policy=policy, shapes=shapes,
            first_tiling=self.first_tiling,
        )  # fmt: skip
        accuracy = trial.accuracy_mm
        trial, distances, move = rigidly_fitted(trial, loaded)
        tried.update(_measures(accuracy, distances, move))
        if accuracy > min(FLAT_EDGE_ERROR_TOL_MM, HINGE_GAP_TOL_MM) or trial.hinge_layout is None:
            return None, (
                f"its flat tiles met their hinges with their assembled shapes only to "
                f"{accuracy:.2g} mm"
            )
        if distances.mean > paper.mean or distances.max > paper.max:
            self.set_aside.append((trial, weights, options, distances))
            return None, (
                f"its tiles sit {distances.mean:.2f} mm from the target on average and up to "
                f"{distances.max:.2f} mm, no closer than the paper's shape ({paper.mean:.2f} "
                f"and {paper.max:.2f} mm)"
            )
        if options.hinges == HingeStrategy.TOP and not meets_fit_level(
            trial.assembled.tiles, distances, loaded
        ):
            # laid out again only where its eq.-1 shape itself is near the fit level
            near = meets_fit_level(
                start.tiles, surface_distances(start.tiles, loaded), loaded,
                policy.close_fit_top_pull_within,
            )  # fmt: skip
            if near:
                trial = self.pulled_layout(trial, distances, options, shapes, tried)
            else:
                tried["co_surface"] = {"refused": "its eq.-1 shape is far from the fit level"}
        return trial, ""

    def pulled_layout(
        self,
        first: ShapedLayout,
        distances: TopFaceDistances,
        options: ResolvedOptions,
        shapes: ShapeCache,
        tried: dict[str, Any],
    ) -> ShapedLayout:
        """The close shape laid out again with the co-optimization pulling it to the target
        too (``policy.close_fit_top_co``), a pass whose co-optimization was used then polished
        (:meth:`polished`), kept in place of ``first`` (its top faces at ``distances``) where
        it meets the 1e-3 mm targets and sits closer to the target on average and no farther
        at most; while the kept one misses the fit level (and was not polished), laid out so
        again from its own assembled shape, up to ``policy.close_fit_top_passes`` times.
        A pass whose co-optimization is refused (folding a tile: ``policy.co_required``,
        at its first such round) is not laid out further nor kept: it would be the plain
        layout of the shape it started from.  ``tried`` gets the measures of each pass as
        ``co_surface`` (each with its polish's, and the kept layout's; a refused one's
        reason)."""
        weights = self.policy.close_fit_top_co
        policy = replace(self.policy, co_surface=weights, co_required=True)
        record: dict[str, Any] = {"surface": weights[0], "face_samples": weights[1]}
        record["paper_co"] = {k: tried[k] for k in _MEASURED}
        record["passes"] = passes = []
        tried["co_surface"] = record
        kept, near = first, distances
        for _ in range(self.policy.close_fit_top_passes):
            if kept is not first:  # from the shape the last pass kept, on every tiling
                shapes = _seeded(shapes, self.first_tiling, kept.assembled)
            trial = shape_and_layout(
                self.loaded, self.flat_map, options, self.progress, policy=policy,
                shapes=shapes, first_tiling=self.first_tiling,
            )  # fmt: skip
            if not trial.co_block["accepted"]:  # (``co_required``: laid out no further)
                reason = trial.co_block["reason"]
                passes.append({"refused": f"co-optimization not used: {reason}", "kept": False})
                break
            accuracy = trial.accuracy_mm
            trial, closer, move = rigidly_fitted(trial, self.loaded)
            measured = _measures(accuracy, closer, move)
            entry: dict[str, Any] = dict(measured)
            if trial.co_block.get("accepted"):
                trial, accuracy, closer, entry["polish"] = self.polished(
                    trial, accuracy, closer, options, shapes
                )
                if entry["polish"]["kept"]:
                    measured = {k: entry["polish"][k] for k in _MEASURED}
            better = (
                trial.hinge_layout is not None
                and accuracy <= _TOL_MM
                and closer.mean < near.mean
                and closer.max <= near.max
            )
            passes.append({**entry, "kept": better})
            if not better:
                break
            kept, near = trial, closer
            tried.update(measured)
            polished = bool(entry.get("polish", {}).get("kept"))
            if (
                meets_fit_level(kept.assembled.tiles, near, self.loaded)
                or polished
                or _same_parts(kept.tiling, self.first_tiling)
            ):
                # (on the first tiling's parts, or polished on its own, the kept shape is laid
                # out congruently already: the next layout ends on that tiling, its joint
                # solve from those tiles ends above their plain layout and is refused, and the
                # design would be this one again: the 160 mm seashell's did)
                break
        record["kept"] = kept is not first
        return kept

    def polished(
        self,
        pulled: ShapedLayout,
        accuracy: float,
        distances: TopFaceDistances,
        options: ResolvedOptions,
        shapes: ShapeCache,
    ) -> tuple[ShapedLayout, float, TopFaceDistances, dict[str, Any]]:
        """A pulled layout (its ``accuracy`` and its top faces' ``distances``) laid out once
        more on its own tiling from its own assembled shape, the co-optimization's pull lowered
        to ``policy.close_fit_top_polish``: from tiles that nearly fold flat already, the joint
        solve's balance between the pull and the flat congruence sits lower, so the tiles come
        back within the 1e-3 mm targets while the shape moves little (and, pulled still, moves
        closer).  The polished layout, its accuracy and distances, and its measures with
        ``kept``, where it meets the targets and either ``pulled`` misses them or it sits
        closer on average and no farther at most; else ``pulled``'s."""
        policy = replace(self.policy, co_surface=self.policy.close_fit_top_polish)
        trial = shape_on_tiling(
            pulled.tiling, pulled.split_bound, self.loaded, options, self.progress,
            policy=policy, shapes=_seeded(shapes, pulled.tiling, pulled.assembled),
        )  # fmt: skip
        polished = trial.accuracy_mm
        trial, closer, move = rigidly_fitted(trial, self.loaded)
        measured = _measures(polished, closer, move)
        kept = (
            trial.hinge_layout is not None
            and polished <= _TOL_MM
            and (
                accuracy > _TOL_MM
                or pulled.hinge_layout is None
                or (closer.mean < distances.mean and closer.max <= distances.max)
            )
        )
        measured["kept"] = kept
        if not kept:
            return pulled, accuracy, distances, measured
        lowered = self.policy.close_fit_top_polish[0]
        note = (
            f"fit: the layout pulled to the target met its hinges to {accuracy:.2g} mm and sat "
            f"{distances.mean:.2f} mm from it on average; laid out again on its own tiling from "
            f"its own shape with the pull lowered to {lowered:g}, {polished:.2g} mm "
            f"and {closer.mean:.2f} mm"
        )
        # the tiling's story (tighter splits tried) is the pulled layout's
        return replace(trial, notes=(*pulled.notes, note)), polished, closer, measured

    def closer_than(
        self, paper: TopFaceDistances
    ) -> tuple[ShapedLayout, Eq1Weights, ResolvedOptions, TopFaceDistances] | None:
        """Of the shapes set aside, the one nearest the target on average among those that sit
        no farther, on average and at most, than ``paper`` (the paper's laid-out design)."""
        closer = [c for c in self.set_aside if c[3].mean <= paper.mean and c[3].max <= paper.max]
        return min(closer, key=lambda c: c[3].mean, default=None)


def rigidly_fitted(
    laid_out: ShapedLayout, loaded: Target
) -> tuple[ShapedLayout, TopFaceDistances, float]:
    """``laid_out`` with its assembled shape moved rigidly closer to the target
    (:func:`~drawstring.geometry.assembled.fit.rigid_fit`) where that lowers the mean distance
    of its top faces and not their largest, its top faces' distances from the target, and the
    largest move of a vertex (mm; 0 where it stays).  A rigid motion of the whole assembled
    shape keeps every tile's shape and every hinge: the flat layout, the hinges and the
    accuracy are those of ``laid_out``."""
    assembled = laid_out.assembled
    before = surface_distances(assembled.tiles, loaded)
    rotation, shift = rigid_fit(assembled.tiles, loaded.vertices, loaded.faces)
    top = assembled.top @ rotation.T + shift
    bottom = assembled.bottom @ rotation.T + shift
    tiles = assembled.tiles @ rotation.T + shift
    after = surface_distances(tiles, loaded)
    if not (after.mean < before.mean and after.max <= before.max):
        return laid_out, before, 0.0
    for array in (top, bottom, tiles):
        array.flags.writeable = False
    moved = replace(assembled, top=top, bottom=bottom, tiles=tiles)
    move = float(np.linalg.norm(tiles - assembled.tiles, axis=2).max())
    return replace(laid_out, assembled=moved), after, move


#: The accuracy figure (the larger of flat edge error and hinge gap, mm) a layout must meet.
_TOL_MM = min(FLAT_EDGE_ERROR_TOL_MM, HINGE_GAP_TOL_MM)

#: The measures of a laid-out close shape in ``metrics.fit`` (:func:`_measures`).
_MEASURED = (
    "rigid_fit_move_max_mm",
    "accuracy_mm",
    "surface_distance_mean_mm",
    "surface_distance_max_mm",
)


def _measures(accuracy: float, distances: TopFaceDistances, move: float) -> dict[str, Any]:
    """A laid-out close shape's accuracy (mm), its top faces' distances from the target and
    its rigid fit's largest move, as ``metrics.fit`` records them."""
    return {
        "rigid_fit_move_max_mm": rounded(move, 6),
        "accuracy_mm": rounded(accuracy, 9),
        "surface_distance_mean_mm": rounded(distances.mean, 9),
        "surface_distance_max_mm": rounded(distances.max, 9),
    }


def _seeded(shapes: ShapeCache, tiling: Tiling, assembled: AssembledResult) -> ShapeCache:
    """A shape cache with ``assembled`` as the shape of ``tiling``'s quad mesh (which every
    tighter tiling shares), read-only, and ``shapes``' eq.-1 weights."""
    seeded = ShapeCache(shapes.eq1)
    for array in (assembled.top, assembled.bottom, assembled.tiles):
        array.flags.writeable = False
    seeded[mesh_key(tiling)] = assembled
    return seeded


def _same_parts(a: Tiling, b: Tiling) -> bool:
    """Whether two tilings of one grid split it into the same parts."""
    return a.linkage.n_tiles == b.linkage.n_tiles and bool(
        np.array_equal(a.linkage.tile_component, b.linkage.tile_component)
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
