"""drawstring studio's HTTP API, driven by FastAPI's test client (issue 48).

One studio (one data folder, one job at a time) serves most tests; the restart test opens its
own twice on one folder.  Designs here are built-ins at 40 tiles without CAD or simulation;
a test waits for a job by polling its record against a deadline.
"""

from __future__ import annotations

import dataclasses
import io
import json
import os
import signal
import sqlite3
import time
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from drawstring.app.cli import main
from drawstring.app.parser import build_parser
from drawstring.app.studio.executor import default_max_running
from drawstring.app.studio.serve import check_bind
from drawstring.app.studio.server import create_app
from drawstring.app.studio.service import StudioConfig
from drawstring.fabrication.profiles import load_profile
from drawstring.geometry.core.errors import InputError
from drawstring.pipeline.record import STAGES, DesignOptions

DATA = Path(__file__).parent / "data"
FAST = {"tiles": 40, "cad": False, "simulate": False}
#: A design that runs for minutes: cancelled or interrupted long before it ends.
SLOW = {"tiles": 1600, "cad": False}
DEADLINE_S = 180.0
DESIGN_PARSER = build_parser().get_default("subparsers")["design"]


def studio_client(data: Path, **config: Any) -> TestClient:
    return TestClient(create_app(StudioConfig(data=data, design_parser=DESIGN_PARSER, **config)))


def submit(client: TestClient, target: str, options: dict[str, Any]) -> str:
    response = client.post("/api/designs", data={"target": target, "options": json.dumps(options)})
    assert response.status_code == 201, response.text
    return str(response.json()["id"])


def wait_for(client: TestClient, design_id: str, *statuses: str) -> dict[str, Any]:
    """The design's record once its status is one of ``statuses`` (polled, with a deadline)."""
    deadline = time.monotonic() + DEADLINE_S
    while True:
        record: dict[str, Any] = client.get(f"/api/designs/{design_id}").json()
        if record["status"] in statuses:
            return record
        assert time.monotonic() < deadline, f"still {record['status']}: {record}"
        time.sleep(0.05)


@pytest.fixture(scope="module")
def studio(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    with studio_client(tmp_path_factory.mktemp("studio"), jobs=1) as client:
        yield client


def test_the_catalogue_lists_targets_profiles_and_every_design_option(studio: TestClient) -> None:
    assert "saddle" in {t["name"] for t in studio.get("/api/targets").json()}
    profiles = {p["name"]: p for p in studio.get("/api/profiles").json()}
    assert {"fdm-dual", "laser-epdm", "plywood-cnc"} <= set(profiles)
    assert profiles["fdm-dual"]["defaults"]["tiles"] == 200
    assert profiles["fdm-dual"]["estimate"]["mass_g"] > 0
    options = {o["name"]: o for o in studio.get("/api/options").json()}
    fields = [f.name for f in dataclasses.fields(DesignOptions)]
    assert list(options) == [*fields, "strict"]
    assert options["size_mm"]["flag"] == "--size" and options["size_mm"]["kind"] == "float"
    assert options["cad"]["flag"] == "--no-cad" and options["cad"]["default"] is True
    assert options["hinges"]["choices"] == ["dual", "top"]
    assert options["weights"]["count"] == 3 and options["grid"]["optional"]
    assert options["tiles"]["profile_default"] == "default_tiles"
    assert "approximate number of tiles" in options["tiles"]["help"]
    preview = studio.get("/api/targets/saddle/preview").json()
    assert len(preview["faces"]) == 3 * preview["triangles"] > 0
    assert studio.get("/api/targets/nothing/preview").status_code == 404
    estimate = studio.post("/api/estimate", json={"tiles": 60, "size_mm": 200.0}).json()
    assert estimate["tiles"] == 60 and estimate["size_mm"] == 200.0 and estimate["hours"] > 0
    assert estimate["beds"]["at_least"] >= 1
    assert studio.get("/api/status").json()["max_running"] == 1


def test_a_bad_option_gets_422_with_the_message_the_command_line_prints(
    studio: TestClient, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["design", "saddle", "--tiles", "3", "--no-cad"]) == 2
    printed = capsys.readouterr().err.strip()
    for path in ("/api/estimate", "/api/designs"):
        if path == "/api/estimate":
            response = studio.post(path, json={"tiles": 3})
        else:
            response = studio.post(path, data={"target": "saddle", "options": '{"tiles": 3}'})
        assert response.status_code == 422
        assert printed == f"drawstring: error: {response.json()['detail']}"
    wrong = studio.post("/api/estimate", json={"tiles": "many"})
    assert wrong.status_code == 422 and "--tiles" in wrong.json()["detail"]
    unknown = studio.post("/api/estimate", json={"tile": 60})
    assert unknown.status_code == 422 and "'tile'" in unknown.json()["detail"]
    target = studio.post("/api/designs", data={"target": "teapot", "options": "{}"})
    assert target.status_code == 422 and "not a built-in" in target.json()["detail"]
    assert studio.post("/api/designs", data={"target": "saddle", "options": "{"}).status_code == 422
    assert studio.get("/api/designs").status_code == 200
    assert all(r["target"] != "teapot" for r in studio.get("/api/designs").json())


def test_a_design_runs_with_progress_by_stage_and_downloads_as_a_zip(studio: TestClient) -> None:
    design_id = submit(studio, "saddle", FAST)
    records = []
    with studio.stream("GET", f"/api/designs/{design_id}/events") as events:
        for line in events.iter_lines():
            if line.startswith("data: "):
                records.append(json.loads(line.removeprefix("data: ")))
    final = records[-1]
    assert final["status"] == "done" and final["exit_status"] == 0, final
    assert final["progress"] == 1.0 and "tiles in 1 part" in final["message"]
    progress = [r["progress"] for r in records]
    assert progress == sorted(progress) and any(0 < p < 1 for p in progress)
    stages = [r["stage"] for r in records if r["status"] == "running" and r["stage"]]
    order = [*STAGES, "co-optimize", "write"]
    # the stream sends the record as it is when it is read: stages that begin between two
    # reads show as the later one (the log below names every stage)
    assert len(set(stages)) >= 2 and set(stages) <= set(order)
    firsts = [order.index(s) for s in dict.fromkeys(stages) if s in STAGES]
    assert firsts == sorted(firsts)

    record = studio.get(f"/api/designs/{design_id}").json()
    numbers = {row["label"]: row["value"] for row in record["numbers"]}
    assert numbers["tiles"] == 36 and numbers["profile"] == "fdm-dual"
    assert record["has_design"] and not record["has_fabrication"]
    assert design_id in {r["id"] for r in studio.get("/api/designs").json()}
    report = studio.get(f"/api/designs/{design_id}/report")
    assert report.status_code == 200 and "drawstring-data" in report.text
    archive = zipfile.ZipFile(io.BytesIO(studio.get(f"/api/designs/{design_id}/files.zip").content))
    names = set(archive.namelist())
    assert {f"saddle-drawstring/{n}" for n in ("design.json", "report.html", "flat.obj")} <= names
    assert not any("/fabrication/" in n for n in names)
    document = json.loads(archive.read("saddle-drawstring/design.json"))
    assert document["options"]["tiles"] == 40 and document["options"]["cad"] is False
    assert sorted(n.removeprefix("saddle-drawstring/") for n in names) == document["files"]
    assert studio.get(f"/api/designs/{design_id}/fabrication.zip").status_code == 404
    log = studio.get(f"/api/designs/{design_id}/log").text
    assert all(f"stage {name} took" in log for name in ("target", "flat", "route", "write"))
    assert studio.post(f"/api/designs/{design_id}/cancel").status_code == 409


def test_refusals_by_the_loader_and_by_the_job(studio: TestClient) -> None:
    closed = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 3 1 4\n"
    refused = studio.post("/api/meshes", files={"mesh": ("../../etc/tetra.obj", closed)})
    assert refused.status_code == 422
    detail = refused.json()["detail"]
    assert detail.startswith("tetra.obj: ") and "closed" in detail and "uploads" not in detail
    text = studio.post("/api/meshes", files={"mesh": ("notes.txt", b"hello")})
    assert text.status_code == 422 and ".stl" in text.json()["detail"]
    hemisphere = (DATA / "hemisphere.obj").read_bytes()
    upload = studio.post("/api/meshes", files={"mesh": ("my cap.obj", hemisphere)})
    assert upload.status_code == 201, upload.text
    assert upload.json()["name"] == "my-cap" and upload.json()["preview"]["triangles"] > 1000
    direct = studio.post(
        "/api/designs", data={"options": json.dumps(FAST)}, files={"mesh": ("cap.obj", hemisphere)}
    )
    assert direct.status_code == 201 and direct.json()["name"] == "cap"
    assert studio.delete(f"/api/designs/{direct.json()['id']}").status_code == 204
    assert studio.get(f"/api/designs/{direct.json()['id']}").status_code == 404

    design_id = submit(studio, "peanut", {"tiles": 7, "cad": False})
    record = wait_for(studio, design_id, "refused", "done", "failed")
    assert record["status"] == "refused" and record["exit_status"] == 2
    assert "--tiles 15 or more" in record["message"] and not record["has_design"]
    assert studio.get(f"/api/designs/{design_id}/files.zip").status_code == 404
    assert studio.get("/api/designs/000000000000").status_code == 404
    assert studio.delete("/api/designs/000000000000").status_code == 404


def test_an_uploaded_profile_is_checked_and_offered(studio: TestClient) -> None:
    toml = load_profile("fdm-dual").to_toml().replace('name = "fdm-dual"', 'name = "my-printer"')
    added = studio.post("/api/profiles", files={"profile": ("my printer.toml", toml.encode())})
    assert added.status_code == 201, added.text
    name = added.json()["name"]
    assert added.json()["title"] == "my-printer" and name.startswith("upload:")
    assert name in studio.get("/api/options").json()[0]["choices"]
    assert studio.post("/api/estimate", json={"profile": name}).json()["profile"] == "my-printer"
    broken = toml.replace("thickness_mm = 6.0", "thickness_mm = -1.0")
    refused = studio.post("/api/profiles", files={"profile": ("bad.toml", broken.encode())})
    assert refused.status_code == 422
    assert refused.json()["detail"].startswith("bad.toml: tile.thickness_mm = -1.0")


def test_cancel_a_queued_and_a_running_design(studio: TestClient) -> None:
    slow = submit(studio, "saddle", SLOW)
    queued = submit(studio, "dome", FAST)
    wait_for(studio, slow, "running")
    assert studio.get(f"/api/designs/{queued}").json()["status"] == "queued"
    cancelled = studio.post(f"/api/designs/{queued}/cancel").json()
    assert cancelled["status"] == "cancelled"
    assert studio.get(f"/api/designs/{slow}").json()["status"] == "running"
    studio.post(f"/api/designs/{slow}/cancel")
    record = wait_for(studio, slow, "cancelled", "done", "failed")
    assert record["status"] == "cancelled" and record["exit_status"] is None
    assert studio.post(f"/api/designs/{slow}/cancel").status_code == 409


def test_a_job_that_dies_fails_alone(studio: TestClient) -> None:
    design_id = submit(studio, "saddle", SLOW)
    wait_for(studio, design_id, "running")
    executor = studio.app.state.studio.executor  # type: ignore[attr-defined]
    deadline = time.monotonic() + DEADLINE_S
    while executor._running[design_id].process.pid is None:
        assert time.monotonic() < deadline
        time.sleep(0.05)
    os.kill(executor._running[design_id].process.pid, signal.SIGKILL)
    record = wait_for(studio, design_id, "failed", "done", "cancelled")
    assert record["status"] == "failed" and "SIGKILL" in record["message"]
    assert studio.get("/api/targets").status_code == 200


def test_after_a_restart_running_designs_are_interrupted_and_run_again(tmp_path: Path) -> None:
    with studio_client(tmp_path, jobs=1) as first:
        running = submit(first, "saddle", FAST)
        queued = submit(first, "dome", SLOW)
        wait_for(first, running, "running")
    database = sqlite3.connect(tmp_path / "studio.sqlite3")
    status = dict(database.execute("SELECT id, status FROM designs").fetchall())
    assert status == {running: "interrupted", queued: "queued"}
    # as a crash leaves it: the server never marked it
    database.execute("UPDATE designs SET status = 'running' WHERE id = ?", (running,))
    database.commit()
    database.close()
    with studio_client(tmp_path, jobs=1) as second:
        record = second.get(f"/api/designs/{running}").json()
        assert record["status"] == "interrupted" and "run it again" in record["message"]
        wait_for(second, queued, "running")  # queued again on start
        second.post(f"/api/designs/{queued}/cancel")
        wait_for(second, queued, "cancelled")
        again = second.post(f"/api/designs/{running}/run").json()
        assert again["status"] in ("queued", "running") and again["exit_status"] is None
        record = wait_for(second, running, "done", "failed", "refused")
        assert record["status"] == "done" and record["has_design"]
        assert not list((tmp_path / "jobs" / running).glob(".design.*"))


def test_token_origin_host_and_size_limits(tmp_path: Path) -> None:
    token = "a-long-enough-token"
    with studio_client(tmp_path, token=token, allowed_hosts=("testserver",)) as client:
        assert client.get("/api/targets").status_code == 401
        assert client.get("/api/targets", headers={"Authorization": f"Bearer {token}"}).is_success
        assert client.get(f"/api/targets?token={token}").is_success
        assert client.get("/").status_code == 200
        cross = client.post(
            f"/api/estimate?token={token}", json={}, headers={"Origin": "http://evil.example"}
        )
        assert cross.status_code == 403
        elsewhere = client.get(f"/api/targets?token={token}", headers={"Host": "evil.example"})
        assert elsewhere.status_code == 421
    with studio_client(tmp_path / "small", upload_limit_bytes=1000) as client:
        big = client.post("/api/meshes", files={"mesh": ("big.obj", b"v 0 0 0\n" * 500)})
        assert big.status_code == 413
    with pytest.raises(InputError, match="--token"):
        check_bind("0.0.0.0", None)
    check_bind("127.0.0.1", None)
    check_bind("::1", None)
    assert main(["studio", "--host", "0.0.0.0", "--data", str(tmp_path)]) == 2
    assert default_max_running() == max(1, len(os.sched_getaffinity(0)) // 2)
