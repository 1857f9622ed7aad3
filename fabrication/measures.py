"""What a design measures as fabricated: route and string lengths, volumes and masses
(:func:`measure_fabrication`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from drawstring.cad.design import normalize_route
from drawstring.cad.paths import route_lengths
from drawstring.fabrication.panels import Panel, panel_holes, plywood_panels
from drawstring.fabrication.profiles import Process
from drawstring.geometry.core.types import FloatArray, IntArray

if TYPE_CHECKING:
    from drawstring.cad.design import CadResult
    from drawstring.fabrication.profiles import Profile

#: String length = flat route length x (1 + margin) + two tails to hold while pulling.
STRING_MARGIN = 0.20
STRING_TAIL_MIN_MM = 150.0


@dataclass(frozen=True)
class Measures:
    """Quantities of a design measured on its fabricated geometry, rounded once: every output
    that states them (bom.csv, manifest.json, assembly.md, route.json, design.json's
    ``metrics.cad``) takes them from :func:`measure_fabrication`.

    Attributes
    ----------
    route_flat_mm, route_assembled_mm : string route along the channels of the printed tiles,
        straight across the gaps and up, over and down the lift bores at lift points
        (:func:`~drawstring.cad.paths.route_lengths`), 0.1 mm.
    string_mm : string to cut, ``route_flat_mm x (1 + STRING_MARGIN) + 2 x tail_mm``, 0.1 mm.
    tail_mm : each of the two ends to hold while pulling, 0.1 mm.
    tile_volume_mm3, hinge_volume_mm3 : volumes of the tile and hinge-part solids, 0.1 mm^3.
    tile_mass_g : printed tiles (solid volume x density x infill) or, for plywood, the panels
        (area x panel thickness x density), 0.1 g.
    hinge_mass_g : hinge parts (volume x hinge density), 0.1 g.
    mass_g : ``tile_mass_g + hinge_mass_g`` (magnets and string left out), 0.1 g.
    """

    route_flat_mm: float
    route_assembled_mm: float
    string_mm: float
    tail_mm: float
    tile_volume_mm3: float
    hinge_volume_mm3: float
    tile_mass_g: float
    hinge_mass_g: float
    mass_g: float

    def to_json(self) -> dict[str, Any]:
        """Keys of design.json's ``metrics.cad``."""
        return {
            "mass_g": self.mass_g,
            "tile_mass_g": self.tile_mass_g,
            "hinge_mass_g": self.hinge_mass_g,
            "route_length_mm": {"flat": self.route_flat_mm, "assembled": self.route_assembled_mm},
            "string_length_mm": self.string_mm,
        }


def measure_fabrication(
    profile: Profile,
    tiles_flat: FloatArray,
    tiles_assembled: FloatArray,
    route_steps: IntArray | Sequence[Sequence[int]],
    lift_tiles: IntArray | Sequence[Sequence[int]],
    cad_flat: CadResult,
    panels: Sequence[Panel] | None = None,
    hinges: IntArray | None = None,
    hinge_side: Sequence[str] = (),
) -> Measures:
    """Route, string and mass of a design, measured on what is fabricated.

    Parameters
    ----------
    profile : the fabrication profile (process, densities, infill, panel thickness).
    tiles_flat, tiles_assembled : (T, 8, 3) float, mm: the tiles as printed (the pose of
        ``flat.step``) and assembled.
    route_steps, lift_tiles : the route and the extra lift bores (as
        :func:`~drawstring.fabrication.exports.write_fabrication`).
    cad_flat : the solids in the print pose (tile and hinge-part volumes).
    panels : plywood panels when the caller has them (made here otherwise, with the magnet
        and pilot holes of :func:`~drawstring.fabrication.panels.panel_holes` where ``hinges``
        and ``hinge_side`` are given).
    """
    steps = normalize_route(route_steps)
    flat_route, assembled_route = route_lengths(
        np.asarray(tiles_flat, dtype=np.float64),
        np.asarray(tiles_assembled, dtype=np.float64),
        steps,
        lift_tiles,
    )
    tail = max(STRING_TAIL_MIN_MM, 0.1 * flat_route)
    tile_volume = float(sum(cad_flat.checks("tiles")[1]))
    pad_volume = float(sum(cad_flat.checks("pads")[1]))
    if profile.process == Process.PLYWOOD_CNC:
        if panels is None:
            lifts = np.asarray(lift_tiles, dtype=np.int64).reshape(-1, 2)
            flat = np.asarray(tiles_flat, dtype=np.float64)
            holes: tuple[list[Any], list[Any]] = ([], [])
            if hinges is not None:
                holes = panel_holes(
                    profile, flat, np.asarray(tiles_assembled, dtype=np.float64), hinges,
                    hinge_side, cad_flat,
                )  # fmt: skip
            panels = plywood_panels(profile, flat, steps, lifts, *holes)[0]
        area = sum(p.area for p in panels)
        tile_mass = area * profile.panel_thickness_mm * 1e-9 * profile.density_kg_m3 * 1e3
    else:
        tile_mass = tile_volume * 1e-9 * profile.density_kg_m3 * profile.infill_fraction * 1e3
    tile_g = round(tile_mass, 1)
    hinge_g = round(pad_volume * 1e-9 * profile.hinge_density_kg_m3 * 1e3, 1)
    return Measures(
        route_flat_mm=flat_route,
        route_assembled_mm=assembled_route,
        string_mm=round(flat_route * (1.0 + STRING_MARGIN) + 2.0 * tail, 1),
        tail_mm=round(tail, 1),
        tile_volume_mm3=round(tile_volume, 1),
        hinge_volume_mm3=round(pad_volume, 1),
        tile_mass_g=tile_g,
        hinge_mass_g=hinge_g,
        mass_g=round(tile_g + hinge_g, 1),
    )
