"""``drawstring studio``: its options and the server's start (uvicorn on one socket).

This module stays light: the web framework loads only when the server starts.
"""

from __future__ import annotations

import argparse
import errno
import ipaddress
import os
import secrets
import socket
import sys
import threading
import time
import webbrowser
from pathlib import Path
from typing import TYPE_CHECKING

from drawstring.geometry.core.errors import InputError

if TYPE_CHECKING:
    from drawstring.app.studio.executor import Executor, Listener
    from drawstring.app.studio.service import ExecutorFactory

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765
#: The environment variable that may hold the token instead of ``--token``.
TOKEN_ENV = "DRAWSTRING_STUDIO_TOKEN"
#: Host names a loopback studio answers to.
LOOPBACK_NAMES = ("127.0.0.1", "localhost", "::1")


def add_studio_options(p: argparse.ArgumentParser) -> None:
    """The options of ``drawstring studio``."""
    p.add_argument(
        "--host",
        default=DEFAULT_HOST,
        help=f"address to listen on (default {DEFAULT_HOST}: this machine only; any other "
        "needs --token)",
    )
    p.add_argument(
        "--port", type=int, default=DEFAULT_PORT, help=f"port (default {DEFAULT_PORT}; 0: any)"
    )
    p.add_argument(
        "--data",
        type=Path,
        help="folder of the designs, uploads and the database (default: "
        "$XDG_DATA_HOME/drawstring/studio, that is ~/.local/share/drawstring/studio)",
    )
    p.add_argument(
        "--jobs",
        type=int,
        help="designs running at once (default: one per two cores); the others wait in turn",
    )
    p.add_argument(
        "--scheduler",
        metavar="tcp://HOST:PORT",
        help="run the designs on the Dask cluster whose scheduler is at this address (started "
        "with `dask scheduler`, workers with `dask worker ADDRESS`); as many run at once as the "
        "cluster has worker threads",
    )
    p.add_argument(
        "--token",
        help=f"a secret every API request must carry (or set {TOKEN_ENV}); needed with a "
        "--host other than this machine",
    )
    p.add_argument("--open", action="store_true", help="open the page in the browser")


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_bind(host: str, token: str | None) -> None:
    """Refuse to serve another machine's network without a token."""
    if token is None and not is_loopback(host):
        example = secrets.token_urlsafe(18)
        raise InputError(
            f"--host {host} lets other machines reach the studio; give it a token that every "
            f"request must carry: --token {example} (or set {TOKEN_ENV}), then open the URL "
            "it prints"
        )
    if token is not None and len(token) < 12:
        raise InputError("--token must be at least 12 characters (a random one is best)")


def _bind(host: str, port: int) -> socket.socket:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        if exc.errno == errno.EADDRINUSE:
            raise InputError(f"port {port} is in use on {host}; give another --port") from None
        raise InputError(f"cannot listen on {host}:{port} ({exc.strerror}); check --host") from None
    sock.listen(128)
    sock.set_inheritable(True)
    return sock


def run_studio(args: argparse.Namespace, design_parser: argparse.ArgumentParser | None) -> int:
    """Serve the studio until Ctrl-C; ``design_parser`` gives the options' flags and help."""
    import uvicorn

    from drawstring.app.studio.server import create_app
    from drawstring.app.studio.service import StudioConfig, default_data_dir

    token = args.token or os.environ.get(TOKEN_ENV) or None
    check_bind(args.host, token)
    if args.jobs is not None and args.jobs < 1:
        raise InputError(f"--jobs must be 1 or more (got {args.jobs})")
    if not 0 <= args.port <= 65535:
        raise InputError(f"--port must be 0 to 65535 (got {args.port})")
    scheduler = getattr(args, "scheduler", None)
    if scheduler is not None:
        if args.jobs is not None:
            raise InputError(
                "--jobs does not apply to --scheduler: the cluster runs one design per worker "
                "thread; start more `dask worker` processes to run more at once"
            )
        from drawstring.app.executor import DaskExecutor

        with DaskExecutor(scheduler):  # refused now if it cannot be reached, not in the server
            pass
    data = (args.data or default_data_dir()).expanduser()
    try:
        data.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot use {data} as the data folder ({exc.strerror})") from None
    sock = _bind(args.host, args.port)
    port = sock.getsockname()[1]
    loopback = is_loopback(args.host)
    config = StudioConfig(
        data=data,
        jobs=args.jobs,
        token=token,
        design_parser=design_parser,
        allowed_hosts=LOOPBACK_NAMES if loopback else None,
        executor=_cluster_executor(scheduler) if scheduler is not None else None,
    )
    shown_host = f"[{args.host}]" if ":" in args.host else args.host
    url = f"http://{shown_host}:{port}/" + (f"?token={token}" if token else "")
    server = uvicorn.Server(
        uvicorn.Config(
            create_app(config),
            log_level="info" if getattr(args, "verbose", False) else "warning",
            timeout_graceful_shutdown=5,
        )
    )
    print(f"drawstring studio: {url}", flush=True)
    print(f"  designs in {data}; Ctrl-C stops it", file=sys.stderr, flush=True)
    if args.open:
        threading.Thread(target=_open_when_up, args=(server, url), daemon=True).start()
    server.run(sockets=[sock])
    return 0


def _cluster_executor(scheduler: str) -> ExecutorFactory:
    """The studio's executor on the Dask cluster at ``scheduler``."""

    def make(listener: Listener, jobs: int | None) -> Executor:
        from drawstring.app.studio.cluster import DaskJobExecutor

        return DaskJobExecutor(listener, scheduler)

    return make


def _open_when_up(server: object, url: str) -> None:
    for _ in range(200):
        if getattr(server, "started", False):
            if not webbrowser.open(url):
                print(f"no browser could be started here: open {url}", file=sys.stderr)
            return
        time.sleep(0.05)
