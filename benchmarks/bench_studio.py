"""Load test of drawstring studio on loopback (issue 48): 20 designs submitted at once.

``drawstring studio`` is started on a free port with a fresh data folder; 20 built-in designs
(the built-ins in turn, 40 tiles, no CAD) are posted together from 20 threads, and while they
run a prober asks the API what the page asks (the design list, one design, the status, an
estimate, the page itself) every quarter second, and an event stream counts the records it is
sent.  Targets: every design finishes (none lost, each ``done``), every API call is answered in
under 1 s while the jobs run.  ``python benchmarks/bench_studio.py`` prints the row and writes
it to ``benchmarks/results.json`` as ``bench_studio``; ``run.py --stages`` runs it with the
other stage benchmarks.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import httpx

from drawstring.geometry.target.builtins import BUILTIN_TARGETS

HERE = Path(__file__).resolve().parent
DESIGNS = 20
OPTIONS = {"tiles": 40, "cad": False}
#: The slowest API answer allowed while the jobs run, seconds.
TARGET_API_S = 1.0
PROBE_EVERY_S = 0.25
DEADLINE_S = 1800.0


def _start(data: Path) -> tuple[subprocess.Popen[str], str]:
    server = subprocess.Popen(
        [sys.executable, "-m", "drawstring.app.cli", "studio", "--port", "0", "--data", str(data)],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    assert server.stdout is not None
    line = server.stdout.readline()  # "drawstring studio: http://127.0.0.1:PORT/"
    if "http://" not in line:
        server.kill()
        raise RuntimeError(f"the studio did not start: {line!r}")
    return server, line.split()[-1].rstrip("/")


def _probe(url: str, ids: list[str], stop: threading.Event, times: list[float]) -> None:
    """Ask what the page asks, in turn, until ``stop``; each answer's time into ``times``."""
    asks = [
        ("GET", "/api/designs", None),
        ("GET", "/api/status", None),
        ("POST", "/api/estimate", {"tiles": 40}),
        ("GET", "/", None),
    ]
    with httpx.Client(base_url=url, timeout=30) as client:
        turn = 0
        while not stop.is_set():
            method, path, body = asks[turn % len(asks)]
            if turn % 5 == 4 and ids:
                method, path, body = "GET", f"/api/designs/{ids[turn % len(ids)]}", None
            start = time.perf_counter()
            response = client.request(method, path, json=body)
            times.append(time.perf_counter() - start)
            response.raise_for_status()
            turn += 1
            stop.wait(PROBE_EVERY_S)


def _listen(url: str, stop: threading.Event, counted: list[int]) -> None:
    """Count the design records the event stream sends, until ``stop`` or the server ends."""
    with httpx.Client(base_url=url, timeout=None) as client:
        try:
            with client.stream("GET", "/api/events") as events:
                for line in events.iter_lines():
                    if line.startswith("event: design"):
                        counted[0] += 1
                    if stop.is_set():
                        return
        except httpx.HTTPError:  # the server stopped with the stream open
            return


def run() -> list[dict[str, Any]]:
    names = list(BUILTIN_TARGETS)
    with tempfile.TemporaryDirectory(prefix="studio-bench-") as folder:
        server, url = _start(Path(folder))
        stop = threading.Event()
        times: list[float] = []
        events = [0]
        ids: list[str] = []
        try:
            with httpx.Client(base_url=url, timeout=60) as client:
                jobs = client.get("/api/status").json()["max_running"]
                listener = threading.Thread(target=_listen, args=(url, stop, events), daemon=True)
                listener.start()
                prober = threading.Thread(target=_probe, args=(url, ids, stop, times), daemon=True)
                prober.start()

                def submit(i: int) -> str:
                    form = {"target": names[i % len(names)], "options": json.dumps(OPTIONS)}
                    response = client.post("/api/designs", data=form)
                    response.raise_for_status()
                    return str(response.json()["id"])

                start = time.perf_counter()
                with ThreadPoolExecutor(DESIGNS) as pool:
                    ids.extend(pool.map(submit, range(DESIGNS)))
                submitted = time.perf_counter() - start
                deadline = time.monotonic() + DEADLINE_S
                while True:
                    records = {r["id"]: r for r in client.get("/api/designs").json()}
                    if all(records[i]["status"] not in ("queued", "running") for i in ids):
                        break
                    if time.monotonic() > deadline:
                        raise RuntimeError("the designs did not finish in time")
                    time.sleep(1.0)
                wall = time.perf_counter() - start
                stop.set()
                prober.join()
        finally:
            stop.set()
            server.terminate()
            server.wait(30)
    statuses = [records[i]["status"] for i in ids]
    runs = [records[i]["finished"] - records[i]["started"] for i in ids if records[i]["started"]]
    ordered = sorted(times)
    row = {
        "case": f"{DESIGNS} designs at once (built-ins in turn, 40 tiles, no CAD)",
        "cores": os.cpu_count(),
        "jobs_at_once": jobs,
        "designs": DESIGNS,
        "done": statuses.count("done"),
        "lost": DESIGNS - len(statuses),
        "not_done": sorted(set(statuses) - {"done"}),
        "submit_all_s": round(submitted, 3),
        "wall_s": round(wall, 1),
        "design_run_median_s": round(statistics.median(runs), 1) if runs else None,
        "api_calls": len(times),
        "api_median_ms": round(1000 * statistics.median(ordered), 1),
        "api_p95_ms": round(1000 * ordered[int(0.95 * (len(ordered) - 1))], 1),
        "api_max_ms": round(1000 * ordered[-1], 1),
        "api_target_s": TARGET_API_S,
        "api_within_target": ordered[-1] < TARGET_API_S,
        "events_received": events[0],
    }
    return [row]


def main() -> None:
    rows = run()
    for key, value in rows[0].items():
        print(f"{key:22} {value}")
    path = HERE / "results.json"
    results: dict[str, Any] = json.loads(path.read_text()) if path.exists() else {}
    results["bench_studio"] = rows
    results.setdefault("machine", {"cores": os.cpu_count(), "python": platform.python_version()})
    path.write_text(json.dumps(results, indent=2) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
