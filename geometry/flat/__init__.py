"""The flat layout: the hinged tiles laid flat (paper section 4.3), its co-optimization with
the assembled top faces, and independent measures of the result.
"""

from drawstring.geometry.flat.coflat import CoOptimizedTop, co_optimize_top
from drawstring.geometry.flat.layout import FlatResult, extrude_flat, optimize_flat
from drawstring.geometry.flat.pose import HingeFaces, hinge_faces

__all__ = [
    "CoOptimizedTop",
    "FlatResult",
    "HingeFaces",
    "co_optimize_top",
    "extrude_flat",
    "hinge_faces",
    "optimize_flat",
]
