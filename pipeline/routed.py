"""The lift points and the string route of a laid-out design (stages lift and route), and
with CAD the checks of the profile's features on them, asked before any solid is built.

The string route needs the layout (the flat gap positions, the hinge layout) and the lift
points, which the lift-point sweep chooses by simulated deployments; the CAD stage's feature
checks (:func:`~.cad_stage.feature_shortfall`: the side faces the route passes, the lift bores,
the hinge strips at the laid-out corners) need the route.  :func:`routed_layout` makes both
right after the layout, so a design whose tiles are too small for the profile's features is
refused, or stepped past by the values the tool chooses (:mod:`~.auto`), before any solid.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from drawstring.fabrication.profiles import Profile
from drawstring.geometry.hinges.placement import HingeLayout
from drawstring.geometry.route.energy import tile_masses_from_volumes
from drawstring.geometry.route.lift import LiftPoints, select_lift_points
from drawstring.geometry.route.result import Route
from drawstring.geometry.simulate.deploy import simulate_stage
from drawstring.geometry.simulate.result import SimulationResult
from drawstring.geometry.tiling.grid import parts_in_place
from drawstring.geometry.tiling.linkage import gap_centroids
from drawstring.pipeline.cad_stage import (
    FeatureShortfall,
    feature_shortfall,
    lift_exits,
    route_steps,
)
from drawstring.pipeline.layout_stage import ShapedLayout, fabricated_tiles
from drawstring.pipeline.record import Progress, ResolvedOptions
from drawstring.pipeline.route_stage import NamedCheck, plan_lift_route


class Deployment:
    """The string routes and deployment simulations of a laid-out design, by lift set: the
    lift-point sweep and the design share them, so each lift set is routed and simulated
    once."""

    def __init__(
        self,
        shaped: ShapedLayout,
        hinge_layout: HingeLayout,
        thickness_mm: float,
        progress: Progress,
    ) -> None:
        linkage = shaped.tiling.linkage
        self._linkage = linkage
        self._tiles_3d = shaped.assembled.tiles
        self._hinge_vertices = hinge_layout.hinge_vertices
        self._thickness_mm = thickness_mm
        self._progress = progress
        # the route is planned with the parts side by side as they meet in the assembled shape
        self._flat_gap_xy = gap_centroids(
            linkage, parts_in_place(linkage, hinge_layout.tiles[:, :4, :2], shaped.tiling.uv)
        )
        #: (T, 8, 3) the flat tiles as fabricated (:func:`~.layout_stage.fabricated_tiles`)
        self.fabricated = fabricated_tiles(hinge_layout, shaped.assembled.tiles)
        self._routes: dict[tuple[int, ...], tuple[Route, str | None, NDArray[np.int64]]] = {}
        #: the simulated deployments, by lift set
        self.runs: dict[tuple[int, ...], SimulationResult] = {}

    def route(self, lift_gaps: NDArray[np.int64]) -> tuple[Route, str | None, NDArray[np.int64]]:
        """The string route through ``lift_gaps``, a note on it, and the lift gaps it serves
        (:func:`~.route_stage.plan_lift_route`)."""
        key = tuple(int(g) for g in lift_gaps)
        if key not in self._routes:
            with self._progress.stage("route"):
                self._routes[key] = plan_lift_route(self._linkage, self._flat_gap_xy, lift_gaps)
        return self._routes[key]

    def simulated(self, lift_gaps: NDArray[np.int64]) -> SimulationResult:
        """The deployment pulled by the string routed through ``lift_gaps``."""
        key = tuple(int(g) for g in lift_gaps)
        if key not in self.runs:
            route_steps, _, served = self.route(lift_gaps)
            with self._progress.stage("simulate"):
                self.runs[key] = simulate_stage(
                    self._linkage,
                    self.fabricated,
                    self._tiles_3d,
                    self._hinge_vertices,
                    route_steps,
                    served,
                    self._thickness_mm,
                )
        return self.runs[key]


def lift_and_route(
    shaped: ShapedLayout,
    deployment: Deployment,
    options: ResolvedOptions,
    masses: NDArray[np.float64],
    progress: Progress,
    notes: list[str],
) -> tuple[LiftPoints, Route, NDArray[np.int64]]:
    """Stages lift and route: the lift points (each lift set the sweep tries checked by a
    simulated deployment, with ``--simulate``), the string route through them, and the lift
    set the sweep chose (the route may serve a lift gap it cannot reach next to it).  Notes
    on them are added to ``notes``."""
    linkage, assembled = shaped.tiling.linkage, shaped.assembled
    deploy_check = None
    if options.simulate:
        # The lift-point sweep raises its threshold while the simulated deployment fails
        # (paper sec. 5.2); every lift set is routed and simulated once.
        deploy_check = NamedCheck(
            "projective-dynamics deployment simulation",
            lambda gaps: deployment.simulated(gaps).deployed,
        )
    assembled_gap_xyz = gap_centroids(linkage, assembled.tiles[:, :4])
    with progress.stage("lift"):
        lift = select_lift_points(
            linkage,
            assembled.tiles.mean(axis=1),
            masses,
            up=options.up,
            gap_positions=assembled_gap_xyz,
            deploy_check=deploy_check,
        )
    if not options.simulate and lift.sweep and not any(ok for _, _, ok in lift.sweep):
        notes.append(
            f"lift points: the check '{lift.check_name}' failed for every threshold, so every "
            "energy peak is a lift point (run with the deployment simulation to check the pull)"
        )
    # the lift set the sweep chose; a lift gap the string cannot reach is served next to it
    chosen = lift.lift_gaps
    route, route_note, served = deployment.route(chosen)
    if route_note:
        notes.append(route_note)
    if not np.array_equal(served, chosen):
        lift = replace(lift, lift_gaps=served, positions=assembled_gap_xyz[served])
    return lift, route, chosen


@dataclass(frozen=True)
class Routed:
    """A laid-out design's lift points and string route: the routes and simulations made
    (``deployment``), the lift points (the gaps the route serves), the route, the lift set
    the sweep chose, the tile masses they were chosen with, and the notes on them."""

    deployment: Deployment
    lift: LiftPoints
    route: Route
    chosen: NDArray[np.int64]
    masses: NDArray[np.float64]
    notes: tuple[str, ...]


def routed_layout(
    shaped: ShapedLayout, options: ResolvedOptions, profile: Profile, progress: Progress
) -> Routed:
    """Stages lift and route on the layout ``shaped`` made with ``options``
    (:func:`lift_and_route`)."""
    hinge_layout = shaped.hinge_layout
    assert hinge_layout is not None  # only a tiling that was tiled again goes without
    masses = tile_masses_from_volumes(
        shaped.assembled.tiles, profile.density_kg_m3 * profile.infill_fraction
    )
    deployment = Deployment(shaped, hinge_layout, options.thickness_mm, progress)
    notes: list[str] = []
    lift, route, chosen = lift_and_route(shaped, deployment, options, masses, progress, notes)
    return Routed(deployment, lift, route, chosen, masses, tuple(notes))


def routed_shortfall(
    profile: Profile, shaped: ShapedLayout, routed: Routed
) -> FeatureShortfall | None:
    """The worst of the CAD stage's feature checks that fails on the laid-out tiles as
    fabricated and their route (:func:`~.cad_stage.feature_shortfall`: side faces the string
    runs through, lift-bore depth, hinge strips at the hinged corners on their faces), or
    None where every feature fits."""
    assert shaped.hinge_layout is not None
    return feature_shortfall(
        profile,
        routed.deployment.fabricated,
        route_steps(routed.route),
        lift_exits(routed.route, routed.lift.lift_gaps),
        shaped.tiling.linkage.hinges,
        shaped.hinge_layout.sides,
    )
