"""Lift points and the string route (paper sections 5.2 and 5.3)."""

from drawstring.geometry.route.lift import LiftPoints, select_lift_points
from drawstring.geometry.route.plan import plan_route
from drawstring.geometry.route.result import Route, route_metrics, route_to_json

__all__ = [
    "LiftPoints",
    "Route",
    "plan_route",
    "route_metrics",
    "route_to_json",
    "select_lift_points",
]
