"""Pictures of the deployment simulation: an animated GIF and single frames.

Tiles are drawn as their six quad faces (tops darker), the string as a red polyline, all from
one fixed camera whose limits cover every frame.  The output is deterministic: the same frames
give a byte-identical GIF (GIF has no timestamps; matplotlib's Agg rendering is deterministic).
"""

from __future__ import annotations

import io
import logging
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from mpl_toolkits.mplot3d import Axes3D  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402
from numpy.typing import ArrayLike  # noqa: E402
from PIL import Image  # noqa: E402

from drawstring.geometry.core.tile import TILE_FACES_SIDES_INWARD  # noqa: E402
from drawstring.geometry.core.types import FloatArray  # noqa: E402
from drawstring.geometry.simulate.tiles import side_face_midpoints  # noqa: E402

logger = logging.getLogger(__name__)


__all__ = ["route_polylines", "save_deploy_frame", "save_deploy_gif"]

_TOP = (0.93, 0.55, 0.22)
_SIDE = (0.80, 0.70, 0.60)
_STRING = (0.80, 0.05, 0.05)


def route_polylines(frames: ArrayLike, snap_pairs: ArrayLike) -> list[FloatArray]:
    """The string through every frame: the route's side-face midpoints in order, closed.

    Parameters
    ----------
    frames : (F, T, 8, 3) float, mm
    snap_pairs : (P, 4) int, ``(tile_a, side_a, tile_b, side_b)`` in route order.

    Returns
    -------
    list of F arrays (2 P + 1, 3), mm
    """
    fr = np.asarray(frames, dtype=np.float64)
    pairs = np.asarray(snap_pairs, dtype=np.int64).reshape(-1, 4)
    out = []
    for tiles in fr:
        mids = side_face_midpoints(tiles)
        a = mids[pairs[:, 0], pairs[:, 1]]
        b = mids[pairs[:, 2], pairs[:, 3]]
        line = np.stack([a, b], axis=1).reshape(-1, 3)
        out.append(np.vstack([line, line[:1]]) if len(line) else line)
    return out


def _limits(frames: FloatArray) -> tuple[FloatArray, float]:
    pts = frames.reshape(-1, 3)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    return 0.5 * (lo + hi), 0.5 * float((hi - lo).max()) * 1.05


def _draw(ax: Axes3D, tiles: FloatArray, line: FloatArray | None) -> None:
    faces = tiles[:, TILE_FACES_SIDES_INWARD].reshape(-1, 4, 3)
    colours = np.tile(np.array([_TOP] + [_SIDE] * 5), (len(tiles), 1))
    poly = Poly3DCollection(faces, facecolors=colours, edgecolors=(0.2, 0.2, 0.2), linewidths=0.3)
    ax.add_collection3d(poly)
    if line is not None and len(line):
        ax.plot(line[:, 0], line[:, 1], line[:, 2], color=_STRING, linewidth=1.5, zorder=10)


def _setup(ax: Axes3D, centre: FloatArray, half: float, elev: float, azim: float) -> None:
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(centre[2] - half, centre[2] + half)
    ax.set_box_aspect((1.0, 1.0, 1.0))
    ax.view_init(elev=elev, azim=azim)
    ax.set_axis_off()


def save_deploy_frame(
    frames: ArrayLike,
    route_polyline_per_frame: Sequence[ArrayLike] | None,
    index: int,
    path: str | Path,
    *,
    elev: float = 28.0,
    azim: float = -60.0,
    size_px: int = 480,
) -> None:
    """One frame as a PNG, with the same fixed camera as :func:`save_deploy_gif`."""
    fr = np.asarray(frames, dtype=np.float64)
    centre, half = _limits(fr)
    fig = plt.figure(figsize=(size_px / 100, size_px / 100), dpi=100)
    ax: Axes3D = fig.add_subplot(projection="3d")
    _setup(ax, centre, half, elev, azim)
    line = None
    if route_polyline_per_frame is not None:
        line = np.asarray(route_polyline_per_frame[index], dtype=np.float64)
    _draw(ax, fr[index], line)
    ax.set_title(f"frame {index + 1} / {len(fr)}", fontsize=9)
    fig.savefig(path)
    plt.close(fig)


def save_deploy_gif(
    frames: ArrayLike,
    route_polyline_per_frame: Sequence[ArrayLike] | None,
    path: str | Path,
    *,
    fps: int = 12,
    elev: float = 28.0,
    azim: float = -60.0,
    size_px: int = 480,
    max_frames: int = 60,
) -> Path:
    """Animated GIF of the deployment from one fixed camera (matplotlib + Pillow).

    Parameters
    ----------
    frames : (F, T, 8, 3) float, mm, tile vertices per frame.
    route_polyline_per_frame : F polylines (k, 3), mm, the string (see :func:`route_polylines`);
        None draws no string.
    path : output file (``.gif``).
    fps : frames per second.
    elev, azim : camera angles, degrees.
    size_px : image width and height.
    max_frames : frames are subsampled evenly to at most this many (first and last kept).

    Returns
    -------
    The path written.
    """
    fr = np.asarray(frames, dtype=np.float64)
    if fr.ndim != 4 or fr.shape[2:] != (8, 3) or len(fr) == 0:
        raise ValueError(f"frames must be (F, T, 8, 3), got {fr.shape}")
    pick = np.unique(np.linspace(0, len(fr) - 1, min(max_frames, len(fr))).round().astype(int))
    centre, half = _limits(fr)
    fig = plt.figure(figsize=(size_px / 100, size_px / 100), dpi=100)
    ax: Axes3D = fig.add_subplot(projection="3d")

    size = (int(fig.get_size_inches()[0] * fig.dpi), int(fig.get_size_inches()[1] * fig.dpi))
    images = []
    for f in pick.tolist():
        # each frame drawn once, straight into pixels (matplotlib's PillowWriter's frames,
        # without FuncAnimation's second draw of each)
        ax.cla()
        _setup(ax, centre, half, elev, azim)
        line = None
        if route_polyline_per_frame is not None:
            line = np.asarray(route_polyline_per_frame[f], dtype=np.float64)
        _draw(ax, fr[f], line)
        ax.set_title(f"deployment {100.0 * f / max(len(fr) - 1, 1):.0f} %", fontsize=9)
        pixels = io.BytesIO()
        fig.savefig(pixels, format="rgba", dpi=fig.dpi)
        rgba = pixels.getvalue()
        image = Image.frombuffer("RGBA", size, rgba, "raw", "RGBA", 0, 1)
        opaque = bool(np.frombuffer(rgba, dtype=np.uint8)[3::4].min() == 255)
        images.append(image.convert("RGB") if opaque else image)
    out = Path(path)
    images[0].save(out, save_all=True, append_images=images[1:], duration=1000 // fps, loop=0)
    plt.close(fig)
    logger.info("wrote %s (%d frames)", out.name, len(pick))
    return out
