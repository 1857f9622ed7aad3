"""Small measures of the CAD stage's solid checks (:func:`~.cad_stage.measure_cad`) for
``design.json``'s ``metrics.cad``."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray


def sunk_fraction(found: Any, pad_volumes: NDArray[np.float64]) -> float:
    """Largest share of a hinge part's volume (``pad_volumes``, mm^3, one per meshed pad)
    inside a tile (0 without hinge parts)."""
    if found is None or not np.any(found.volumes > 0):
        return 0.0
    hit = np.flatnonzero(found.volumes > 0)
    volumes = pad_volumes[found.pairs[hit, 1]]
    return float(np.max(found.volumes[hit] / np.maximum(volumes, 1e-300)))


def worst_links(
    links: NDArray[np.int64], distances: NDArray[np.float64], count: int = 5
) -> list[dict[str, Any]]:
    """The ``count`` links whose openings lie farthest apart (missing ones first): tiles and
    distance in mm (None: an opening was not found on the solid)."""
    order = np.argsort(-np.where(np.isfinite(distances), distances, np.inf), kind="stable")
    return [
        {
            "tiles": [int(links[k, 0]), int(links[k, 2])],
            "distance_mm": round(float(distances[k]), 6) if np.isfinite(distances[k]) else None,
        }
        for k in order[:count]
    ]


def finite_max(values: NDArray[np.float64]) -> float:
    """The largest finite value (0 where there is none)."""
    finite = np.asarray(values, dtype=np.float64)
    finite = finite[np.isfinite(finite)]
    return float(finite.max()) if finite.size else 0.0
