"""Hinges: each hinge's face and trims, and the rigid layout of the flat tiles with their
hinge pairs brought together (paper section 4.4).
"""

from drawstring.geometry.hinges.placement import HingeLayout, HingeStrategy, layout_hinges

__all__ = [
    "HingeLayout",
    "HingeStrategy",
    "layout_hinges",
]
