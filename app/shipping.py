"""A design's input files sent to a Dask worker as bytes, and the design run among them.

A task sends the bytes of every file its target and options name (a mesh file, a profile's
TOML), path as given.  :func:`shipped_inputs` gives the worker a temporary folder, the target
and options to design with, and a function that labels the result with the paths as given.  A
file the worker sees at the same path with the same bytes (a local cluster, a shared file
system) is read there.  Otherwise its bytes are written into the temporary folder: at the same
relative path under a working folder the design runs in, for a path given relative to the
client's working folder; elsewhere for an absolute one, the design made from that copy and
relabelled with the path as given.  Either way the folder written is the one the client would
write, byte for byte (timings aside), except that ``report.html`` cannot name the bed of a
profile given by an absolute path the worker does not see.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import shutil
import tempfile
import threading
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

from drawstring.pipeline.policy import DEFAULT_POLICY
from drawstring.pipeline.record import Design, DesignOptions

#: The layout policy of a design on a worker: the design's own, with no work run ahead in a
#: forked child.  A Dask worker runs its task in a thread of a process with threads of its own
#: (forking there is unsafe), and a nanny's worker process is daemonic (it may not have
#: children); the cluster's cores are kept busy by the other tasks instead.  Work run ahead
#: never changes a design (docs/architecture.md, determinism), so the folder is the one the
#: command line writes.
WORKER_POLICY = replace(DEFAULT_POLICY, retile_ahead=False, co_speculate=False)

#: Held while a design that names files runs: one that runs in a working folder of its own
#: changes the process's, which a worker's other threads must not see (one thread per worker
#: process is the rule, docs/scaling.md; with more, such designs take turns).
_WORKING_FOLDER = threading.Lock()

#: Files: (path as given, or relative POSIX path in a folder; bytes).
Files = tuple[tuple[str, bytes], ...]


@dataclass(frozen=True)
class Shipped:
    """What a worker designs: the target and options (copies' paths where it does not see the
    files), a temporary folder of its own, and the copies' paths -> the paths as given."""

    target: str
    options: DesignOptions
    root: Path
    given: dict[str, str]

    def relabelled(self, result: Design) -> Design:
        """``result`` labelled with the paths as given."""
        return relabelled(result, self.given)

    def shown(self, message: str) -> str:
        """A message naming the files as given."""
        for copy, path in self.given.items():
            message = message.replace(copy, path)
        return message


@contextlib.contextmanager
def shipped_inputs(files: Files, target: str, options: DesignOptions) -> Iterator[Shipped]:
    """A temporary folder holding the copies of ``files`` this worker does not see, the
    working folder changed meanwhile where relative paths need it; removed at the end."""
    lock = _WORKING_FOLDER if files else contextlib.nullcontext()
    with lock, tempfile.TemporaryDirectory(prefix="drawstring-task-") as tmp:
        root = Path(tmp)
        copies = _copies(files, root / "copies")
        moved = replace(
            options,
            **{
                f.name: copies[value]
                for f in dataclasses.fields(options)
                if isinstance(value := getattr(options, f.name), str) and value in copies
            },
        )
        given = {copy: path for path, copy in copies.items()}
        with _working_folder(files, root / "work"):
            yield Shipped(copies.get(target, target), moved, root, given)


def folder_files(folder: Path) -> Files:
    """Every file under ``folder``: relative POSIX path and bytes, in path order."""
    return tuple(
        (path.relative_to(folder).as_posix(), path.read_bytes())
        for path in sorted(folder.rglob("*"))
        if path.is_file()
    )


def _seen(path: str, data: bytes) -> bool:
    """Whether this process sees ``data`` at ``path``."""
    try:
        return Path(path).read_bytes() == data
    except OSError:
        return False


def _relative(path: str) -> bool:
    """A path inside the working folder it is given relative to."""
    return not Path(path).is_absolute() and ".." not in Path(path).parts


def _copies(files: Files, folder: Path) -> dict[str, str]:
    """Absolute path as given -> the path of its copy in ``folder``, for each such file this
    worker does not see there with those bytes."""
    copies: dict[str, str] = {}
    for i, (path, data) in enumerate(files):
        if _relative(path) or _seen(path, data):
            continue
        copy = folder / str(i) / Path(path).name  # the file's name, hence the target's, is kept
        copy.parent.mkdir(parents=True)
        copy.write_bytes(data)
        copies[path] = str(copy)
    return copies


@contextlib.contextmanager
def _working_folder(files: Files, folder: Path) -> Iterator[None]:
    """Where a relative path is not seen here with its bytes: every relative file written at
    its path under ``folder``, the process's working folder ``folder`` meanwhile."""
    relative = [(path, data) for path, data in files if _relative(path)]
    if all(_seen(path, data) for path, data in relative):
        yield
        return
    for path, data in relative:
        (folder / path).parent.mkdir(parents=True, exist_ok=True)
        (folder / path).write_bytes(data)
    here = os.getcwd()
    os.chdir(folder)
    try:
        yield
    finally:
        os.chdir(here)


def relabelled(result: Design, given: dict[str, str]) -> Design:
    """``result`` with every path of a copy replaced by the path as given, as the command line
    records it (the target's source as given; an option naming a file as ``str(Path(...))``)."""
    if not given:
        return result
    target = result.target
    if target.source in given:
        target = replace(target, source=given[target.source])
    options = replace(
        result.options,
        **{
            f.name: str(Path(given[value]))
            for f in dataclasses.fields(result.options)
            if isinstance(value := getattr(result.options, f.name), str) and value in given
        },
    )
    return replace(result, target=target, options=options)


def place_folder(folder: Path, files: dict[str, bytes]) -> None:
    """Write a design folder's files (relative path -> bytes) as ``folder``, replacing an
    earlier one whole: written into a temporary sibling, renamed into place at the end."""
    staging = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", suffix=".tmp", dir=folder.parent))
    try:
        for relative, data in files.items():
            path = staging / relative
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(data)
        os.chmod(staging, 0o755)
        if folder.exists():
            retired = Path(
                tempfile.mkdtemp(prefix=f".{folder.name}.", suffix=".old", dir=folder.parent)
            )
            os.rename(folder, retired / folder.name)
            os.rename(staging, folder)
            shutil.rmtree(retired, ignore_errors=True)
        else:
            os.rename(staging, folder)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
