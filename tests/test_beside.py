"""Writers run beside the caller (:class:`~drawstring.fabrication.beside.Beside`): what each
returned comes back in the order started, what one raised is raised as it was, and a child
that dies is a one-line error; forked or not, the same answers."""

from __future__ import annotations

import errno
import multiprocessing
import os
import signal
import time
from pathlib import Path

import pytest

from drawstring.fabrication.beside import Beside, can_fork
from drawstring.geometry.core.errors import InputError, InternalError

MODES = [1, pytest.param(None, id="forked")]


def _needs_fork(workers: int | None) -> None:
    if workers is None and not can_fork():
        pytest.skip("processes cannot fork here")


def _write(path: Path, text: str) -> list[str]:
    path.write_text(text, encoding="utf-8")
    return [path.name]


def _refuse(path: Path) -> None:
    raise InputError(f"{path.name} refused; retry with: --tiles 40")


def _full_disk(path: Path) -> None:
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))


class _Unpicklable(Exception):
    def __init__(self, a: int, b: int) -> None:
        super().__init__(f"{a} and {b}")


def _unpicklable(_: Path) -> None:
    raise _Unpicklable(1, 2)


def _die(_: Path) -> None:
    os.kill(os.getpid(), signal.SIGKILL)


def _sleep(path: Path) -> None:
    time.sleep(60)
    path.write_text("late", encoding="utf-8")


@pytest.mark.parametrize("workers", MODES)
def test_results_in_the_order_started(tmp_path: Path, workers: int | None) -> None:
    _needs_fork(workers)
    beside = Beside(workers)
    assert beside.forks == (workers is None)
    for k in range(3):
        beside.start(f"{k}.txt", _write, tmp_path / f"{k}.txt", f"file {k}")
    assert beside.results() == [["0.txt"], ["1.txt"], ["2.txt"]]
    assert [(tmp_path / f"{k}.txt").read_text() for k in range(3)] == ["file 0", "file 1", "file 2"]
    assert beside.results() == []
    assert multiprocessing.active_children() == []


@pytest.mark.parametrize("workers", MODES)
@pytest.mark.parametrize(
    ("write", "kind", "message"),
    [
        (_refuse, InputError, "bad.txt refused; retry with: --tiles 40"),
        (_full_disk, OSError, f"[Errno {errno.ENOSPC}] {os.strerror(errno.ENOSPC)}: "),
    ],
)
def test_an_error_is_raised_as_the_writer_raised_it(
    tmp_path: Path, workers: int | None, write: object, kind: type, message: str
) -> None:
    _needs_fork(workers)
    beside = Beside(workers)
    with pytest.raises(kind) as raised:
        beside.start("bad.txt", write, tmp_path / "bad.txt")
        beside.results()
    assert type(raised.value) is kind
    assert str(raised.value).startswith(message)
    if isinstance(raised.value, OSError):
        assert raised.value.filename == str(tmp_path / "bad.txt")


def test_an_error_that_does_not_cross_a_pipe_keeps_its_name(tmp_path: Path) -> None:
    _needs_fork(None)
    beside = Beside()
    beside.start("bad.txt", _unpicklable, tmp_path / "bad.txt")
    with pytest.raises(InternalError, match=r"^_Unpicklable: 1 and 2$"):
        beside.results()


def test_a_child_that_dies_is_one_line_naming_its_file(tmp_path: Path) -> None:
    _needs_fork(None)
    beside = Beside()
    beside.start("flat.step", _die, tmp_path / "flat.step")
    with pytest.raises(InternalError) as raised:
        beside.results()
    assert str(raised.value) == (
        f"the process writing flat.step ended without finishing it (exit code {-signal.SIGKILL})"
    )


def test_a_failure_stops_the_writers_still_running(tmp_path: Path) -> None:
    _needs_fork(None)
    beside = Beside()
    beside.start("bad.txt", _refuse, tmp_path / "bad.txt")
    beside.start("late.txt", _sleep, tmp_path / "late.txt")
    start = time.perf_counter()
    with pytest.raises(InputError):
        beside.results()
    assert time.perf_counter() - start < 30
    assert multiprocessing.active_children() == []
    assert not (tmp_path / "late.txt").exists()


def test_a_child_prints_no_traceback(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    _needs_fork(None)
    beside = Beside()
    beside.start("bad.txt", _full_disk, tmp_path / "bad.txt")
    with pytest.raises(OSError):
        beside.results()
    assert "Traceback" not in capfd.readouterr().err


def test_a_design_folder_written_beside_is_the_serial_one(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A small design with CAD and its deployment, written with the pictures, the STEP files
    and the 3MF in forked children, and written with fork unavailable: the same bytes in
    every file."""
    _needs_fork(None)
    from drawstring.fabrication import beside
    from drawstring.output.folder import write_design
    from drawstring.pipeline.record import DesignOptions
    from drawstring.pipeline.run import design

    children: list[str] = []

    class Counted(beside._Child):
        def __init__(self, what: str, *args: object) -> None:
            children.append(what)
            super().__init__(what, *args)

    monkeypatch.setattr(beside, "_Child", Counted)
    result = design("saddle", DesignOptions(grid=(3, 3), resolution=1500))
    forked = write_design(result, tmp_path / "forked")
    assert sorted(children) == ["assembled.step", "flat.step", "print.3mf", "the pictures"]
    monkeypatch.setattr(beside, "can_fork", lambda: False)
    serial = write_design(result, tmp_path / "serial")
    assert len(children) == 4
    names = sorted(p.relative_to(forked).as_posix() for p in forked.rglob("*") if p.is_file())
    assert "fabrication/flat.step" in names and "deploy.gif" in names
    assert names == sorted(
        p.relative_to(serial).as_posix() for p in serial.rglob("*") if p.is_file()
    )
    for name in names:
        assert (forked / name).read_bytes() == (serial / name).read_bytes(), name


def _in_a_daemon(path: Path) -> None:
    beside = Beside()
    beside.start(path.name, _write, path, "forks" if beside.forks else "here")
    beside.results()


def test_a_daemonic_process_writes_here(tmp_path: Path) -> None:
    """A daemonic process (a Dask nanny's worker) may not have children: its writers run in
    it, one after the other."""
    _needs_fork(None)
    process = multiprocessing.get_context("fork").Process(
        target=_in_a_daemon, args=(tmp_path / "a.txt",), daemon=True
    )
    process.start()
    process.join(60)
    assert process.exitcode == 0
    assert (tmp_path / "a.txt").read_text() == "here"
