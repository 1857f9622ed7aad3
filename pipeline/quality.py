"""What a design's measures mean for the maker: each flat, hinge and contact measure against
the profile's fabrication tolerance (``design.tolerance_mm``; a miss is a problem, exit status
3) and against drawstring's accuracy and fit targets (quality levels in design.json's
``quality``; a miss is a warning, exit status 4 only with ``--strict``)."""

from __future__ import annotations

from typing import Any

from drawstring.geometry.core.tolerances import (
    FLAT_EDGE_ERROR_TOL_MM,
    HINGE_GAP_TOL_MM,
    SURFACE_MAX_REL,
    SURFACE_MEAN_REL,
)
from drawstring.pipeline.record import above

#: The measures the fabrication tolerance bounds: design.json metric, its name in a problem
#: line, its accuracy target (mm).  The hinge gap is the whole 3D one: seen from above and in
#: depth (the tiles' thickness difference at bottom hinges).
TOLERANCE_MEASURES: tuple[tuple[str, str, float], ...] = (
    ("flat_edge_error_max_mm", "flat edge error", FLAT_EDGE_ERROR_TOL_MM),
    ("hinge_gap_in_plane_max_mm", "hinge gap seen from above", HINGE_GAP_TOL_MM),
    ("hinge_gap_max_mm", "hinge gap", HINGE_GAP_TOL_MM),
    ("contact_gap_max_mm", "assembled contact gap", HINGE_GAP_TOL_MM),
)
#: Quality levels: at the accuracy or fit target; off it but within the fabrication tolerance
#: (amber in report.html); over the tolerance (a problem).
AT_TARGET, WITHIN_TOLERANCE, OUT_OF_TOLERANCE, OFF_TARGET = (
    "target",
    "tolerance",
    "out of tolerance",
    "off target",
)


def _value(measured: dict[str, Any], key: str) -> float | None:
    value = measured.get(key)
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def tolerance_problems(measured: dict[str, Any], tolerance_mm: float) -> list[str]:
    """One line for each measure over the fabrication tolerance (the hinge gap named once:
    seen from above where that part misses, else in depth)."""
    problems = []
    in_plane_missed = False
    for key, name, _target in TOLERANCE_MEASURES:
        value = _value(measured, key)
        if value is None or value <= tolerance_mm:
            continue
        if key == "hinge_gap_in_plane_max_mm":
            in_plane_missed = True
        elif key == "hinge_gap_max_mm":
            if in_plane_missed:
                continue
            name = "hinge gap in depth (the tiles' thickness difference at bottom hinges)"
        problems.append(
            f"{name} {above(value, tolerance_mm)} mm exceeds the profile's fabrication "
            f"tolerance {tolerance_mm:g} mm"
        )
    return problems


def quality_levels(
    measured: dict[str, Any], tolerance_mm: float, target_diagonal_mm: float
) -> dict[str, Any]:
    """design.json's ``quality``: each measure with its target and level, and whether all are
    at their target (``met``)."""
    levels: dict[str, Any] = {}
    for key, _name, target in TOLERANCE_MEASURES:
        value = _value(measured, key)
        if value is None:
            continue
        level = (
            AT_TARGET
            if value <= target
            else WITHIN_TOLERANCE
            if value <= tolerance_mm
            else OUT_OF_TOLERANCE
        )
        levels[key] = {"target_mm": target, "level": level}
    side = _value(measured, "tile_side_mean_mm")
    fits = (
        ("surface_distance_mean_mm", SURFACE_MEAN_REL * side if side else None),
        ("surface_distance_max_mm", SURFACE_MAX_REL * target_diagonal_mm or None),
    )
    for key, bound in fits:
        value = _value(measured, key)
        if value is None or bound is None:
            continue
        level = AT_TARGET if value <= bound else OFF_TARGET
        levels[key] = {"target_mm": round(bound, 6), "level": level}
    return {
        "tolerance_mm": tolerance_mm,
        "met": all(entry["level"] == AT_TARGET for entry in levels.values()),
        "measures": levels,
    }
