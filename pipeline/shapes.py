"""The assembled shapes of a design's tilings (paper eq. 1 and extrusion), solved once per
quad mesh.

Tighter split bounds cut the linkage but keep the quad mesh, so every tiling of one design
shares its assembled shape; :class:`ShapeCache` holds them by mesh, with the eq.-1 weights
they are solved with (``--fit``).
"""

from __future__ import annotations

from collections.abc import Callable

from drawstring.geometry.assembled.shape import AssembledResult, optimize_assembled
from drawstring.geometry.assembled.top import Eq1Weights
from drawstring.geometry.target.surface import Target
from drawstring.geometry.tiling.grid import Tiling
from drawstring.pipeline.record import Progress, ResolvedOptions

#: A quad mesh as a dictionary key: vertex array shape and bytes, quad array shape and bytes.
MeshKey = tuple[tuple[int, ...], bytes, tuple[int, ...], bytes]


class ShapeCache(dict[MeshKey, AssembledResult]):
    """The assembled shapes solved so far, by quad mesh, and the eq.-1 weights they are solved
    with (``eq1``; None: ``options.weights``, no face samples)."""

    def __init__(self, eq1: Eq1Weights | None = None) -> None:
        super().__init__()
        self.eq1 = eq1


def assembled_shape(
    tiling: Tiling,
    loaded: Target,
    options: ResolvedOptions,
    progress: Progress,
    shapes: ShapeCache,
) -> AssembledResult:
    """The assembled configuration of ``tiling``'s quad mesh (paper eq. 1 with ``shapes.eq1``,
    or ``options.weights``, and extrusion), solved once per mesh and kept in ``shapes`` with
    read-only arrays."""
    key = mesh_key(tiling)
    with progress.stage("assembled"):
        if key not in shapes:
            w = shapes.eq1 if shapes.eq1 is not None else Eq1Weights.of(options.weights)
            shapes[key] = optimize_assembled(
                tiling.vertices,
                tiling.quads,
                loaded.vertices,
                loaded.faces,
                thickness=options.thickness_mm,
                w_planar=w.planar,
                w_square=w.square,
                w_surface=w.surface,
                w_samples=w.samples,
            )
            for array in (shapes[key].top, shapes[key].bottom, shapes[key].tiles):
                array.flags.writeable = False  # shared between tilings: nothing may edit it
        return shapes[key]


def mesh_key(tiling: Tiling) -> MeshKey:
    """The key of ``tiling``'s quad mesh in a :class:`ShapeCache`."""
    return (
        tiling.vertices.shape,
        tiling.vertices.tobytes(),
        tiling.quads.shape,
        tiling.quads.tobytes(),
    )


#: A check on the first tiling and its assembled shape that raises to refuse the design.
FirstCheck = Callable[[Tiling, AssembledResult], None]


def refusing_shape(
    tiling: Tiling,
    loaded: Target,
    options: ResolvedOptions,
    progress: Progress,
    shapes: ShapeCache,
    check: FirstCheck | None = None,
) -> AssembledResult:
    """The one check that refuses a design: eq. 1 and its extrusion on the first tiling with
    ``shapes``' weights (the paper's, or ``--weights``) raising
    :class:`~drawstring.geometry.core.errors.ThicknessError` when a tile turns inside out, and
    ``check`` on that shape (with CAD, the boundary channel check).  The pipeline asks it
    before any layout and the retry search asks it of every value it tries, so a ``retry
    with:`` that passed it is not refused again; every later stage keeps going on what
    passed (another shape that folds falls back to this one, which tighter tilings share)."""
    shape = assembled_shape(tiling, loaded, options, progress, shapes)
    if check is not None:
        check(tiling, shape)
    return shape
