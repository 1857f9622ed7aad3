"""Work spread over threads gives bitwise the same results as on one thread: the blocks'
results come back in order, and the hinge stage's row searches and opening checks do not
depend on how their rows are blocked."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from drawstring.geometry.core import parallel
from drawstring.geometry.flat.layout import extrude_flat, optimize_flat
from drawstring.geometry.flat.pose import free_openings, lay_flat
from drawstring.geometry.flat.verify import heightfield_tiles
from drawstring.geometry.hinges.placement import layout_hinges
from drawstring.geometry.hinges.sides import hinge_sides
from drawstring.geometry.tiling.linkage import build_linkage


def test_blocks_come_back_in_order_from_several_threads(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(parallel, "thread_count", lambda: 3)
    seen: set[str] = set()

    def work(k: int) -> int:
        seen.add(threading.current_thread().name)
        return k * k

    assert parallel.map_blocks(work, list(range(40))) == [k * k for k in range(40)]
    assert any(name.startswith("drawstring") for name in seen)  # not all on the caller's thread


def test_one_core_runs_the_blocks_on_the_callers_thread(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(parallel, "thread_count", lambda: 1)
    names = parallel.map_blocks(lambda _: threading.current_thread().name, [0, 1, 2])
    assert names == [threading.current_thread().name] * 3


def _saddle(n: int):
    linkage = build_linkage(np.ones((n, n), dtype=bool))
    uv = linkage.vertex_ij * (120.0 / n) - 60.0
    top, t3 = heightfield_tiles(uv, linkage.tile_corners, "saddle", 6.0, 0.004)
    return linkage, uv, top, t3


def test_hinge_stage_results_do_not_depend_on_the_thread_count(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # 12 x 12 tiles: enough rows for several plane-search blocks
    linkage, uv, top, t3 = _saddle(12)
    flat = optimize_flat(linkage, top, uv=uv, min_gap_angle_deg=12.0)
    t2 = extrude_flat(flat, t3, 6.0)
    bottom = hinge_sides(linkage, t3, 12.0)
    results = []
    for threads in (1, 2, 4):
        monkeypatch.setattr(parallel, "thread_count", lambda t=threads: t)
        openings = free_openings(linkage, lay_flat(t3), bottom, clearance=0.1, touch=1e-5)
        layout = layout_hinges(linkage, flat, t2, t3, strategy="dual")
        results.append((*openings, layout.tiles, layout.hinge_vertices))
    for other in results[1:]:
        for a, b in zip(results[0], other, strict=True):
            assert np.array_equal(a, b)
