"""Points on a tile's side face in bilinear coordinates (``u`` along its top edge, ``v`` from
top to bottom), and where a round pocket fits on two faces that touch (the magnet pockets of
:mod:`drawstring.cad.magnets_labels`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from drawstring.cad.feature_common import feature_wall_mm
from drawstring.cad.paths import unit_vector

if TYPE_CHECKING:  # profiles live in the fabrication layer; cad only reads fields
    from drawstring.cad.dimensions import FeatureDimensions as Profile


def side_quad(tile: NDArray[np.float64], side: int) -> NDArray[np.float64]:
    """(4, 3): top k, top k+1, bottom k, bottom k+1 of side ``side``."""
    nxt = (side + 1) % 4
    return np.asarray(tile[[side, nxt, 4 + side, 4 + nxt]])


def bilinear(quad: NDArray[np.float64], u: float, v: float) -> NDArray[np.float64]:
    """Point at (u along the top edge, v from top to bottom) of a side quad."""
    top = (1 - u) * quad[0] + u * quad[1]
    bottom = (1 - u) * quad[2] + u * quad[3]
    return np.asarray((1 - v) * top + v * bottom)


def invert_bilinear(quad: NDArray[np.float64], point: NDArray[np.float64], u: float, v: float):
    """(u, v) of the point of a side quad nearest ``point`` (Gauss-Newton from a guess)."""
    for _ in range(20):
        residual = bilinear(quad, u, v) - point
        du = (1 - v) * (quad[1] - quad[0]) + v * (quad[3] - quad[2])
        dv = ((1 - u) * quad[2] + u * quad[3]) - ((1 - u) * quad[0] + u * quad[1])
        jac = np.stack([du, dv], axis=1)
        step = np.linalg.lstsq(jac, -residual, rcond=None)[0]
        u, v = u + float(step[0]), v + float(step[1])
        if np.linalg.norm(step) < 1e-14:
            break
    return u, v


def pocket_fits(quad: NDArray[np.float64], u: float, v: float, radius: float) -> bool:
    """Whether a pocket circle at (u, v) stays inside the side face (mid-lines test)."""
    centre = bilinear(quad, u, v)
    edges = (
        (bilinear(quad, 0, 0), bilinear(quad, 1, 0)),
        (bilinear(quad, 0, 1), bilinear(quad, 1, 1)),
        (bilinear(quad, 0, 0), bilinear(quad, 0, 1)),
        (bilinear(quad, 1, 0), bilinear(quad, 1, 1)),
    )
    for a, b in edges:
        direction = unit_vector(b - a)
        offset = centre - a
        distance = np.linalg.norm(offset - (offset @ direction) * direction)
        if distance < radius:
            return False
    return True


#: Whether a pocket at ``(u, v)`` on side quad a keeps the given wall (mm) from the planes
#: that cut its tiles (hinge reliefs).
ClearOfCuts = Callable[[float, float, float], bool]


def pocket_place(
    quad_a: NDArray[np.float64],
    quad_b: NDArray[np.float64],
    u: float,
    radius: float,
    profile: Profile,
    clear: ClearOfCuts | None = None,
) -> tuple[float, float]:
    """``(u, v)`` of a pocket on side quad a: ``(u, 0.5)`` where it fits both faces
    (:func:`pocket_fits`) and no relief plane opens it (``clear``), else the nearest place
    where it fits them a :func:`feature_wall_mm` inside their edges and the cuts, and lies no
    nearer the face's middle than ``u`` (a pocket set off a string channel stays off it), else
    ``(u, 0.5)`` (it breaks out)."""

    def fits(at_u: float, at_v: float, size: float) -> bool:
        u_b, v_b = invert_bilinear(quad_b, bilinear(quad_a, at_u, at_v), 1.0 - at_u, at_v)
        return (
            pocket_fits(quad_a, at_u, at_v, size)
            and pocket_fits(quad_b, u_b, v_b, size)
            and (clear is None or clear(at_u, at_v, size - radius))
        )

    if fits(u, 0.5, radius):
        return u, 0.5
    width = float(np.linalg.norm(quad_a[1] - quad_a[0] + quad_a[3] - quad_a[2])) / 2.0
    height = float(np.linalg.norm(quad_a[2] - quad_a[0] + quad_a[3] - quad_a[1])) / 2.0
    grid = np.meshgrid(np.linspace(0.0, 1.0, 41), np.linspace(0.0, 1.0, 21), indexing="ij")
    us, vs = grid[0].ravel(), grid[1].ravel()
    off_middle = np.sign(u - 0.5) * (us - 0.5) >= abs(u - 0.5) - 1e-12
    moved = np.hypot((us - u) * width, (vs - 0.5) * height)
    wall = feature_wall_mm(profile)
    for k in np.flatnonzero(off_middle)[np.argsort(moved[off_middle], kind="stable")]:
        if fits(float(us[k]), float(vs[k]), radius + wall):
            return float(us[k]), float(vs[k])
    return u, 0.5
