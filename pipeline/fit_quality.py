"""How close the design sits to its target: the surface distance measured over every top face,
per tile and in all, and the warning where it misses its quality level.

The numbers are measured on the output geometry, the assembled tiles against the target as
the design approximates it (:func:`surface_distances`); the warning (:func:`fit_warnings`)
says what ``--fit`` did and what would bring the tiles closer.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from drawstring.geometry.assembled.fit import TopFaceDistances, top_face_distances
from drawstring.geometry.core.tolerances import SURFACE_MAX_REL, SURFACE_MEAN_REL
from drawstring.geometry.core.types import FloatArray
from drawstring.geometry.target.surface import Target
from drawstring.pipeline.record import ResolvedOptions, rounded


def surface_distances(tiles_3d: FloatArray, target: Target) -> TopFaceDistances:
    """The assembled tiles' top faces' distances from ``target``, each face sampled over its
    whole area (:func:`~drawstring.geometry.assembled.fit.top_face_distances`)."""
    return top_face_distances(tiles_3d, target.vertices, target.faces)


def meets_fit_level(
    tiles: FloatArray, distances: TopFaceDistances, loaded: Target, within: float = 1.0
) -> bool:
    """Whether assembled ``tiles`` whose top faces sit at ``distances`` from the target meet
    the fit level (``within`` times it): on average ``SURFACE_MEAN_REL`` of the mean tile
    side, at most ``SURFACE_MAX_REL`` of the target's diagonal."""
    top = tiles[:, :4]
    side = float(np.linalg.norm(np.roll(top, -1, axis=1) - top, axis=2).mean())
    return bool(
        distances.mean <= within * SURFACE_MEAN_REL * side
        and distances.max <= within * SURFACE_MAX_REL * loaded.bbox_diagonal_mm
    )


def surface_distance_metrics(distances: TopFaceDistances) -> dict[str, float]:
    """design.json's ``surface_distance_max_mm`` and ``surface_distance_mean_mm``."""
    return {
        "surface_distance_max_mm": rounded(distances.max, 9),
        "surface_distance_mean_mm": rounded(distances.mean, 9),
    }


def fit_misses(metrics: dict[str, Any], target_diagonal_mm: float) -> list[str]:
    """How the measured surface distance misses its quality levels, one phrase each (none
    where it meets them): the mean against ``SURFACE_MEAN_REL`` of the mean tile side, the
    largest against ``SURFACE_MAX_REL`` of the target's diagonal."""
    side = float(metrics.get("tile_side_mean_mm", 0.0))
    mean_distance = float(metrics.get("surface_distance_mean_mm", 0.0))
    max_distance = float(metrics.get("surface_distance_max_mm", 0.0))
    far: list[str] = []
    if side > 0 and mean_distance > SURFACE_MEAN_REL * side:
        far.append(
            f"{mean_distance:.2f} mm on average ({100 * mean_distance / side:.1f} % of the mean "
            f"tile side, over {100 * SURFACE_MEAN_REL:g} %: {SURFACE_MEAN_REL * side:.2f} mm)"
        )
    if target_diagonal_mm > 0 and max_distance > SURFACE_MAX_REL * target_diagonal_mm:
        far.append(
            f"up to {max_distance:.2f} mm ({100 * max_distance / target_diagonal_mm:.1f} % of "
            f"the target's diagonal, over {100 * SURFACE_MAX_REL:g} %: "
            f"{SURFACE_MAX_REL * target_diagonal_mm:.2f} mm)"
        )
    return far


def fit_warnings(
    metrics: dict[str, Any],
    target_diagonal_mm: float,
    fit: dict[str, Any] | None,
    options: ResolvedOptions,
    *,
    top_tried: bool = False,
) -> list[str]:
    """The warning "tiles sit far from the target" where the measured surface distance misses
    its quality level (:func:`fit_misses`), with what ``--fit`` did (``fit``,
    ``metrics.fit``) and what would bring the tiles closer (not top hinges where
    ``top_tried``: they were laid out too)."""
    far = fit_misses(metrics, target_diagonal_mm)
    if not far:
        return []
    used = (fit or {}).get("used", "paper")
    close = (fit or {}).get("close", {})
    if used == "weights":
        how = (
            "with --weights; drop it for the closest shape every layout target allows (--fit close)"
        )
    elif used == "paper" and not close:
        how = (
            "with --fit paper; the default --fit close brings the tiles as close as every "
            "layout target allows"
        )
    elif used == "paper":
        how = f"the close fit was not kept ({close.get('refused', '')})"
        if options.hinges != "top" and not top_tried:
            how += "; --hinges top lays out the close shape without that depth condition"
    else:
        how = (
            "after the close fit, the closest shape whose flat layout keeps every target; "
            "more tiles bring planar tiles closer to a curved target"
        )
    return [f"tiles sit far from the target: {', '.join(far)}, {how}"]
