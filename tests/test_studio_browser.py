"""drawstring studio's page end to end in a real headless Chromium (Selenium with Debian's
``chromium`` and ``chromium-driver``; skipped where they are not installed): pick the saddle,
60 tiles without CAD, run it, watch the progress reach 100 %, see the report's 3D view and
download the design as a zip."""

from __future__ import annotations

import json
import shutil
import socket
import threading
import time
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from drawstring.app.parser import build_parser
from drawstring.app.studio.serve import LOOPBACK_NAMES
from drawstring.app.studio.server import create_app
from drawstring.app.studio.service import StudioConfig

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMEDRIVER = shutil.which("chromedriver") or "/usr/bin/chromedriver"
CHROMIUM_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-dev-shm-usage",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
    "--disable-sync",
    # WebGL on the CPU: the 3D views need it with no GPU
    "--enable-unsafe-swiftshader",
    "--use-angle=swiftshader",
    "--window-size=1400,1100",
)
DEADLINE_S = 180.0

pytestmark = pytest.mark.skipif(
    not (Path(CHROMIUM).is_file() and Path(CHROMEDRIVER).is_file()),
    reason="Chromium and its driver are not installed (apt-get install chromium chromium-driver)",
)


def until(what: str, check: Callable[[], Any], timeout: float = DEADLINE_S) -> Any:
    """``check()``'s first truthy value, polled until the deadline."""
    deadline = time.monotonic() + timeout
    while True:
        value = check()
        if value:
            return value
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.1)


@pytest.fixture
def studio_url(tmp_path: Path) -> Iterator[str]:
    """A studio served by uvicorn on a free loopback port, in a thread of this process."""
    import uvicorn

    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    port = sock.getsockname()[1]
    config = StudioConfig(
        data=tmp_path / "data",
        jobs=1,
        design_parser=build_parser().get_default("subparsers")["design"],
        allowed_hosts=LOOPBACK_NAMES,
    )
    server = uvicorn.Server(uvicorn.Config(create_app(config), log_level="warning"))
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    until("the server to start", lambda: server.started, 30)
    try:
        yield f"http://127.0.0.1:{port}/"
    finally:
        server.should_exit = True
        thread.join(30)
        sock.close()


@pytest.fixture
def browser(tmp_path: Path) -> Iterator[Any]:
    webdriver = pytest.importorskip("selenium.webdriver")
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in (*CHROMIUM_FLAGS, f"--user-data-dir={tmp_path / 'chromium-profile'}"):
        options.add_argument(flag)
    downloads = tmp_path / "downloads"
    downloads.mkdir()
    options.add_experimental_option(
        "prefs",
        {"download.default_directory": str(downloads), "download.prompt_for_download": False},
    )
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    driver.execute_cdp_cmd(
        "Browser.setDownloadBehavior", {"behavior": "allow", "downloadPath": str(downloads)}
    )
    driver.downloads = downloads
    try:
        yield driver
    finally:
        driver.quit()


def test_design_the_saddle_in_the_page(studio_url: str, browser: Any) -> None:
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    js = browser.execute_script
    browser.get(studio_url)
    until("the page to load", lambda: js("return window.studio && window.studio.ready"), 60)
    Select(browser.find_element(By.ID, "target")).select_by_value("saddle")
    until(
        "the saddle in 3D",
        lambda: js("return studio.previewed === 'saddle' && studio.view.renders > 0"),
    )
    tiles = browser.find_element(By.ID, "opt-tiles")
    tiles.clear()
    tiles.send_keys("60")
    for name in ("cad", "simulate"):
        box = browser.find_element(By.ID, f"opt-{name}")
        if box.is_selected():
            box.click()
    until(
        "the estimate for 60 tiles",
        lambda: "60 tiles" in browser.find_element(By.ID, "estimate").text,
    )
    browser.find_element(By.ID, "run").click()

    # the rows are redrawn at every change: read them in one script each time
    row = (
        "const c = document.querySelector('#design-rows td.state');"
        "return c && [c.dataset.status, Number(c.dataset.progress), c.textContent]"
    )
    seen: list[float] = []

    def finished() -> list[Any] | None:
        state = js(row)
        if not state:
            return None
        if not seen or state[1] != seen[-1]:
            seen.append(state[1])
        return state if state[0] not in ("queued", "running") else None

    status, progress, text = until("the design to finish", finished)
    assert status == "done", text
    assert progress == 1.0 and "100 %" in text
    assert any(0 < p < 1 for p in seen), seen  # the bar moved by stage on its way

    frame = until("the report", lambda: browser.find_element(By.ID, "report").get_attribute("src"))
    assert frame.endswith("/report")
    browser.switch_to.frame(browser.find_element(By.ID, "report"))
    view = "return window.drawstringView && drawstringView.ready && drawstringView.renders"
    assert until("the report's 3D view", lambda: js(view)) > 0
    assert js("return drawstringView.tileCount") == 64
    browser.switch_to.default_content()

    browser.find_element(By.ID, "download-zip").click()
    downloads: Path = browser.downloads
    zipped = until("the zip", lambda: [p for p in downloads.glob("*.zip") if p.stat().st_size])
    with zipfile.ZipFile(zipped[0]) as archive:
        names = archive.namelist()
        document = json.loads(archive.read("saddle-drawstring/design.json"))
    assert "saddle-drawstring/report.html" in names and "saddle-drawstring/flat.obj" in names
    assert document["options"]["tiles"] == 60 and document["options"]["cad"] is False
