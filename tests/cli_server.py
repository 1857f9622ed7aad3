"""Runs ``python -m drawstring.app.cli ARGS`` for the tests, each in a fresh forked process.

Started once per test session (``cli`` in conftest.py): it imports the command line and the
modules its commands load, then reads one JSON request a line on stdin
(``{"argv": [...], "cwd": "...", "env": {...}}``).  For each it forks a child that, in that
folder and environment, runs the module as ``python -m`` does (:func:`runpy.run_module` as
``__main__``, ``sys.argv`` set, the working folder first on ``sys.path``) with stdin from
/dev/null and stdout and stderr to files, and exits with the status the interpreter would
give.  It answers with one JSON line: ``{"returncode": ..., "stdout": ..., "stderr": ...}``.
A child starts from this process as it was before any command ran (nothing configured, no
logging set up): only the interpreter's start and the imports (the CAD kernel's among them)
are shared.
"""

from __future__ import annotations

import atexit
import json
import os
import runpy
import sys
import tempfile
import traceback

import drawstring.app
import drawstring.app.cli  # first: it sets the BLAS thread count before numpy loads
import drawstring.output.folder  # noqa: F401
import drawstring.output.folder_simulation  # noqa: F401
import drawstring.output.report  # noqa: F401
import drawstring.output.writers  # noqa: F401
import drawstring.pipeline.run  # noqa: F401

try:  # what a design with CAD loads
    import build123d  # noqa: F401
    import ezdxf  # noqa: F401
except ImportError:
    pass

# run as __main__ by each child, as ``python -m`` runs it: not this module object
del sys.modules["drawstring.app.cli"], drawstring.app.cli


def _child(request: dict, out: int, err: int) -> None:
    """Body of the forked child: the command line as ``python -m`` runs it; never returns."""
    code = 1
    try:
        null = os.open(os.devnull, os.O_RDONLY)
        for fd, target in ((null, 0), (out, 1), (err, 2)):
            os.dup2(fd, target)
        sys.stdin = sys.__stdin__ = open(0, closefd=False)  # not this process's requests
        os.environ.clear()
        os.environ.update(request["env"])
        argv, cwd = request["argv"], request["cwd"]
        os.chdir(cwd)
        sys.path[0] = cwd
        sys.argv = ["drawstring/app/cli.py", *argv]
        try:
            runpy.run_module("drawstring.app.cli", run_name="__main__", alter_sys=True)
            code = 0
        except SystemExit as done:
            if done.code is None:
                code = 0
            elif isinstance(done.code, int):
                code = done.code
            else:
                print(done.code, file=sys.stderr)
        except BaseException:  # as the interpreter reports an uncaught exception
            traceback.print_exc()
        atexit._run_exitfuncs()
        sys.stdout.flush()
        sys.stderr.flush()
    finally:
        os._exit(code)


def serve() -> None:
    answers = sys.stdout
    for line in sys.stdin:
        request = json.loads(line)
        with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
            answers.flush()
            pid = os.fork()
            if pid == 0:
                _child(request, out.fileno(), err.fileno())
            _, status = os.waitpid(pid, 0)
            code = os.waitstatus_to_exitcode(status)
            texts = []
            for f in (out, err):
                f.seek(0)
                texts.append(f.read().decode("utf-8", errors="replace"))
        answers.write(json.dumps({"returncode": code, "stdout": texts[0], "stderr": texts[1]}))
        answers.write("\n")
        answers.flush()


if __name__ == "__main__":
    serve()
