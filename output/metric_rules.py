"""The report's metric targets: what each metric of design.json means and when it passes.

``METRIC_RULES`` holds the known metrics (dotted names for nested ones) with their meaning,
their target and a check; :func:`evaluate_metrics` turns the metrics of a design.json into
:class:`MetricRow` lines of the report's table.  Used by :mod:`drawstring.output.report`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from drawstring.geometry.core.tolerances import (
    CAD_PAD_INTERFERENCE_REL,
    CAPSTAN_FACTOR_WARN,
    FLAT_EDGE_ERROR_TOL_MM,
    HINGE_GAP_TOL_MM,
    PRINT_GAP_TOL_MM,
    SURFACE_MAX_REL,
    SURFACE_MEAN_REL,
)

# ----------------------------------------------------------------------------------------------
# Metrics: targets and marks
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MetricRule:
    """What a metric means and its target; ``check`` is None for numbers shown without a mark.
    An ``advisory`` target is one of quality that a design may miss and still be made (the
    pipeline warns, and exits 0): the report marks it off target, not failed."""

    meaning: str
    target: Callable[[dict[str, Any]], str]
    check: Callable[[Any, dict[str, Any]], bool] | None
    advisory: bool = False


def _opt(design: dict[str, Any], key: str, default: float) -> float:
    value = design.get("options", {}).get(key)
    return float(value) if isinstance(value, int | float) else default


def _scale_bound(design: dict[str, Any]) -> float:
    """The bound design.json's warnings and problems judge the scale factor by:
    ``--max-scale-factor``, at most what gaps in [θmin, 90°] absorb (the tighter
    ``split_bound`` of a re-tiling only steers where the splits go)."""
    theta = math.radians(_opt(design, "min_gap_angle_deg", 12.0))
    return min(_opt(design, "max_scale_factor", 2.0), 2.0 / (1.0 + math.sin(theta)))


def _diag(design: dict[str, Any]) -> float:
    value = design.get("target", {}).get("bbox_diagonal_mm")
    return float(value) if isinstance(value, int | float) and value > 0 else math.nan


def _tile_side(design: dict[str, Any]) -> float:
    value = design.get("metrics", {}).get("tile_side_mean_mm")
    return float(value) if isinstance(value, int | float) and value > 0 else math.nan


def _const(text: str) -> Callable[[dict[str, Any]], str]:
    return lambda _design: text


def _cad(design: dict[str, Any], key: str, default: float) -> float:
    value = design.get("metrics", {}).get("cad", {}).get(key)
    return float(value) if isinstance(value, int | float) else default


def _at_most(limit: float) -> Callable[[Any, dict[str, Any]], bool]:
    return lambda v, _design: float(v) <= limit


#: Known metrics of design.json (dotted names for nested ones) and their targets.  Targets are
#: what the report calls good enough to print; they are not solver tolerances.
METRIC_RULES: dict[str, MetricRule] = {
    "scale_factor_max": MetricRule(
        "max/min conformal area scale over the tiles of a part (a quad linkage expands at most "
        "2x; gaps opening between θmin and 90° absorb 2 / (1 + sin θmin))",
        lambda d: f"≤ {_scale_bound(d):.3g}",
        lambda v, d: float(v) <= _scale_bound(d) + 1e-9,
    ),
    "scale_factor_max_before_splits": MetricRule(
        "the same ratio before splits were cut", _const("(before splits)"), None
    ),
    "split_bound": MetricRule(
        "the scale bound the parts were split with: --max-scale-factor, no more than gaps in "
        "[θmin, 90°] absorb, tighter where the first tiling's flat tiles missed their hinges",
        _const("≤ --max-scale-factor"),
        lambda v, d: float(v) <= _opt(d, "max_scale_factor", 2.0) + 1e-9,
    ),
    "planarity_max_mm": MetricRule(
        "largest distance of a face corner from its best-fit plane (top, bottom, contact faces)",
        _const("≤ 0.01 mm"),
        _at_most(0.01),
    ),
    "contact_gap_max_mm": MetricRule(
        "assembled: largest gap between the contact faces of neighbouring tiles",
        _const("≤ 0.05 mm"),
        _at_most(0.05),
    ),
    "contact_angle_max_deg": MetricRule(
        "assembled: largest angle between the contact faces of neighbouring tiles",
        _const("≤ 0.5°"),
        _at_most(0.5),
    ),
    "surface_distance_max_mm": MetricRule(
        "largest distance of the tiles' top faces from the target (target.obj), over each face",
        lambda d: (
            f"≤ {100 * SURFACE_MAX_REL:g} % of the diagonal ({SURFACE_MAX_REL * _diag(d):.2f} mm)"
        ),
        lambda v, d: float(v) <= SURFACE_MAX_REL * _diag(d),
        advisory=True,  # the closest shape the layout allows can still miss it; a warning
    ),
    "surface_distance_mean_mm": MetricRule(
        "mean distance of the tiles' top faces from the target (target.obj), over their area",
        lambda d: (
            f"≤ {100 * SURFACE_MEAN_REL:g} % of the mean tile side "
            f"({SURFACE_MEAN_REL * _tile_side(d):.2f} mm)"
        ),
        lambda v, d: float(v) <= SURFACE_MEAN_REL * _tile_side(d) + 1e-9,
        advisory=True,
    ),
    "flat_edge_error_max_mm": MetricRule(
        "largest edge length difference between the flat and the assembled tiles",
        _const(f"≤ {FLAT_EDGE_ERROR_TOL_MM:g} mm"),
        _at_most(FLAT_EDGE_ERROR_TOL_MM),
    ),
    "flat_overlap_area_mm2": MetricRule(
        "total area where tiles overlap in the flat layout",
        _const("= 0 mm² (≤ 0.01)"),
        _at_most(0.01),
    ),
    "flat_gap_angle_min_deg": MetricRule(
        "smallest opening angle of a gap in the flat layout (room for the printer or cutter)",
        lambda d: f"≥ {_opt(d, 'min_gap_angle_deg', 0.0):g}°",
        lambda v, d: float(v) >= _opt(d, "min_gap_angle_deg", 0.0) - 0.01,
    ),
    "flat_gap_angle_max_deg": MetricRule(
        "largest opening angle of a gap in the flat layout (square gaps open 90°)",
        _const("≤ 90°"),
        _at_most(90.0),
    ),
    "hinge_gap_max_mm": MetricRule(
        "largest distance between the two corners a hinge joins, flat layout",
        _const(f"≤ {HINGE_GAP_TOL_MM:g} mm"),
        _at_most(HINGE_GAP_TOL_MM),
    ),
    "hinge_gap_in_plane_max_mm": MetricRule(
        "the same, seen from above (the rest is the thickness difference of the two tiles)",
        _const(f"≤ {HINGE_GAP_TOL_MM:g} mm"),
        _at_most(HINGE_GAP_TOL_MM),
    ),
    "flat_merge_shift_max_mm": MetricRule(
        "largest move of a flat.obj vertex off its tile's rigid copy when the hinge pairs were "
        "merged (the printed tiles are the rigid copies)",
        _const("(mm)"),
        None,
    ),
    "thickness_min_mm": MetricRule(
        "thinnest tile (bottom corners to the top face's plane)", _const("(mm)"), None
    ),
    "thickness_max_mm": MetricRule(
        "thickest tile (tiles differ where the quad mesh is not conical)", _const("(mm)"), None
    ),
    "contact_area_lost_mm2": MetricRule(
        "side-face contact area the hinge trims remove (pairs that overlap in the flat pose)",
        _const("(mm²)"),
        None,
    ),
    "cad.interference_tiles_pads_max_rel": MetricRule(
        "largest share of a hinge part's volume inside a tile, print pose",
        _const(f"≤ {100 * CAD_PAD_INTERFERENCE_REL:g} %"),
        _at_most(CAD_PAD_INTERFERENCE_REL),
    ),
    "cad.print_clearance_mm": MetricRule(
        "distance tiles printed together keep apart: the nozzle width (their hinges relieved)",
        _const("(mm)"),
        None,
    ),
    "cad.tile_pairs_closer": MetricRule(
        "pairs of printed tiles closer than that", _const("= 0"), _at_most(0)
    ),
    "cad.tile_gap_min_mm": MetricRule(
        "closest two printed tiles come in the print pose (a slicer joins tiles closer than "
        "a nozzle width, welding a hinge shut)",
        lambda d: f"≥ {_cad(d, 'print_clearance_mm', 0.4):g} mm (the nozzle)",
        lambda v, d: float(v) >= _cad(d, "print_clearance_mm", 0.4) - PRINT_GAP_TOL_MM,
    ),
    "lift_points": MetricRule(
        "points where the string leaves the top face to lift the structure",
        _const("(count)"),
        None,
    ),
    "route.tiles": MetricRule("tiles the string passes through", _const("(count)"), None),
    "route.boundary_tiles_covered": MetricRule(
        "boundary tiles the string passes through (closing the boundary assembles the linkage)",
        lambda d: f"all ({d.get('linkage', {}).get('boundary_tiles', '?')})",
        lambda v, d: (
            bool(v)
            if isinstance(v, bool)
            else (float(v) >= 1.0)
            if isinstance(v, float) and float(v) <= 1.0
            else float(v) >= float(d.get("linkage", {}).get("boundary_tiles", math.inf))
        ),
    ),
    "route.turn_angle_total_rad": MetricRule(
        "total turning of the string (friction grows with it)", _const("(lower is better)"), None
    ),
    "route.crossings": MetricRule(
        "places where the string crosses itself", _const("= 0"), _at_most(0)
    ),
    "route.capstan_factor": MetricRule(
        "exp(μ·turning) of the planning route through the flat gap centres (it sums every "
        "turn from gap to gap, so it runs high; the friction of the pull is the channels' "
        "factor below)",
        _const("(lower is better)"),
        None,
    ),
    "route.capstan_factor_channels_assembled": MetricRule(
        "pull force over the force at the far end, exp(μ·bend of the channels), assembled",
        _const(f"≤ {CAPSTAN_FACTOR_WARN:g}"),
        _at_most(CAPSTAN_FACTOR_WARN),
        advisory=True,  # a warning: a slicker string and channel lower it
    ),
    "route.length_mm": MetricRule("string length through the channels", _const("(mm)"), None),
    "simulation.deployed": MetricRule(
        "the simulated pull brings the flat layout to the assembled shape",
        _const("yes"),
        lambda v, _d: bool(v) is True,
    ),
    "simulation.steps": MetricRule("simulation steps", _const("(count)"), None),
    "simulation.final_max_deviation_mm": MetricRule(
        "after the simulated pull: largest distance of a tile corner from the assembled pose",
        lambda d: f"≤ 1 % of the mean tile side ({0.01 * _tile_side(d):.2f} mm)",
        lambda v, d: float(v) <= 0.01 * _tile_side(d) + 1e-9,
    ),
    "simulation.max_penetration_mm": MetricRule(
        "largest overlap between tiles during the simulated pull",
        _const("≤ 0.1 mm"),
        _at_most(0.1),
    ),
    "rigidity.null_dimension": MetricRule(
        "independent small motions of the assembled linkage with the string tight "
        "(6 = only moving it as a whole)",
        _const("= 6"),
        lambda v, _d: int(v) == 6,
    ),
    "rigidity.internal_flexes": MetricRule(
        "ways the assembled shape can wobble with the string tight", _const("= 0"), _at_most(0)
    ),
}


@dataclass(frozen=True)
class MetricRow:
    """One line of the metrics table; ``passed`` is None where no target applies."""

    name: str
    value: str
    meaning: str
    target: str
    passed: bool | None
    advisory: bool = False


def _flatten_metrics(metrics: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    flat: dict[str, Any] = {}
    for key, value in metrics.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            flat.update(_flatten_metrics(value, name + "."))
        else:
            flat[name] = value
    return flat


def _format_value(value: Any) -> str:
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            return str(value)
        if value != 0 and (abs(value) < 1e-3 or abs(value) >= 1e6):
            return f"{value:.3e}"
        return f"{value:.4g}" if abs(value) < 1000 else f"{value:.1f}"
    if isinstance(value, list):
        return f"{len(value)} item{'s' if len(value) != 1 else ''}"
    return str(value)


def within_tolerance(design: dict[str, Any], name: str) -> bool:
    """Whether design.json's ``quality`` puts metric ``name`` off its accuracy target but
    within the profile's fabrication tolerance: a quality miss (amber), not a failure."""
    quality = design.get("quality")
    measures = quality.get("measures") if isinstance(quality, dict) else None
    entry = measures.get(name) if isinstance(measures, dict) else None
    return isinstance(entry, dict) and entry.get("level") == "tolerance"


def evaluate_metrics(design: dict[str, Any]) -> list[MetricRow]:
    """Every metric of design.json with its target and mark (known names) or no mark."""
    rows = []
    for name, value in _flatten_metrics(design.get("metrics", {}) or {}).items():
        rule = METRIC_RULES.get(name)
        passed: bool | None = None
        target = ""
        meaning = ""
        if rule is not None:
            meaning = rule.meaning
            target = rule.target(design)
            if rule.check is not None and isinstance(value, int | float):
                try:
                    passed = bool(rule.check(value, design))
                except (TypeError, ValueError):
                    passed = None
                if not math.isfinite(float(value)):
                    passed = False
        # a value that is not finite is a broken measurement: failed, whatever the target
        finite = not isinstance(value, int | float) or math.isfinite(float(value))
        advisory = rule is not None and (rule.advisory or within_tolerance(design, name)) and finite
        rows.append(MetricRow(name, _format_value(value), meaning, target, passed, advisory))
    return rows
