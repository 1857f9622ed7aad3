"""Pipeline helpers measured on known geometry."""

from __future__ import annotations

import math

import numpy as np

from drawstring.fabrication.pipeline import cad_problems, channel_turn_assembled
from drawstring.geometry.linkage import build_linkage, gap_centroids, rotating_squares_layout
from drawstring.geometry.route import plan_route


def flat_boxes(link, side: float = 10.0, thickness: float = 3.0) -> np.ndarray:
    """Assembled tiles of a planar grid: boxes, top face at z = 0, bottom at -thickness."""
    offsets = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)
    corners = (link.tile_cells[:, None, :] + offsets[None]) * side
    top = np.concatenate([corners, np.zeros((link.n_tiles, 4, 1))], axis=2)
    bottom = top - np.array([0.0, 0.0, thickness])
    return np.concatenate([top, bottom], axis=1)


def test_channel_turn_of_a_planar_loop_is_at_least_one_full_turn() -> None:
    link = build_linkage(np.ones((5, 4), dtype=bool))
    layout = rotating_squares_layout(link, math.radians(30))
    route = plan_route(link, gap_centroids(link, layout))
    turn = channel_turn_assembled(route, flat_boxes(link))
    # A closed loop in a plane turns by at least 2 pi; the channels bend only at the corners
    # of the ring and where the route steps in and out, each by a right angle.
    assert turn >= 2 * math.pi - 1e-9
    assert math.isclose(turn / (math.pi / 2), round(turn / (math.pi / 2)), abs_tol=1e-9)


def test_cad_problems_name_each_fault_of_the_solids() -> None:
    clean = {
        "solids_valid": True,
        "interference_tiles_max_mm3": 0.0,
        "interference_tiles_pads_max_mm3": 0.007,
        "interference_tiles_pads_max_rel": 0.0005,  # tessellation of shared pin walls
        "channel_opening_distance_max_mm": 0.0,
        "channel_openings_missing": 0,
    }
    assert cad_problems(clean) == []
    faults = {
        "solids_valid": False,
        "interference_tiles_max_mm3": 0.000234,
        "interference_tiles_pads_max_mm3": 5.7,
        "interference_tiles_pads_max_rel": 0.4,  # an uncut pin hole
        "channel_opening_distance_max_mm": 0.2,
        "channel_openings_missing": 1,
    }
    found = cad_problems(faults)
    assert len(found) == 4
    assert any("40 % of its volume inside a tile" in p for p in found)
    assert any("interfere in the print pose (0.000234" in p for p in found)
