"""Target surfaces: mesh files and built-in shapes, checked to be a disk and scaled to size."""

from drawstring.geometry.target.builtins import BUILTIN_TARGETS
from drawstring.geometry.target.surface import Target, load_target

__all__ = [
    "BUILTIN_TARGETS",
    "Target",
    "load_target",
]
