"""The vocabulary of a frustum tile, defined once: its vertices, sides, faces, the face a hinge
sits on, and the two poses a design is built in.

A tile is eight vertices: the top corners 0..3 counter-clockwise seen from above, starting at
the grid cell's bottom-left, and the bottom corners 4..7 under them.  Its *side* ``k`` is the
grid side under the top edge ``k -> k + 1`` (:class:`Side`); its six *faces* are the top, the
bottom and one face per side (:class:`Face`, the rows of :data:`TILE_FACES`).  Modules that
need the faces in another order (the CAD layer builds solids sides first, the simulation winds
side faces inwards) take that order from here, derived from :data:`TILE_FACES`.
"""

from __future__ import annotations

from enum import IntEnum, StrEnum

import numpy as np

from drawstring.geometry.core.types import IntArray


class Side(IntEnum):
    """A tile's side in the grid: side ``k`` lies under the top edge ``k -> k + 1``."""

    BOTTOM = 0
    RIGHT = 1
    TOP = 2
    LEFT = 3

    @property
    def label(self) -> str:
        """The side's name in messages and reports (``"bottom"``, ``"right"``, ...)."""
        return self.name.lower()


class Face(IntEnum):
    """A tile's faces, numbered as the rows of :data:`TILE_FACES`."""

    TOP = 0
    BOTTOM = 1
    SIDE_BOTTOM = 2
    SIDE_RIGHT = 3
    SIDE_TOP = 4
    SIDE_LEFT = 5

    @staticmethod
    def of_side(side: int) -> Face:
        """The face under side ``side`` (0..3)."""
        return Face(Face.SIDE_BOTTOM + int(side))


#: The six faces as vertex indices, each counter-clockwise seen from outside the tile: top,
#: bottom, then the face of side ``k`` (vertices ``k, 4 + k, 4 + k + 1, k + 1``).
TILE_FACES: IntArray = np.array(
    [[0, 1, 2, 3], [4, 7, 6, 5]] + [[k, 4 + k, 4 + (k + 1) % 4, (k + 1) % 4] for k in range(4)],
    dtype=np.int64,
)

#: The four side faces in side order (rows ``Face.SIDE_BOTTOM..`` of :data:`TILE_FACES`).
SIDE_FACES: IntArray = TILE_FACES[Face.SIDE_BOTTOM :]

#: The four side faces wound the other way (counter-clockwise seen from inside the tile,
#: starting at corner ``k``: ``k, k + 1, 4 + k + 1, 4 + k``), as the deployment simulation and
#: the rigidity check pair two tiles' touching faces vertex by vertex.
SIDE_FACES_INWARD: IntArray = np.roll(SIDE_FACES[:, ::-1], 1, axis=1)

#: Top and bottom, then the side faces wound inwards: the faces as the deployment simulation
#: reads them.
TILE_FACES_SIDES_INWARD: IntArray = np.vstack([TILE_FACES[: Face.SIDE_BOTTOM], SIDE_FACES_INWARD])

#: The order the CAD layer builds a tile's faces in: the sides first, then top and bottom, so
#: that a side's face index is its side index.
CAD_FACE_ORDER: tuple[Face, ...] = (
    Face.SIDE_BOTTOM,
    Face.SIDE_RIGHT,
    Face.SIDE_TOP,
    Face.SIDE_LEFT,
    Face.TOP,
    Face.BOTTOM,
)


class HingeSide(StrEnum):
    """The face a hinge joins two tiles' corners on (``hinges.json`` writes the value)."""

    TOP = "top"
    BOTTOM = "bottom"


class HingeStrategy(StrEnum):
    """Where hinges go: each on the face where its tiles clear (``dual``), or all on top."""

    DUAL = "dual"
    TOP = "top"


class Pose(StrEnum):
    """The two poses a design's tiles are built in."""

    #: as printed or cut: the flat layout with its hinges (T2D)
    FLAT = "flat"
    #: as assembled by the pull: the tiles moved rigidly onto T3D
    ASSEMBLED = "assembled"
