"""Time lift-point selection plus string routing at about 200 and 1600 tiles.

Targets (issue 5): lift + route <= 1 s at 200 tiles and <= 5 s at 1600 tiles on 2 cores.
The test shape is a full grid over a two-bump height field (a stand-in flattening: tile (i, j)
sits at its cell centre, lifted to z = f(x, y)); gap centroids come from the known
rotating-squares flat layout.
"""

from __future__ import annotations

import json
import math
import time
from typing import Any

import numpy as np
from numpy.typing import NDArray

from drawstring.geometry.route.lift import select_lift_points
from drawstring.geometry.route.plan import plan_route
from drawstring.geometry.route.result import route_metrics
from drawstring.geometry.tiling.linkage import Linkage, build_linkage, rotating_squares_layout


def _flat_gap_centroids(linkage: Linkage, opening: float = 0.5) -> NDArray[np.float64]:
    corners = rotating_squares_layout(linkage, opening, side=10.0)
    sides = linkage.gap_sides
    valid = sides[:, :, 0] >= 0
    t = np.maximum(sides[:, :, 0], 0)
    k = sides[:, :, 1]
    mid = 0.5 * (corners[t, k] + corners[t, (k + 1) % 4])
    return np.asarray((mid * valid[..., None]).sum(1) / valid.sum(1)[:, None])


def _instance(n: int) -> tuple[Linkage, NDArray[np.float64], NDArray[np.float64]]:
    linkage = build_linkage(np.ones((n, n), dtype=bool))
    xy = (linkage.tile_cells + 0.5) / n
    z = 80.0 * np.exp(-((xy[:, 0] - 0.3) ** 2 + (xy[:, 1] - 0.35) ** 2) / 0.02)
    z += 60.0 * np.exp(-((xy[:, 0] - 0.7) ** 2 + (xy[:, 1] - 0.65) ** 2) / 0.02)
    centroids = np.column_stack([xy * n * 10.0, z])
    return linkage, centroids, _flat_gap_centroids(linkage)


def run() -> list[dict[str, Any]]:
    """One row per size: stage, tiles, time_s and quality numbers."""
    rows: list[dict[str, Any]] = []
    for n in (14, 40):
        linkage, centroids, flat = _instance(n)
        masses = np.full(linkage.n_tiles, 0.01)
        t0 = time.perf_counter()
        lift = select_lift_points(linkage, centroids, masses)
        t1 = time.perf_counter()
        route = plan_route(linkage, flat, lift.lift_gaps)
        t2 = time.perf_counter()
        m = route_metrics(route, linkage, flat, None, mu=0.3)
        rows.append(
            {
                "stage": "lift",
                "tiles": linkage.n_tiles,
                "time_s": t1 - t0,
                "peaks": len(lift.peaks),
                "lift_points": len(lift.lift_gaps),
                "tau": lift.tau,
                "check": lift.check_name,
            }
        )
        rows.append(
            {
                "stage": "route",
                "tiles": linkage.n_tiles,
                "time_s": t2 - t1,
                "method": route.method,
                "turn_angle_total_rad": route.turn_angle_total_rad,
                "lower_bound_rad": route.lower_bound_rad,
                "crossings": route.crossings,
                "channel_partners_ok": m["channel_partners_ok"],
                "tiles_passed_once": m["tiles_passed_once"],
                "lift_gaps_missed": m["lift_gaps_missed"],
                "boundary_tiles_covered": route.boundary_tiles_covered,
                "capstan_factor_mu0.3": m["capstan_factor"],
                "route_gaps": len(route.gaps),
                "length_flat_mm": route.length_flat_mm,
            }
        )
        rows.append(
            {
                "stage": "lift+route",
                "tiles": linkage.n_tiles,
                "time_s": t2 - t0,
                "target_s": 1.0 if n == 14 else 5.0,
                "turn_over_bound": route.turn_angle_total_rad / (2 * math.pi),
            }
        )
    return rows


if __name__ == "__main__":
    for row in run():
        print(json.dumps(row))
