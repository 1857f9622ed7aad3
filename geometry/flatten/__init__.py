"""Flattening: the target mapped conformally onto a rectangle (Boundary First Flattening)."""

from drawstring.geometry.flatten.conformal import Flattening, flatten

__all__ = [
    "Flattening",
    "flatten",
]
