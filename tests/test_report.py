"""Design report: reading the output folder, hinge/neighbour recovery, metric marks, the page,
and the page in a real (headless) Chromium: the 3D canvas renders, the deployment slider
changes the frame, a click picks a tile, no console errors and no network requests.

The browser test drives Chromium over the DevTools protocol on a pipe (``--remote-debugging-pipe``:
JSON messages ending in a NUL byte, commands on fd 3, answers on fd 4), stdlib only.  It is
skipped only where no Chromium is installed.
"""

from __future__ import annotations

import base64
import fcntl
import io
import json
import os
import queue
import shutil
import signal
import threading
import time
import webbrowser
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from drawstring.geometry.core.errors import InputError
from drawstring.geometry.core.tile import TILE_FACES
from drawstring.geometry.tiling.linkage import (
    Linkage,
    build_linkage,
    rotating_squares_layout,
)
from drawstring.output import design_folder, metric_rules, report, report_sections
from drawstring.output.report_data import FolderContents

SIDE = 20.0  # mm, tile edge of the fake design
THICKNESS = 6.0  # mm
OPENING = np.radians(40.0)  # flat layout gap angle
DOME = 0.004  # 1/mm, assembled pose: z = -DOME * r^2 at tile centres


# ----------------------------------------------------------------------------------------------
# A small fake design folder
# ----------------------------------------------------------------------------------------------


def fake_tiles(link: Linkage, opening: float, dome: float) -> np.ndarray:
    """(T, 8, 3) frustum tiles of a rotating-squares layout, lowered onto a dome by ``dome``."""
    top = rotating_squares_layout(link, opening, SIDE)  # (T, 4, 2)
    centre = top.mean(axis=1, keepdims=True)
    bottom = centre + 0.9 * (top - centre)  # frustum: bottom corners pulled in
    tiles = np.zeros((link.n_tiles, 8, 3))
    tiles[:, :4, :2], tiles[:, 4:, :2] = top, bottom
    tiles[:, :4, 2], tiles[:, 4:, 2] = THICKNESS, 0.0
    mid = centre[:, 0] - centre[:, 0].mean(axis=0)
    tiles[:, :, 2] -= dome * (mid**2).sum(axis=1)[:, None]
    return tiles


def write_obj(path: Path, tiles: np.ndarray) -> None:
    lines = ["# fake tiles"]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in tiles.reshape(-1, 3)]
    for t in range(len(tiles)):
        lines.append(f"g tile_{t}")
        for face in TILE_FACES:
            lines.append("f " + " ".join(str(8 * t + int(v) + 1) for v in face))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def boundary_loop(link: Linkage) -> list[int]:
    """Tiles of the outer ring of a full grid, counter-clockwise from the bottom-left tile."""
    n_i, n_j = link.grid_shape
    ring = [(i, 0) for i in range(n_i)] + [(n_i - 1, j) for j in range(1, n_j)]
    ring += [(i, n_j - 1) for i in range(n_i - 2, -1, -1)] + [(0, j) for j in range(n_j - 2, 0, -1)]
    index = {tuple(c): t for t, c in enumerate(link.tile_cells.tolist())}
    return [index[c] for c in ring]


def side_towards(cell: np.ndarray, other: np.ndarray) -> int:
    di, dj = (other - cell).tolist()
    return {(0, -1): 0, (1, 0): 1, (0, 1): 2, (-1, 0): 3}[(di, dj)]


def make_design_folder(folder: Path, with_deploy: bool = True) -> Linkage:
    """A 4 x 3 tile design with every file the report reads."""
    folder.mkdir(parents=True, exist_ok=True)
    link = build_linkage(np.ones((4, 3), dtype=bool))
    write_obj(folder / "flat.obj", fake_tiles(link, OPENING, 0.0))
    write_obj(folder / "assembled.obj", fake_tiles(link, 0.0, DOME))
    if with_deploy:
        share = np.linspace(0.0, 1.0, 5)
        frames = np.stack([fake_tiles(link, (1 - s) * OPENING, s * DOME) for s in share])
        np.savez_compressed(folder / "deploy.npz", frames=frames.astype(np.float32))
    loop = boundary_loop(link)
    cells = link.tile_cells
    steps = []
    for k, t in enumerate(loop):
        prev, nxt = loop[k - 1], loop[(k + 1) % len(loop)]
        enter = side_towards(cells[t], cells[prev])
        leave = side_towards(cells[t], cells[nxt])
        steps.append(
            {"gap": -1 if k == 0 else k, "tile": t, "enter_side": enter, "leave_side": leave}
        )
    route = {"steps": steps, "lift": [{"gap": 3, "tile": loop[5]}], "length_mm": 321.0}
    (folder / "route.json").write_text(json.dumps(route), encoding="utf-8")
    design = {
        "drawstring_version": "0.1.0",
        "target": {"name": "fake-dome", "size_mm": 90.0, "bbox_diagonal_mm": 100.0},
        "options": {"profile": "fdm-dual", "max_scale_factor": 2.0, "min_gap_angle_deg": 12.0},
        "profile": "fdm-dual",
        "linkage": {"tiles": link.n_tiles, "hinges": link.n_hinges, "splits": 0, "grid": [4, 3]},
        "metrics": {
            "scale_factor_max": 1.6,
            "planarity_max_mm": 0.002,
            "flat_overlap_area_mm2": 0.5,
            "route": {"length_mm": 321.0, "crossings": 0},
            "mystery_number": 7,
        },
    }
    (folder / "design.json").write_text(json.dumps(design), encoding="utf-8")
    return link


# ----------------------------------------------------------------------------------------------
# Reading and measuring
# ----------------------------------------------------------------------------------------------


def test_obj_round_trip_and_volume(tmp_path: Path) -> None:
    link = build_linkage(np.ones((2, 2), dtype=bool))
    tiles = fake_tiles(link, OPENING, 0.0)
    write_obj(tmp_path / "flat.obj", tiles)
    back = design_folder.read_obj_tiles(tmp_path / "flat.obj")
    np.testing.assert_allclose(back, tiles, atol=1e-6)
    # Frustum volume h/3 (A1 + A2 + sqrt(A1 A2)) with A1 = 400, A2 = 0.81 * 400.
    a1, a2 = SIDE**2, 0.81 * SIDE**2
    expected = THICKNESS / 3 * (a1 + a2 + np.sqrt(a1 * a2))
    np.testing.assert_allclose(design_folder.tile_volumes(tiles), expected, rtol=1e-9)


def test_obj_with_wrong_vertex_count_is_refused(tmp_path: Path) -> None:
    (tmp_path / "flat.obj").write_text("v 0 0 0\nv 1 0 0\n", encoding="utf-8")
    with pytest.raises(InputError, match="8 per tile"):
        design_folder.read_obj_tiles(tmp_path / "flat.obj")


def test_hinges_from_flat_layout_match_the_linkage() -> None:
    link = build_linkage(np.ones((4, 3), dtype=bool))
    hinges, side = design_folder.hinges_from_flat(fake_tiles(link, OPENING, 0.0))
    # Canonical (tile_a < tile_b) rows of the linkage's own hinges.
    known = link.hinges.copy()
    swap = known[:, 0] > known[:, 2]
    known[swap] = known[swap][:, [2, 3, 0, 1]]
    assert sorted(map(tuple, hinges.tolist())) == sorted(map(tuple, known.tolist()))
    assert (side == 0).all()  # frustum tiles: only the top corners coincide


def test_touching_tiles_in_assembled_pose_are_edge_neighbours() -> None:
    link = build_linkage(np.ones((3, 3), dtype=bool))
    pairs = design_folder.touching_tiles(fake_tiles(link, 0.0, 0.0))
    cells = link.tile_cells
    steps = np.abs(cells[pairs[:, 0]] - cells[pairs[:, 1]]).sum(axis=1)
    assert len(pairs) == 12 and (steps == 1).all()  # 3x3 grid: 12 shared edges, no diagonals


def test_subsample_frames_keeps_ends() -> None:
    frames = np.arange(10 * 2 * 8 * 3, dtype=float).reshape(10, 2, 8, 3)
    kept = design_folder.subsample_frames(frames, max_values=4 * 48)
    assert len(kept) == 4
    np.testing.assert_array_equal(kept[0], frames[0])
    np.testing.assert_array_equal(kept[-1], frames[-1])


def test_route_reader_accepts_lists_and_gap_only_lift_points(tmp_path: Path) -> None:
    path = tmp_path / "route.json"
    path.write_text(json.dumps({"steps": [[-1, 0, 3, 1], [5, 1, 3, 2]], "lift": [5]}))
    route = design_folder.read_route(path)
    assert route.steps.tolist() == [[-1, 0, 3, 1], [5, 1, 3, 2]]
    assert route.lift.tolist() == [[5, 1]]  # the tile the route passes at gap 5
    path.write_text("{not json")
    with pytest.raises(InputError, match="route.json"):
        design_folder.read_route(path)


def test_scale_factor_is_checked_against_the_bound_design_json_judges_it_by() -> None:
    # A re-tiling's tighter split bound only steers where the splits go: the report marks the
    # scale factor against --max-scale-factor and what gaps in [12, 90] deg absorb (1.656),
    # as design.json's warnings and problems do, not against that split bound.
    design = {
        "options": {"max_scale_factor": 2.0, "min_gap_angle_deg": 12.0},
        "metrics": {"scale_factor_max": 1.5, "split_bound": 1.38},  # tightened after a miss
    }
    marks = {row.name: row.passed for row in metric_rules.evaluate_metrics(design)}
    assert marks == {"scale_factor_max": True, "split_bound": True}
    design["metrics"] = {"scale_factor_max": 1.7, "split_bound": 1.38}
    marks = {row.name: row.passed for row in metric_rules.evaluate_metrics(design)}
    assert marks == {"scale_factor_max": False, "split_bound": True}
    design["options"] = {"max_scale_factor": 1.6, "min_gap_angle_deg": 12.0}
    design["metrics"] = {"scale_factor_max": 1.62}
    marks = {row.name: row.passed for row in metric_rules.evaluate_metrics(design)}
    assert marks == {"scale_factor_max": False}


def test_metric_marks() -> None:
    design = {
        "options": {"max_scale_factor": 2.0, "min_gap_angle_deg": 12.0},
        "target": {"bbox_diagonal_mm": 100.0},
        "metrics": {
            "scale_factor_max": 2.5,
            "flat_gap_angle_min_deg": 15.0,
            "surface_distance_max_mm": 1.0,
            "simulation": {"deployed": True},
            "cad": {
                "interference_tiles_pads_max_rel": 0.4,  # an uncut pin hole
                "print_clearance_mm": 0.6,
                "tile_gap_min_mm": 0.5,  # closer than the 0.6 mm nozzle
                "tile_pairs_closer": 2,
            },
            "something_new": 1.0,
        },
    }
    marks = {row.name: row.passed for row in metric_rules.evaluate_metrics(design)}
    assert marks == {
        "scale_factor_max": False,  # above --max-scale-factor
        "flat_gap_angle_min_deg": True,
        "surface_distance_max_mm": True,  # 1 mm <= 2 % of 100 mm
        "simulation.deployed": True,
        "cad.interference_tiles_pads_max_rel": False,
        "cad.print_clearance_mm": None,
        "cad.tile_pairs_closer": False,
        "cad.tile_gap_min_mm": False,
        "something_new": None,
    }
    design["metrics"]["cad"]["tile_gap_min_mm"] = 0.6
    marks = {row.name: row.passed for row in metric_rules.evaluate_metrics(design)}
    assert marks["cad.tile_gap_min_mm"] is True


# ----------------------------------------------------------------------------------------------
# The page
# ----------------------------------------------------------------------------------------------


def test_quality_targets_missed_are_not_failures(tmp_path: Path) -> None:
    # A design that misses only quality targets (the surface distance with the paper's
    # weights: a warning, exit 0) does not fail its checks: such targets are marked off
    # target, in amber, not "✗ ... checks fail ... Look at these before printing".
    make_design_folder(tmp_path)
    doc = json.loads((tmp_path / "design.json").read_text())
    doc["metrics"]["flat_overlap_area_mm2"] = 0.0
    doc["metrics"]["surface_distance_max_mm"] = 9.0  # over 2 % of the 100 mm diagonal
    (tmp_path / "design.json").write_text(json.dumps(doc))
    page = report.write_report(tmp_path).read_text(encoding="utf-8")
    assert "<p class='verdict warn'>⚠ 4 of 5 checks pass; 1 quality target missed: " in page
    assert "surface_distance_max_mm (the design can be made" in page
    assert "verdict fail" not in page and "⚠ off target" in page
    doc["metrics"]["flat_overlap_area_mm2"] = 0.5  # a real failure as well
    (tmp_path / "design.json").write_text(json.dumps(doc))
    page = report.write_report(tmp_path).read_text(encoding="utf-8")
    assert "✗ 1 of 5 checks fail: flat_overlap_area_mm2. Look at these before printing. " in page
    assert "Also 1 quality target missed: surface_distance_max_mm.</p>" in page  # no "can be made"
    # a quality metric that is not finite is a broken measurement: failed, not off target
    doc["metrics"]["flat_overlap_area_mm2"] = 0.0
    doc["metrics"]["surface_distance_max_mm"] = float("nan")
    (tmp_path / "design.json").write_text(json.dumps(doc))
    page = report.write_report(tmp_path).read_text(encoding="utf-8")
    assert "✗ 1 of 5 checks fail: surface_distance_max_mm" in page and "⚠" not in page


def test_an_accuracy_miss_within_the_fabrication_tolerance_is_amber_over_it_fails() -> None:
    def row(level: str) -> metric_rules.MetricRow:
        design = {
            "metrics": {"flat_edge_error_max_mm": 0.02},
            "quality": {"measures": {"flat_edge_error_max_mm": {"level": level}}},
        }
        (found,) = metric_rules.evaluate_metrics(design)
        return found

    assert row("tolerance").passed is False and row("tolerance").advisory  # off target, amber
    assert not row("out of tolerance").advisory  # a failure
    assert not row("target").advisory


def test_report_of_a_full_folder(tmp_path: Path) -> None:
    make_design_folder(tmp_path)
    (tmp_path / "flat.png").write_bytes(_tiny_png())
    page = report.write_report(tmp_path).read_text(encoding="utf-8")
    assert "drawstring design: fake-dome" in page
    assert "✗ 1 of 4 checks fail: flat_overlap_area_mm2" in page
    assert "mystery_number" in page and "data:image/png;base64," in page
    assert "321 mm" in page and "of string (bom.csv)" not in page  # route length; no CAD yet
    # with the fabrication files, the length of string to cut too, not the route's alone
    doc = json.loads((tmp_path / "design.json").read_text())
    doc["metrics"]["cad"] = {"string_length_mm": 1360.4}
    (tmp_path / "design.json").write_text(json.dumps(doc))
    again = report.write_report(tmp_path).read_text(encoding="utf-8")
    assert "321 mm; cut 1.36 m of string (bom.csv)" in again
    assert "globalThis.THREE=Object.freeze(" in page
    # Self-contained: nothing fetched from anywhere.
    assert "src='http" not in page and 'src="http' not in page and "<link" not in page
    data = _page_data(page)
    assert data["tiles"] == 12 and len(data["frames"]) == 5
    assert data["neighbour_rule"] == "sharing a hinge" and len(data["hinges"]) == 17
    assert sorted(data["neighbours"][0]) == [1, 4]  # cell (0, 0) hinges to (1, 0) and (0, 1)
    assert "does not have yet" in page and "fabrication files" in page


def test_report_of_a_folder_with_only_design_json(tmp_path: Path) -> None:
    (tmp_path / "design.json").write_text(json.dumps({"target": {"name": "bare"}}))
    page = report.render_report(tmp_path)
    data = _page_data(page)
    assert data["tiles"] == 0 and data["frames"] is None and data["route"] is None
    for missing in ("assembled.obj", "flat.obj", "route.json", "deploy.npz"):
        assert missing in page
    assert "No checks yet" in page and "not computed yet" in page


def test_report_names_an_unreadable_file(tmp_path: Path) -> None:
    make_design_folder(tmp_path, with_deploy=False)
    (tmp_path / "flat.obj").write_text("v 0 0 0\n", encoding="utf-8")
    page = report.render_report(tmp_path)
    assert "flat.obj could not be read" in page
    assert "deploy.npz is not in this design yet" in page
    assert _page_data(page)["neighbour_rule"] == "touching along an edge"


def test_lifted_grid_stands_in_for_the_assembled_tiles(tmp_path: Path) -> None:
    lines = [f"v {x} {y} {0.01 * x * y}" for y in range(3) for x in range(3)]
    lines += ["f 1 2 5 4", "f 2 3 6 5", "f 4 5 8 7", "f 5 6 9 8"]
    (tmp_path / "lifted.obj").write_text("\n".join(lines) + "\n", encoding="utf-8")
    page = report.render_report(tmp_path)
    data = _page_data(page)
    assert data["tiles"] == 4 and data["assembled_source"] == "lifted.obj"
    assert data["neighbours"] == [[1, 2], [0, 3], [0, 3], [1, 2]]
    assert "Size (lifted grid)" in page and "without thickness" in page


def test_write_report_refuses_a_missing_folder(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="not a folder"):
        report.write_report(tmp_path / "nope")


def test_open_report_writes_then_opens(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    opened: list[str] = []

    def fake_open(url: str) -> bool:
        opened.append(url)
        return True

    monkeypatch.setattr(webbrowser, "open", fake_open)
    (tmp_path / "design.json").write_text("{}")
    path, shown = report.open_report(tmp_path)
    assert path == tmp_path / "report.html" and path.is_file() and shown
    assert opened == [path.resolve().as_uri()]
    # no browser on this machine: said so
    monkeypatch.setattr(webbrowser, "open", lambda url: False)
    assert report.open_report(tmp_path) == (path, False)


def _page_data(page: str) -> dict[str, Any]:
    start = page.index('id="drawstring-data">') + len('id="drawstring-data">')
    return json.loads(page[start : page.index("</script>", start)].replace("<\\/", "</"))


def _tiny_png() -> bytes:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(2, 1.5))
    ax.plot([0, 1], [0, 1])
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=50)
    plt.close(fig)
    return buf.getvalue()


# ----------------------------------------------------------------------------------------------
# In a real browser
# ----------------------------------------------------------------------------------------------

CHROMIUM = next(
    (p for p in (shutil.which("chromium"), shutil.which("chromium-browser")) if p), None
)
CHROMIUM_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--enable-unsafe-swiftshader",
    "--use-angle=swiftshader",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-extensions",
    "--remote-debugging-pipe",
)


class Browser:
    """Headless Chromium driven over the DevTools protocol on a pipe (stdlib only)."""

    def __init__(self, executable: str, profile_dir: Path, timeout: float = 30.0) -> None:
        self.timeout = timeout
        to_chrome_r, to_chrome_w = os.pipe()
        from_chrome_r, from_chrome_w = os.pipe()
        # Copy the child's ends to free fds >= 10 so the dup2 onto fds 3 and 4 cannot clobber
        # them (the copies are close-on-exec; the dup2 targets are not).
        high_r = fcntl.fcntl(to_chrome_r, fcntl.F_DUPFD_CLOEXEC, 10)
        high_w = fcntl.fcntl(from_chrome_w, fcntl.F_DUPFD_CLOEXEC, 10)
        log = profile_dir / "chromium.log"
        actions = [
            (os.POSIX_SPAWN_OPEN, 0, os.devnull, os.O_RDONLY, 0),
            (os.POSIX_SPAWN_OPEN, 1, str(log), os.O_WRONLY | os.O_CREAT, 0o644),
            (os.POSIX_SPAWN_DUP2, 1, 2),
            (os.POSIX_SPAWN_DUP2, high_r, 3),
            (os.POSIX_SPAWN_DUP2, high_w, 4),
        ]
        argv = [executable, *CHROMIUM_FLAGS, f"--user-data-dir={profile_dir}", "about:blank"]
        self.pid = os.posix_spawn(executable, argv, os.environ, file_actions=actions)
        for fd in (to_chrome_r, from_chrome_w, high_r, high_w):
            os.close(fd)
        self._out = os.fdopen(to_chrome_w, "wb", buffering=0)
        self._in = os.fdopen(from_chrome_r, "rb", buffering=0)
        self._messages: queue.Queue[dict[str, Any]] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()
        self._next_id = 0
        self.events: list[dict[str, Any]] = []
        self.session = ""
        try:
            self._attach()
        except BaseException:
            self.close()
            raise

    def _attach(self) -> None:
        target = self.call("Target.createTarget", {"url": "about:blank"})["targetId"]
        self.session = self.call("Target.attachToTarget", {"targetId": target, "flatten": True})[
            "sessionId"
        ]
        for domain in ("Page", "Runtime", "Log", "Network"):
            self.call(f"{domain}.enable")

    def _read(self) -> None:
        buffer = b""
        while chunk := self._in.read(65536):
            buffer += chunk
            *messages, buffer = buffer.split(b"\0")
            for message in messages:
                self._messages.put(json.loads(message))

    def call(self, method: str, params: dict[str, Any] | None = None) -> dict[str, Any]:
        self._next_id += 1
        message: dict[str, Any] = {"id": self._next_id, "method": method, "params": params or {}}
        if self.session:
            message["sessionId"] = self.session
        self._out.write(json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + self.timeout
        while True:
            answer = self._messages.get(timeout=max(0.1, deadline - time.monotonic()))
            if answer.get("id") == self._next_id:
                if "error" in answer:
                    raise RuntimeError(f"{method}: {answer['error']}")
                return dict(answer.get("result", {}))
            if "method" in answer:
                self.events.append(answer)

    def evaluate(self, expression: str) -> Any:
        result = self.call(
            "Runtime.evaluate",
            {"expression": expression, "returnByValue": True, "awaitPromise": True},
        )
        if "exceptionDetails" in result:
            raise RuntimeError(f"{expression}: {result['exceptionDetails']}")
        return result["result"].get("value")

    def wait_for(self, expression: str, timeout: float = 20.0) -> Any:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            value = self.evaluate(expression)
            if value:
                return value
            time.sleep(0.05)
        raise TimeoutError(expression)

    def screenshot(self, clip: dict[str, float] | None = None) -> bytes:
        params: dict[str, Any] = {"format": "png", "captureBeyondViewport": True}
        if clip is not None:
            params["clip"] = {**clip, "scale": 1}
        return base64.b64decode(self.call("Page.captureScreenshot", params)["data"])

    def problems(self) -> list[str]:
        """Console errors, uncaught exceptions, and requests for anything not in the page."""
        out = []
        for e in self.events:
            method, params = e["method"], e.get("params", {})
            if method == "Runtime.exceptionThrown":
                out.append(f"exception: {params['exceptionDetails']}")
            elif method == "Runtime.consoleAPICalled" and params.get("type") in ("error", "assert"):
                out.append(f"console.{params['type']}: {params.get('args')}")
            elif method == "Log.entryAdded" and params["entry"].get("level") == "error":
                out.append(f"log: {params['entry'].get('text')}")
            elif method == "Network.requestWillBeSent":
                url = params["request"]["url"]
                if not url.startswith(("file:", "data:", "blob:", "about:")):
                    out.append(f"network request: {url}")
        return out

    def close(self) -> None:
        try:
            self.session = ""
            self.call("Browser.close")
        except (RuntimeError, queue.Empty, OSError):
            pass
        for _ in range(50):
            if os.waitpid(self.pid, os.WNOHANG) != (0, 0):
                return
            time.sleep(0.1)
        os.kill(self.pid, signal.SIGKILL)
        os.waitpid(self.pid, 0)


def open_page(browser: Browser, page: Path, width: int = 1280, height: int = 1000) -> None:
    browser.call(
        "Emulation.setDeviceMetricsOverride",
        {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False},
    )
    browser.call("Page.navigate", {"url": page.resolve().as_uri()})
    browser.wait_for("window.drawstringView !== undefined && window.drawstringView.ready")


def element_box(browser: Browser, selector: str) -> dict[str, float]:
    box = browser.evaluate(
        f"(() => {{ const r = document.querySelector({json.dumps(selector)})"
        ".getBoundingClientRect(); return {x: r.left + scrollX, y: r.top + scrollY, "
        "width: r.width, height: r.height}; })()"
    )
    return {k: float(v) for k, v in box.items()}


def pixels(png: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=float)


@pytest.fixture
def browser(tmp_path: Path) -> Any:
    if CHROMIUM is None:
        pytest.skip("Chromium is not installed (apt-get install chromium)")
    profile = tmp_path / "chromium-profile"
    profile.mkdir()
    b = Browser(CHROMIUM, profile)
    yield b
    b.close()


def test_page_in_a_real_browser(tmp_path: Path, browser: Browser) -> None:
    folder = tmp_path / "fake-dome-drawstring"
    make_design_folder(folder)
    page = report.write_report(folder)
    open_page(browser, page)
    view = element_box(browser, "#view canvas")
    assert view["width"] > 300 and view["height"] > 300

    # The 3D canvas renders: the assembled pose, not a blank background.
    assembled = pixels(browser.screenshot(view))
    assert assembled.std(axis=(0, 1)).max() > 10.0
    assert browser.evaluate("drawstringView.frame") == 4

    # Moving the slider (as a user would: value + input event) shows another frame.
    renders = browser.evaluate("drawstringView.renders")
    browser.evaluate(
        "(() => { const s = document.getElementById('deploy'); s.value = '0';"
        " s.dispatchEvent(new Event('input')); })()"
    )
    browser.wait_for(f"drawstringView.renders > {renders}")
    assert browser.evaluate("drawstringView.frame") == 0
    flat = pixels(browser.screenshot(view))
    assert np.abs(flat - assembled).mean() > 1.0

    # A click on the middle of the view picks a tile and names its neighbours.
    cx, cy = view["x"] + view["width"] / 2, view["y"] + view["height"] / 2
    browser.evaluate(f"window.scrollTo(0, {view['y'] - 10})")
    top = browser.evaluate("scrollY")
    for kind in ("mousePressed", "mouseReleased"):
        browser.call(
            "Input.dispatchMouseEvent",
            {"type": kind, "x": cx, "y": cy - top, "button": "left", "clickCount": 1},
        )
    info = browser.wait_for(
        "document.getElementById('tile-info').textContent.startsWith('Tile ') &&"
        " document.getElementById('tile-info').textContent"
    )
    selected = browser.evaluate("drawstringView.selected")
    assert info.startswith(f"Tile {selected}:") and "neighbour" in info

    # Toggling the tiles off leaves the edges, hinges and route: the picture changes.
    renders = browser.evaluate("drawstringView.renders")
    browser.evaluate("document.getElementById('show-tiles').click()")
    browser.wait_for(f"drawstringView.renders > {renders}")
    assert np.abs(pixels(browser.screenshot(view)) - flat).mean() > 1.0
    assert browser.problems() == []


def test_distance_colouring_in_a_real_browser(tmp_path: Path, browser: Browser) -> None:
    # tiles.npz's per-tile distances colour the 3D view on request, with their scale, and the
    # picked tile's text gives its own; without them the option is disabled.
    folder = tmp_path / "fake-dome-drawstring"
    link = make_design_folder(folder, with_deploy=False)
    mean = np.linspace(0.0, 2.0, link.n_tiles)
    np.savez(
        folder / "tiles.npz",
        assembled=fake_tiles(link, 0.0, DOME),
        surface_distance_mean_mm=mean,
        surface_distance_max_mm=mean + 0.5,
    )
    open_page(browser, report.write_report(folder))
    view = element_box(browser, "#view canvas")
    assert browser.evaluate("document.getElementById('colour-fit').disabled") is False
    assert browser.evaluate("document.getElementById('fit-scale').hidden") is True
    plain = pixels(browser.screenshot(view))
    renders = browser.evaluate("drawstringView.renders")
    browser.evaluate("document.getElementById('colour-fit').click()")
    browser.wait_for(f"drawstringView.renders > {renders}")
    assert browser.evaluate("drawstringView.colourFit") is True
    assert browser.evaluate("document.getElementById('fit-scale').hidden") is False
    assert browser.evaluate("document.getElementById('fit-scale-label').textContent").startswith(
        "0 to 2.00 mm"
    )
    assert np.abs(pixels(browser.screenshot(view)) - plain).mean() > 1.0
    assert browser.problems() == []

    bare = tmp_path / "bare-drawstring"
    make_design_folder(bare, with_deploy=False)
    open_page(browser, report.write_report(bare))
    assert browser.evaluate("document.getElementById('colour-fit').disabled") is True


def test_page_without_geometry_in_a_real_browser(tmp_path: Path, browser: Browser) -> None:
    (tmp_path / "design.json").write_text(json.dumps({"target": {"name": "bare"}}))
    open_page(browser, report.write_report(tmp_path))
    assert browser.evaluate("drawstringView.message") == "no geometry"
    assert browser.evaluate("document.getElementById('deploy').disabled") is True
    assert browser.problems() == []


# ----------------------------------------------------------------------------------------------
# Pictures of the output folder (flat.png)
# ----------------------------------------------------------------------------------------------


def _two_part_layout() -> tuple[Linkage, np.ndarray]:
    """A 4 x 3 grid split through in two parts, the right part moved 80 mm away."""
    from drawstring.geometry.tiling.linkage import Split

    link = build_linkage(np.ones((4, 3), dtype=bool), (Split("x", 2, 0, 3),))
    tiles = fake_tiles(link, OPENING, 0.0)
    tiles[link.tile_component == link.tile_component[-1], :, 0] += 80.0
    return link, tiles


def test_flat_picture_shades_no_gap_between_parts() -> None:
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    from drawstring.output import flat_picture

    link, tiles = _two_part_layout()
    assert link.n_components == 2
    split_gaps = [
        g for g in range(link.n_gaps) if len(set(link.tile_component[link.gap_tiles(g)])) > 1
    ]
    assert split_gaps, "the split leaves gaps with tiles of both parts"
    bottom = np.zeros(link.n_hinges, dtype=bool)
    angle = flat_picture.flat_gap_angles(link, tiles, bottom)
    # The moved part's split gaps measure an angle or none; either way they are not drawn.
    points = tiles[link.hinges[:, 0], link.hinges[:, 1], :2]
    fig, ax = plt.subplots()
    flat_picture.draw_flat_layout(ax, link, tiles, points, bottom, angle)
    (shaded,) = [c for c in ax.collections if c.get_gid() == "gaps"]
    assert isinstance(shaded, PolyCollection)
    drawn = [p.vertices[: len(p.vertices) - 1] for p in shaded.get_paths()]
    rings = flat_picture.gap_rings(link, tiles)
    one_part = [g for g in range(link.n_gaps) if g not in split_gaps and np.isfinite(angle[g])]
    assert len(drawn) == len(one_part) > 0
    for g in split_gaps:
        assert not any(
            len(d) >= len(rings[g]) and np.allclose(d[: len(rings[g])], rings[g]) for d in drawn
        )
    # Every shaded polygon lies within one part's tiles (none spans the 80 mm between parts).
    for d in drawn:
        assert np.ptp(d[:, 0]) < 2 * SIDE
    plt.close(fig)


def test_flat_picture_dashes_the_string_between_parts() -> None:
    from drawstring.output import flat_picture

    link, tiles = _two_part_layout()
    loop = boundary_loop(build_linkage(np.ones((4, 3), dtype=bool)))
    cells = link.tile_cells
    enter = [side_towards(cells[t], cells[loop[k - 1]]) for k, t in enumerate(loop)]
    leave = [side_towards(cells[t], cells[loop[(k + 1) % len(loop)]]) for k, t in enumerate(loop)]
    within, between = flat_picture.route_runs(
        flat_picture.side_openings(tiles),
        np.array(loop),
        np.array(enter),
        np.array(leave),
        link.tile_component,
    )
    # The loop around the grid crosses the split twice: twice from one part to the other.
    assert len(between) == 2
    for run in between:
        assert np.ptp(run[:, 0]) > 60.0  # across the space between the parts
    assert all(np.ptp(run[:, 0]) < 2 * SIDE for run in within)


def test_threading_starts_where_the_assembly_guide_does(tmp_path: Path) -> None:
    # assembly.md starts the closed route at the lift point where both string ends stand up
    # and says which route.json step is its step 1; the page says the same.  The fake route
    # lifts at gap 3, between its steps 2 and 3 (route.json indices), so step 1 is step 4.
    link = make_design_folder(tmp_path)
    loop = boundary_loop(link)
    page = report.render_report(tmp_path)
    text = page[page.index("Thread the string") :]
    assert text.startswith(
        f"Thread the string through the {len(loop)} tiles of the route, starting at lift point "
        f"A, down through the top face into tile {loop[3]}, with both string ends left standing "
        "up there (the route is a closed loop; step 1 here is step 4 of "
        "<span class=mono>route.json</span>, as in the assembly guide)"
    )
    order = " → ".join(str(t) for t in loop[3:] + loop[:3])
    assert f"<p class=mono>{order}</p>" in text
    assert f"A (tile {loop[2]} → tile {loop[3]}): the two string ends" in text


def test_flat_picture_legend_lists_only_the_hinges_and_trims_the_design_has() -> None:
    import matplotlib.pyplot as plt

    from drawstring.geometry.hinges.placement import HingeTrim
    from drawstring.output import flat_picture, pictures

    points = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    fig, ax = plt.subplots()
    pictures.draw_hinges(ax, points, np.zeros(3, dtype=bool))
    assert ax.get_legend_handles_labels()[1] == [pictures.TOP_HINGE["label"]]
    pictures.draw_hinges(ax, points, np.array([False, True, False]))
    labels = ax.get_legend_handles_labels()[1]
    assert pictures.BOTTOM_HINGE["label"] in labels
    plt.close(fig)

    # A trimmed piece is drawn as its outline seen from above; a design without trims adds
    # nothing.
    class Layout:
        trims: tuple[HingeTrim, ...] = ()

    fig, ax = plt.subplots()
    flat_picture.draw_trims(ax, Layout())  # type: ignore[arg-type]
    assert not ax.collections
    cube = np.array([[x, y, z] for x in (0, 2) for y in (0, 1) for z in (0, 3)], dtype=float)
    Layout.trims = (HingeTrim(0, 1, cube, 6.0, 2.0, 0),)
    flat_picture.draw_trims(ax, Layout())  # type: ignore[arg-type]
    outline, crosses = ax.collections
    drawn = outline.get_paths()[0].vertices[:-1]
    assert len(drawn) == 4 and np.allclose(np.ptp(drawn, axis=0), [2.0, 1.0])
    # a cross at each piece's centre carries the legend entry: tiny pieces stay visible
    assert crosses.get_label().startswith("trimmed overlap (cut away")
    assert np.allclose(crosses.get_offsets(), [[1.0, 0.5]])
    assert ax.get_legend_handles_labels()[1] == [crosses.get_label()]
    plt.close(fig)


def test_a_layout_larger_than_the_bed_names_its_print_jobs(tmp_path: Path) -> None:
    from drawstring.fabrication.profiles import load_profile

    bed = load_profile("fdm-dual")
    flat = np.zeros((2, 8, 3))
    flat[1, :, 0] = 1.5 * bed.bed_x_mm  # wider than the bed either way round
    flat[1, :, 1] = 1.5 * bed.bed_y_mm
    found = FolderContents(
        tmp_path, {"options": {"profile": "fdm-dual"}}, None, flat, None, None, ()
    )
    without = report_sections.bed_note(found)
    assert "does not fit the" in without and "split it into print jobs" in without
    (tmp_path / "fabrication").mkdir()
    jobs = [{"job": 1, "bed": 1}, {"job": 2, "bed": 2}, {"job": 3, "bed": 1, "loose": True}]
    (tmp_path / "fabrication" / "manifest.json").write_text(json.dumps({"print_jobs": jobs}))
    assert "splits it into 3 print jobs on 2 beds" in report_sections.bed_note(found)
    laser = FolderContents(
        tmp_path, {"options": {"profile": "laser-epdm"}}, None, flat, None, None, ()
    )
    assert "the loose tiles print nested on 2 beds" in report_sections.bed_note(laser)
    plywood = FolderContents(
        tmp_path, {"options": {"profile": "plywood-cnc"}}, None, flat, None, None, ()
    )
    assert "fit" not in report_sections.bed_note(plywood)  # panels on sheets: no bed to fit
    assert "cut as panels nested on the sheets" in report_sections.bed_note(plywood)
    flat[1] = 0.1 * flat[1]
    assert "(fits the" in report_sections.bed_note(found)
    # the planner's free border counts: a layout as large as the bed does not fit it
    from drawstring.fabrication.profiles import BED_MARGIN_MM

    flat[1, :, 0] = bed.bed_x_mm - BED_MARGIN_MM
    flat[1, :, 1] = 0.5 * bed.bed_y_mm
    assert "does not fit" in report_sections.bed_note(found)
