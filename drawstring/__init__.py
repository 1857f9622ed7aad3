"""drawstring: curved surfaces as flat auxetic linkages that one string pull assembles.

The Python API is these names::

    from drawstring import DesignOptions, design, write_design

    result = design("saddle", DesignOptions(tiles=200, cad=False))
    write_design(result, "saddle-drawstring")

``design`` raises :class:`InputError` for input it refuses (the command line's exit status 2);
``result.problems`` and ``result.warnings`` list what the measured design misses.  The names
load on first use, so ``import drawstring`` stays cheap.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from drawstring.geometry.core.errors import InputError
    from drawstring.output.folder import write_design
    from drawstring.pipeline.record import Design, DesignOptions, Progress
    from drawstring.pipeline.run import design

#: Public name -> module that defines it.
_API = {
    "Design": "drawstring.pipeline.record",
    "DesignOptions": "drawstring.pipeline.record",
    "Progress": "drawstring.pipeline.record",
    "design": "drawstring.pipeline.run",
    "write_design": "drawstring.output.folder",
    "InputError": "drawstring.geometry.core.errors",
}

__all__ = ["Design", "DesignOptions", "InputError", "Progress", "design", "write_design"]


def __getattr__(name: str) -> Any:
    module = _API.get(name)
    if module is None:
        raise AttributeError(f"module 'drawstring' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value
