"""Shared ground of every stage: errors, named tolerances, rigid fits, byte-identical archives,
and array work spread over threads.
"""

from drawstring.geometry.core.errors import DesignError, InputError, InternalError, ThicknessError
from drawstring.geometry.core.npz import save_npz
from drawstring.geometry.core.parallel import map_blocks, thread_count
from drawstring.geometry.core.rigid import apply_rigid, rigid_copies, rigid_fit
from drawstring.geometry.core.types import BoolArray, FloatArray, IntArray

__all__ = [
    "BoolArray",
    "FloatArray",
    "IntArray",
    "DesignError",
    "InputError",
    "InternalError",
    "ThicknessError",
    "apply_rigid",
    "map_blocks",
    "rigid_copies",
    "rigid_fit",
    "save_npz",
    "thread_count",
]
