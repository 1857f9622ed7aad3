"""The assembled shape: planar, near-square quads near the target (paper eq. 1), the frustum
tiles extruded from them, and the rigidity of the assembled linkage.
"""

from drawstring.geometry.assembled.reextrude import reextrude
from drawstring.geometry.assembled.rigidity import rigidity_report
from drawstring.geometry.assembled.shape import AssembledResult, optimize_assembled

__all__ = [
    "AssembledResult",
    "optimize_assembled",
    "reextrude",
    "rigidity_report",
]
