"""Tiling: the quad grid on the flat rectangle, its linkage topology, lifting and splits."""

from drawstring.geometry.tiling.grid import Tiling, tile_surface
from drawstring.geometry.tiling.linkage import Linkage, Split, build_linkage, gap_centroids

__all__ = [
    "Linkage",
    "Split",
    "Tiling",
    "build_linkage",
    "gap_centroids",
    "tile_surface",
]
