"""``drawstring sweep``: the variants, their folders and table, on real Dask clusters.

The cluster tests start a ``dask scheduler`` and ``dask worker`` processes on 127.0.0.1 (each in
a session of its own, ended with it), and design small saddles without CAD or simulation.
"""

from __future__ import annotations

import csv
import json
import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import pytest

from drawstring.app.cli import main
from drawstring.app.parser import build_parser
from drawstring.app.sweep.command import LIST_OPTIONS
from drawstring.app.sweep.task import VariantSpec, run_variant
from drawstring.app.sweep.variants import ListOption, checked, variants
from drawstring.fabrication.profiles import load_profile
from drawstring.geometry.core.errors import InputError
from drawstring.pipeline.record import DesignOptions

BIN = Path(sys.executable).parent
#: Small, quick designs: the saddle's mesh coarse, no solids, no simulation.
QUICK = ["--resolution", "2000", "--no-cad", "--no-simulate"]
DATA = Path(__file__).parent / "data"


#: report.html's cell of design.json's size, which its timings change.
DESIGN_JSON_SIZE = re.compile(rb"(<a href='design.json'>design.json</a></td><td class=num>)[^<]*")


def same_folder(a: Path, b: Path) -> None:
    """Assert two design folders hold the same files, byte for byte (design.json's timings
    aside, and with them its size shown in report.html)."""
    files_a = sorted(p.relative_to(a).as_posix() for p in a.rglob("*") if p.is_file())
    files_b = sorted(p.relative_to(b).as_posix() for p in b.rglob("*") if p.is_file())
    assert files_a == files_b
    for name in files_a:
        data_a, data_b = (a / name).read_bytes(), (b / name).read_bytes()
        if name == "design.json":
            doc_a, doc_b = json.loads(data_a), json.loads(data_b)
            doc_a.pop("timings_s"), doc_b.pop("timings_s")
            assert doc_a == doc_b
        elif name == "report.html":
            masked = [DESIGN_JSON_SIZE.sub(rb"\1", data) for data in (data_a, data_b)]
            assert masked[0] == masked[1]
        else:
            assert data_a == data_b, name


def table(out: Path) -> list[dict[str, str]]:
    with (out / "sweep.csv").open(newline="") as f:
        return list(csv.DictReader(f))


# -- the variants ---------------------------------------------------------------------------


def test_the_variants_are_the_product_of_the_lists_named_by_what_varies() -> None:
    lists = [
        ListOption("--profile", "profile", ("fdm-dual", "my/own.toml")),
        ListOption("--tiles", "tiles", ("40", "60")),
        ListOption("--thickness", "thickness_mm", ("5.5",)),
    ]
    made = variants(DesignOptions(cad=False), lists, "saddle")
    assert [v.name for v in made] == [
        "profile-fdm-dual_tiles-40",
        "profile-fdm-dual_tiles-60",
        "profile-own_tiles-40",
        "profile-own_tiles-60",
    ]
    assert made[3].options == DesignOptions(
        profile="my/own.toml", tiles=60, thickness_mm=5.5, cad=False
    )
    assert made[0].values == (("--profile", "fdm-dual"), ("--tiles", "40"), ("--thickness", "5.5"))
    # nothing varies: one variant, named by the target
    assert [v.name for v in variants(DesignOptions(), [lists[2]], "shell.stl")] == ["shell"]


def test_list_values_are_checked_against_the_field_and_its_choices() -> None:
    with pytest.raises(InputError, match="--tiles takes whole numbers"):
        variants(DesignOptions(), [ListOption("--tiles", "tiles", ("40", "4o"))], "saddle")
    with pytest.raises(InputError, match="--size takes numbers"):
        variants(DesignOptions(), [ListOption("--size", "size_mm", ("nan",))], "saddle")
    with pytest.raises(InputError, match=r"--hinges values must be among dual, top \(got 'side'\)"):
        checked([ListOption("--hinges", "hinges", ("dual", "side"), ("dual", "top"))])
    # an option whose field the designs do not have is refused by name
    with pytest.raises(InputError, match="--nozzle is not an option of this drawstring"):
        checked([ListOption("--nozzle", "nozzle", ("0.4",))])


def test_a_list_option_the_designs_do_not_have_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--printer`` and ``--fit`` map to DesignOptions fields of their names; where this
    drawstring's designs lack one, the sweep is refused naming it."""
    sweep = build_parser().parse_args(["sweep", "saddle"])
    assert list(sweep.sweep_lists) == list(LIST_OPTIONS)
    known = {f.name for f in fields(DesignOptions)}
    missing = [flag for flag, arg in sweep.sweep_lists.items() if arg.dest not in known]
    if not missing:
        pytest.skip("every list option is an option of this drawstring's designs")
    for flag in missing:
        assert main(["sweep", "saddle", flag, "a,b", "--out", str(tmp_path / "s")]) == 2
        assert f"{flag} is not an option of this drawstring" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()


def test_bad_sweeps_are_refused_before_any_work(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    cases = [
        (["--out", str(mine)], "is not a drawstring sweep"),
        (["--tiles", "40,,60"], "none empty"),
        (["--hinges", "dual,side"], "--hinges values must be among dual, top"),
        (["--workers", "0"], "--workers must be at least 1"),
    ]
    for args, message in cases:
        out = [] if "--out" in args else ["--out", str(tmp_path / "new")]
        assert main(["sweep", "saddle", *args, *out]) == 2, args
        assert message in capsys.readouterr().err, args
    assert main(["sweep", "no-such-target.obj", "--out", str(tmp_path / "new")]) == 2
    assert "unknown target" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_status:  # the parser's own refusal
        main(["sweep", "saddle", "--workers", "2", "--scheduler", "tcp://127.0.0.1:1"])
    assert exit_status.value.code == 2
    assert "not allowed with argument" in capsys.readouterr().err
    assert not (tmp_path / "new").exists()
    assert [p.name for p in mine.iterdir()] == ["notes.txt"]


def test_a_worker_without_the_clients_files_designs_from_their_bytes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A mesh file and a profile's TOML travel with the task; a worker that does not see them
    designs from copies, and the folder is the one ``drawstring design`` writes with the paths
    as given (a refusal names them as given too)."""
    client = tmp_path / "client"
    (client / "meshes").mkdir(parents=True)
    (client / "meshes" / "dome.obj").write_bytes((DATA / "hemisphere.obj").read_bytes())
    laser = client / "laser.toml"
    laser.write_text(load_profile("laser-epdm").to_toml())
    monkeypatch.chdir(client)
    args = ["--grid", "4", "4", "--no-cad", "--no-simulate", "--quiet"]
    assert (
        main(["design", "meshes/dome.obj", "--profile", "laser.toml", *args, "--out", "cli"]) == 0
    )
    files = (
        ("meshes/dome.obj", (client / "meshes" / "dome.obj").read_bytes()),
        ("laser.toml", laser.read_bytes()),
    )
    options = DesignOptions(profile="laser.toml", grid=(4, 4), cad=False, simulate=False)
    worker = tmp_path / "worker"
    worker.mkdir()
    monkeypatch.chdir(worker)  # where neither file is
    outcome = run_variant(VariantSpec("v", "meshes/dome.obj", options, files))
    assert (outcome.status, outcome.message) == (0, "")
    written = tmp_path / "from-worker"
    for name, data in outcome.files:
        (written / name).parent.mkdir(parents=True, exist_ok=True)
        (written / name).write_bytes(data)
    same_folder(client / "cli", written)
    assert list(worker.iterdir()) == []  # nothing left behind
    # given by absolute paths the worker does not have: designed from copies, labelled as given
    far = [(f"/nowhere/{name}", data) for name, data in files]
    spec = VariantSpec("v", far[0][0], replace(options, profile=far[1][0]), tuple(far))
    outcome = run_variant(spec)
    doc = json.loads(dict(outcome.files)["design.json"])
    assert (doc["target"]["source"], doc["options"]["profile"]) == (far[0][0], far[1][0])
    assert dict(outcome.files)["tiles.npz"] == (written / "tiles.npz").read_bytes()
    broken = (("bad.toml", b"[tile\n"),)
    refused = run_variant(VariantSpec("b", "saddle", DesignOptions(profile="bad.toml"), broken))
    assert refused.status == 2 and refused.files == ()
    assert refused.message.startswith("bad.toml: not valid TOML"), refused.message


# -- on a cluster ---------------------------------------------------------------------------


@dataclass
class Cluster:
    address: str
    #: worker address -> the `dask worker` process (its nanny) running it
    workers: dict[str, subprocess.Popen[bytes]]


def _start(args: list[str], log: Path) -> subprocess.Popen[bytes]:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    with log.open("wb") as out:
        return subprocess.Popen(
            [str(BIN / "dask"), *args],
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,  # its own group: the nanny and its worker end together
            env=env,
        )


def _end(process: subprocess.Popen[Any]) -> None:
    if process.poll() is None:
        try:
            os.killpg(process.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    process.wait(timeout=30)


@pytest.fixture
def cluster(tmp_path: Path) -> Iterator[Cluster]:
    """A scheduler and two single-threaded workers on 127.0.0.1."""
    from distributed import Client

    file = tmp_path / "scheduler.json"
    local = ["--host", "127.0.0.1"]
    processes = [
        _start(
            ["scheduler", *local, "--port", "0", "--no-dashboard", "--scheduler-file", str(file)],
            tmp_path / "scheduler.log",
        )
    ]
    try:
        deadline = time.monotonic() + 60
        while not file.is_file():
            assert time.monotonic() < deadline, (tmp_path / "scheduler.log").read_text()
            assert processes[0].poll() is None, (tmp_path / "scheduler.log").read_text()
            time.sleep(0.1)
        for i in range(2):
            worker = ["worker", "--scheduler-file", str(file), *local, "--nthreads", "1"]
            worker += ["--name", f"w{i}", "--no-dashboard"]
            processes.append(_start(worker, tmp_path / f"worker{i}.log"))
        with Client(scheduler_file=str(file), timeout=60) as client:
            client.wait_for_workers(2, timeout=60)
            info = client.scheduler_info()
        workers = {
            address: processes[1 + int(worker["name"][1:])]
            for address, worker in info["workers"].items()
        }
        yield Cluster(info["address"], workers)
    finally:
        for process in processes:
            _end(process)


def _sweep(*args: str, cwd: Path | None = None) -> subprocess.Popen[str]:
    """``drawstring sweep ARGS`` in a process of its own (its local cluster with it)."""
    return subprocess.Popen(
        [sys.executable, "-m", "drawstring.app.cli", "sweep", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        cwd=cwd,
    )


def test_a_sweep_runs_on_the_clusters_workers(cluster: Cluster, tmp_path: Path) -> None:
    out = tmp_path / "sweep"
    run = _sweep(
        "saddle", "--profile", "fdm-dual,laser-epdm", "--tiles", "30,40", *QUICK,
        "--scheduler", cluster.address, "--out", str(out),
    )  # fmt: skip
    try:
        stdout, stderr = run.communicate(timeout=300)
    finally:
        _end(run)
    assert run.returncode == 0, stderr
    names = [
        "profile-fdm-dual_tiles-30",
        "profile-fdm-dual_tiles-40",
        "profile-laser-epdm_tiles-30",
        "profile-laser-epdm_tiles-40",
    ]
    assert sorted(p.name for p in out.iterdir()) == [*names, "sweep.csv", "sweep.html"]
    rows = table(out)
    assert [row["variant"] for row in rows] == names
    assert [(row["--profile"], row["--tiles"]) for row in rows] == [
        ("fdm-dual", "30"), ("fdm-dual", "40"), ("laser-epdm", "30"), ("laser-epdm", "40"),
    ]  # fmt: skip
    for row in rows:
        doc = json.loads((out / row["variant"] / "design.json").read_text())
        assert row["status"] == "0" and row["message"] == ""
        assert doc["options"]["profile"] == row["--profile"]
        assert doc["options"]["tiles"] == int(row["--tiles"])
        assert int(row["tiles"]) == doc["linkage"]["tiles"]
        assert float(row["mass_g"]) > 0 and row["deployed"] == ""  # no simulation asked
        for name in doc["files"]:
            assert (out / row["variant"] / name).is_file()
    # every variant was designed by one of the cluster's two workers, and both worked
    assert {row["worker"] for row in rows} == set(cluster.workers)
    page = (out / "sweep.html").read_text()
    for name in names:
        assert f'<a href="{name}/report.html">{name}</a>' in page
    assert "4 variants of saddle on the cluster at" in stderr
    assert "[4/4 done, 0 running]" in stderr
    assert f"wrote {out}: 4 of 4 variants (4 exit 0)" in stdout
    # a variant's folder is the one `drawstring design` writes
    alone = tmp_path / "alone"
    common = ["--quiet", "--out", str(alone)]
    assert (
        main(["design", "saddle", "--profile", "laser-epdm", "--tiles", "40", *QUICK, *common]) == 0
    )
    same_folder(alone, out / "profile-laser-epdm_tiles-40")


def test_a_sweep_loses_nothing_when_a_worker_dies(cluster: Cluster, tmp_path: Path) -> None:
    out = tmp_path / "sweep"
    run = _sweep(
        "saddle", "--hinges", "dual,top", "--tiles", "30,40", *QUICK,
        "--scheduler", cluster.address, "--out", str(out),
    )  # fmt: skip
    lines: queue.Queue[str] = queue.Queue()
    assert run.stderr is not None
    reader = threading.Thread(target=lambda: [lines.put(line) for line in run.stderr], daemon=True)
    reader.start()
    killed = ""
    seen = []
    try:
        deadline = time.monotonic() + 120
        while not killed:  # the first variant started: its worker dies
            assert time.monotonic() < deadline and run.poll() is None, "".join(seen)
            try:
                line = lines.get(timeout=0.5)
            except queue.Empty:
                continue
            seen.append(line)
            if " started on " in line:
                variant, killed = line.split("] ", 1)[1].strip().split(" started on ")
                _end(cluster.workers[killed])
        # stderr is the reader's alone (communicate would take lines from it)
        run.wait(timeout=300)
        assert run.stdout is not None
        stdout = run.stdout.read()
    finally:
        _end(run)
    reader.join(timeout=10)
    while not lines.empty():
        seen.append(lines.get())
    assert run.returncode == 0, "".join(seen)
    assert f"wrote {out}: 4 of 4 variants (4 exit 0)" in stdout
    rows = {row["variant"]: row for row in table(out)}
    assert list(rows) == [
        "tiles-30_hinges-dual", "tiles-30_hinges-top", "tiles-40_hinges-dual",
        "tiles-40_hinges-top",
    ]  # fmt: skip
    for name, row in rows.items():
        assert row["status"] == "0", row
        assert json.loads((out / name / "design.json").read_text())["linkage"]["tiles"] > 0
    (survivor,) = set(cluster.workers) - {killed}
    assert rows[variant]["worker"] == survivor  # designed again by the worker left
    assert f"{variant} started on {survivor}" in "".join(seen)


def test_a_local_sweep_records_refusals_and_goes_on(tmp_path: Path) -> None:
    """Variants refused before any work (a size out of range) or by their worker (a profile
    that is not TOML) are rows with their message; the others are designed and the sweep
    exits 3.  An earlier sweep's folder is written again."""
    (tmp_path / "bad.toml").write_text("[tile\n")
    out = tmp_path / "sweep"
    out.mkdir()
    (out / "sweep.csv").write_text("variant\n")
    run = _sweep(
        "saddle", "--profile", "fdm-dual,bad.toml", "--size", "160,-5", "--tiles", "30",
        *QUICK, "--workers", "1", "--out", "sweep", cwd=tmp_path,
    )  # fmt: skip
    try:
        stdout, stderr = run.communicate(timeout=300)
    finally:
        _end(run)
    assert run.returncode == 3, stderr
    rows = table(out)
    statuses = [(row["variant"], row["status"]) for row in rows]
    assert statuses == [
        ("profile-fdm-dual_size-160", "0"),
        ("profile-fdm-dual_size--5", "2"),
        ("profile-bad_size-160", "2"),
        ("profile-bad_size--5", "2"),
    ]
    assert rows[1]["message"].startswith("--size must be a positive number")
    assert rows[2]["message"].startswith("bad.toml: not valid TOML")
    assert rows[2]["worker"].startswith("tcp://127.0.0.1:")  # refused there
    assert sorted(p.name for p in out.iterdir()) == [
        "profile-fdm-dual_size-160", "sweep.csv", "sweep.html",
    ]  # fmt: skip
    assert "1 of 4 variants (1 exit 0, 3 exit 2)" in stdout
    assert "3 of 4 variants did not exit 0" in stderr


def test_the_executor_maps_in_order_and_names_a_failed_item() -> None:
    import math

    from drawstring.app.executor import DaskExecutor

    with DaskExecutor(workers=1) as executor:
        assert executor.describe() == "a local cluster of 1 worker process"
        assert executor.map(abs, [-3, 2, -1]) == [3, 2, 1]
        with pytest.raises(RuntimeError, match=r"task-1 failed on the cluster: ValueError"):
            executor.map(math.sqrt, [4.0, -1.0])


# -- the studio's jobs on a cluster ---------------------------------------------------------


def test_the_studios_jobs_run_on_the_clusters_workers(cluster: Cluster, tmp_path: Path) -> None:
    """``drawstring studio --scheduler``: a design job is a task on a worker, its stages come
    back as they begin, and its folder lands in the job folder as ``drawstring design`` writes
    it."""
    from fastapi.testclient import TestClient

    from drawstring.app.studio.cluster import DaskJobExecutor
    from drawstring.app.studio.server import create_app
    from drawstring.app.studio.service import StudioConfig

    config = StudioConfig(
        data=tmp_path / "studio",
        design_parser=build_parser().get_default("subparsers")["design"],
        executor=lambda listener, jobs: DaskJobExecutor(listener, cluster.address),
    )
    options = {"tiles": 40, "resolution": 2000, "cad": False, "simulate": False}
    with TestClient(create_app(config)) as client:
        assert client.get("/api/status").json()["max_running"] == 2  # one per worker thread
        created = client.post(
            "/api/designs", data={"target": "saddle", "options": json.dumps(options)}
        )
        assert created.status_code == 201, created.text
        design_id = created.json()["id"]
        stages = []
        deadline = time.monotonic() + 300
        while (record := client.get(f"/api/designs/{design_id}").json())["status"] in (
            "queued",
            "running",
        ):
            assert time.monotonic() < deadline, record
            stages.append(record["stage"])
            time.sleep(0.1)
        assert record["status"] == "done" and record["exit_status"] == 0, record
        assert record["progress"] == 1.0 and "tiles in 1 part" in record["message"]
        assert set(stages) - {""}  # stages reported from the worker as they began
        log = client.get(f"/api/designs/{design_id}/log").text
    for stage in ("target", "flatten", "flat", "route", "write"):
        assert f" stage {stage}\n" in log
    (worker,) = re.findall(r"designed on (\S+)", log)
    assert worker in cluster.workers
    alone = tmp_path / "alone"
    assert main(["design", "saddle", "--tiles", "40", *QUICK, "--quiet", "--out", str(alone)]) == 0
    same_folder(alone, tmp_path / "studio" / "jobs" / design_id / "design")


def test_the_studio_refuses_jobs_with_a_scheduler(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["studio", "--scheduler", "tcp://127.0.0.1:9", "--jobs", "2"]) == 2
    assert "--jobs does not apply to --scheduler" in capsys.readouterr().err


# -- one design's CAD on a cluster ----------------------------------------------------------


def test_a_designs_cad_on_the_cluster_writes_the_same_files(
    cluster: Cluster, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``drawstring design --scheduler``: the tile solids are built by the cluster's workers,
    and every file is the one the local run writes, byte for byte
    (design.json's timings aside)."""
    from distributed import Client, get_task_stream

    args = ["saddle", "--tiles", "30", "--resolution", "2000", "--no-simulate"]
    assert main(["design", *args, "--quiet", "--out", str(tmp_path / "local")]) == 0
    with Client(cluster.address, timeout=60) as client, get_task_stream(client) as stream:
        on_cluster = ["--scheduler", cluster.address, "--out", str(tmp_path / "cluster")]
        assert main(["design", *args, *on_cluster]) == 0
    assert "the CAD stage's tiles run on the cluster at" in capsys.readouterr().err
    # keys: the task's name, its index, a random suffix
    ran = {(str(task["key"]).rsplit("-", 2)[0], task["worker"]) for task in stream.data}
    assert {kind for kind, _ in ran} == {"cad-tiles"}
    assert {worker for _, worker in ran} == set(cluster.workers)  # both workers built parts
    local, remote = tmp_path / "local", tmp_path / "cluster"
    assert (local / "fabrication").is_dir()
    same_folder(local, remote)
