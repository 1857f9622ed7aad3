"""Fixtures shared by the test modules."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

HERE = Path(__file__).parent


class CommandLine:
    """``drawstring`` run as a user runs it (``python -m drawstring.app.cli``), each command in
    a fresh process forked by one server per session (tests/cli_server.py), which pays the
    interpreter's start and the imports once."""

    def __init__(self, log: Path) -> None:
        self._log = log
        self._server = subprocess.Popen(
            [sys.executable, str(HERE / "cli_server.py")],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=log.open("w"),
            text=True,
        )

    def run(self, *args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
        """Run ``drawstring ARGS`` in ``cwd`` (default: this process's working folder) with this
        process's environment; its exit status and what it wrote, as ``subprocess.run`` gives
        them."""
        server = self._server
        assert server.stdin is not None and server.stdout is not None
        request = {"argv": list(args), "cwd": str(cwd or Path.cwd()), "env": dict(os.environ)}
        server.stdin.write(json.dumps(request) + "\n")
        server.stdin.flush()
        answer = server.stdout.readline()
        assert answer, f"the command line server died: {self._log.read_text()}"
        done = json.loads(answer)
        command = [sys.executable, "-m", "drawstring.app.cli", *args]
        return subprocess.CompletedProcess(
            command, done["returncode"], done["stdout"], done["stderr"]
        )

    def close(self) -> None:
        assert self._server.stdin is not None
        self._server.stdin.close()
        self._server.wait(timeout=60)


@pytest.fixture(scope="session")
def cli(tmp_path_factory: pytest.TempPathFactory) -> Iterator[CommandLine]:
    """Runs ``drawstring`` commands in fresh processes (:class:`CommandLine`)."""
    server = CommandLine(tmp_path_factory.mktemp("cli") / "server.log")
    yield server
    server.close()
