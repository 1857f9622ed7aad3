"""Printing time and filament of a print bed, estimated from its parts without a slicer.

The estimate follows what a slicer lays down with the settings of :mod:`.slicer`: per tile and
layer, its perimeters round the tile's outline, solid layers at the top and bottom (and
throughout a tile too small for sparse infill), sparse infill between them, the TPU pads
line by line; each kind of line at its speed from the printer preset, slowed by the
acceleration it needs over the tile's width and by the filament's flow limit; the corners of
the perimeter loops (the triangles of the tile's mesh each layer cuts), where the nozzle
slows down to turn; a per-layer and per-tile overhead for travel, retraction and layer
changes; the tool changes and the wipe tower (:func:`bed_features`, :func:`estimate_bed`).
How much each term weighs (:data:`TIME_WEIGHTS`, :data:`TILE_FILAMENT_WEIGHTS`,
:data:`PAD_FILAMENT_WEIGHTS`) is fitted to PrusaSlicer's own estimates of designs sliced with
those settings: ``benchmarks/calibrate_print.py`` slices them, fits the weights by
non-negative least squares and prints them; ``benchmarks/results.json`` keeps the estimate
next to PrusaSlicer's for every built-in (rows of kind ``print_estimate``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING

import numpy as np

from drawstring.fabrication.slicer import SOLID_INFILL_BELOW_AREA_MM2

if TYPE_CHECKING:
    from drawstring.fabrication.mesh3mf import PartMesh
    from drawstring.fabrication.printers import Printer
    from drawstring.fabrication.profiles import Profile

#: A slicer's line width for a nozzle (PrusaSlicer's default for perimeters and infill).
LINE_WIDTH_PER_NOZZLE = 1.125


@dataclass(frozen=True)
class BedFeatures:
    """The quantities the estimate of one bed is a weighted sum of.

    Times in seconds (each line kind's length over its effective speed), counts as they are.

    perimeter_s : perimeter loops round every tile in every layer.
    solid_s : solid layers (top, bottom, and whole tiles too small for sparse infill).
    sparse_s : sparse infill.
    first_layer_s : the extra time of the first layer at its own speed.
    pad_s : the TPU pads, line by line at the TPU flow limit.
    corners : corners of the perimeter loops: the mesh's triangles each layer cuts, times the
        perimeters (each a slow-down where the nozzle turns).
    tile_layers : tiles times their layers (travel and retraction between tiles).
    pad_layers : layers that print TPU (tool changes and their primes).
    tower_layers : layers of the wipe tower (up to the last layer with TPU).
    layers : layers of the bed.
    line_mm3 : volume of the PLA lines (perimeters, solid and sparse infill), mm^3.
    pad_mm3 : volume of the pads, mm^3.
    purge_mm3 : what the tool changes prime in the wipe tower, mm^3: a purge each way per
        layer that prints TPU.
    """

    perimeter_s: float
    solid_s: float
    sparse_s: float
    first_layer_s: float
    pad_s: float
    corners: float
    tile_layers: float
    pad_layers: float
    tower_layers: float
    layers: float
    line_mm3: float
    pad_mm3: float
    purge_mm3: float

    def time_terms(self) -> list[float]:
        return [
            self.perimeter_s,
            self.solid_s,
            self.sparse_s,
            self.first_layer_s,
            self.pad_s,
            self.corners,
            self.tile_layers,
            self.pad_layers,
            self.tower_layers,
            self.layers,
        ]

    def tile_terms(self) -> list[float]:
        """Terms of the tiles' filament (mm^3 of PLA lines, wipe tower layers, mm^3 primed)."""
        return [self.line_mm3, self.tower_layers, self.purge_mm3]

    def pad_terms(self) -> list[float]:
        """Terms of the pads' filament (mm^3 of TPU, wipe tower layers, mm^3 primed)."""
        return [self.pad_mm3, self.tower_layers, self.purge_mm3]

    def to_json(self) -> dict[str, float]:
        return {f.name: round(float(getattr(self, f.name)), 3) for f in fields(self)}


# The weights below are fitted by ``benchmarks/calibrate_print.py --fit`` to PrusaSlicer
# 2.5.0's estimates of the beds of its fitting set (benchmarks/data/print_samples.json: 23
# beds of small designs, two test coupons and every built-in at 200 tiles); the terms that
# fitted to 0 (corners, tile layers, wipe tower layers, layer changes) are what PrusaSlicer's
# estimate already carries in the others.
#: Weights of :meth:`BedFeatures.time_terms` (s per s of each line kind, s per corner, ...).
TIME_WEIGHTS: tuple[float, ...] = (1.979, 0.7402, 1.755, 2.811, 6.624, 0.0, 0.0, 22.36, 0.0, 0.0)
#: Weights of :meth:`BedFeatures.tile_terms` (mm^3 per mm^3 of lines, per tower layer, per
#: mm^3 primed).
TILE_FILAMENT_WEIGHTS: tuple[float, ...] = (1.092, 26.69, 0.4649)
#: Weights of :meth:`BedFeatures.pad_terms`, alike.
PAD_FILAMENT_WEIGHTS: tuple[float, ...] = (0.8611, 2.685, 0.2455)


def effective_speed(speed: float, acceleration: float, run_mm: float) -> float:
    """Mean speed (mm/s) over a straight run of ``run_mm`` that starts and ends at rest,
    accelerating at ``acceleration`` up to ``speed`` (a triangle profile when the run is too
    short to reach it)."""
    if run_mm <= speed * speed / acceleration:
        return math.sqrt(acceleration * run_mm) / 2.0
    return run_mm / (run_mm / speed + speed / acceleration)


def _outline(vertices: np.ndarray) -> tuple[float, float]:
    """Area and perimeter (mm^2, mm) of the convex hull of the points' x, y."""
    from scipy.spatial import ConvexHull

    hull = ConvexHull(vertices[:, :2])
    ring = vertices[hull.vertices, :2]
    perimeter = float(np.linalg.norm(np.roll(ring, -1, axis=0) - ring, axis=1).sum())
    return float(hull.volume), perimeter


def layer_cuts(part: PartMesh, layer_height: float) -> int:
    """How many of the part's triangles the planes through the middle of its layers cut, all
    layers together: the segments of its sliced outlines."""
    corners = part.vertices[part.triangles][:, :, 2]
    low = corners.min(axis=1) - part.vertices[:, 2].min()
    high = corners.max(axis=1) - part.vertices[:, 2].min()
    # layer k's plane is at (k + 0.5) x layer height; count the planes strictly inside each
    # triangle's z range
    first = np.floor(low / layer_height - 0.5) + 1
    last = np.ceil(high / layer_height - 0.5) - 1
    return int(np.maximum(last - first + 1, 0).sum())


def bed_features(parts: Sequence[PartMesh], printer: Printer, profile: Profile) -> BedFeatures:
    """The features of one bed of parts (tiles and hinge pads, in the bed's pose)."""
    lh = printer.layer_height_mm
    width = LINE_WIDTH_PER_NOZZLE * printer.nozzle_mm
    density = profile.infill_fraction
    caps = printer.top_layers + printer.bottom_layers
    accel = printer.print_acceleration_mm_s2
    flow_cap = printer.pla_max_flow_mm3_s / (width * lh)
    perimeter_speed = min(
        printer.perimeters
        / (
            (printer.perimeters - 1) / printer.perimeter_mm_s
            + 1.0 / printer.external_perimeter_mm_s
        ),
        flow_cap,
    )
    solid_speed = min(printer.solid_infill_mm_s, flow_cap)
    sparse_speed = min(printer.infill_mm_s, flow_cap)
    first_speed = min(printer.first_layer_mm_s, flow_cap)
    perimeter_s = solid_s = sparse_s = first_s = 0.0
    tile_layers = line_mm3 = pad_mm3 = corners = 0.0
    top = 0.0
    pad_levels: set[int] = set()
    for part in parts:
        low, high = float(part.vertices[:, 2].min()), float(part.vertices[:, 2].max())
        height = high - low
        top = max(top, high)
        if part.kind == "pad":
            pad_mm3 += part.volume
            pad_levels.update(range(int(low / lh), max(math.ceil(high / lh), 1)))
            continue
        layers = max(round(height / lh), 1)
        area, perimeter = _outline(part.vertices)
        section = part.volume / height if height > 0 else area
        side = math.sqrt(max(section, 1.0))
        inside = max(section - perimeter * printer.perimeters * width, 0.0)
        solid_layers = layers if inside < SOLID_INFILL_BELOW_AREA_MM2 else min(caps, layers)
        perimeter_mm = perimeter * printer.perimeters * layers
        solid_mm = inside / width * solid_layers
        sparse_mm = inside / width * density * (layers - solid_layers)
        perimeter_s += perimeter_mm / effective_speed(perimeter_speed, accel, side)
        solid_s += solid_mm / effective_speed(solid_speed, accel, side)
        sparse_s += sparse_mm / effective_speed(sparse_speed, accel, side)
        first_mm = perimeter * printer.perimeters + inside / width
        first_s += first_mm / effective_speed(first_speed, accel, side) - first_mm / (
            effective_speed(solid_speed, accel, side)
        )
        corners += layer_cuts(part, lh) * printer.perimeters
        tile_layers += layers
        line_mm3 += (perimeter_mm + solid_mm + sparse_mm) * width * lh
    pad_speed = printer.tpu_max_flow_mm3_s / (width * lh)
    dual = line_mm3 > 0 and pad_mm3 > 0
    return BedFeatures(
        perimeter_s=perimeter_s,
        solid_s=solid_s,
        sparse_s=sparse_s,
        first_layer_s=max(first_s, 0.0),
        pad_s=pad_mm3 / (pad_speed * width * lh),
        corners=corners,
        tile_layers=tile_layers,
        pad_layers=float(len(pad_levels)) if dual else 0.0,
        tower_layers=float(max(pad_levels) + 1)
        if dual and printer.wipe_tower_width_mm > 0
        else 0.0,
        layers=float(max(round(top / lh), 1)),
        line_mm3=line_mm3,
        pad_mm3=pad_mm3,
        purge_mm3=2.0 * len(pad_levels) * printer.wipe_tower_purge_mm3 if dual else 0.0,
    )


@dataclass(frozen=True)
class BedEstimate:
    """The estimate of one bed: printing time (s) and filament (g) per material."""

    time_s: float
    tile_g: float
    pad_g: float


def estimate_bed(features: BedFeatures, profile: Profile) -> BedEstimate:
    """Printing time and filament of one bed, the fitted weights applied to its features."""
    time_s = float(np.dot(TIME_WEIGHTS, features.time_terms()))
    tile_mm3 = float(np.dot(TILE_FILAMENT_WEIGHTS, features.tile_terms()))
    pad_mm3 = float(np.dot(PAD_FILAMENT_WEIGHTS, features.pad_terms()))
    return BedEstimate(
        time_s=time_s,
        tile_g=tile_mm3 * profile.density_kg_m3 * 1e-6,
        pad_g=pad_mm3 * profile.hinge_density_kg_m3 * 1e-6,
    )
