"""Hinges: each hinge's face and trims, and the rigid layout of the flat tiles with their
hinge pairs brought together (paper section 4.4).
"""

from drawstring.geometry.hinges.placement import HingeLayout, layout_hinges
from drawstring.geometry.hinges.sides import dual_hinge_faces, hinge_sides
from drawstring.geometry.hinges.trims import HingeTrim

__all__ = [
    "HingeLayout",
    "HingeTrim",
    "dual_hinge_faces",
    "hinge_sides",
    "layout_hinges",
]
