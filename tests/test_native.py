"""What native libraries print stays off the terminal unless -v (INFO logging) is on."""

from __future__ import annotations

import ctypes
import logging

import pytest

from drawstring.geometry.core.native import native_output_silenced


def _c_print(text: str) -> None:
    libc = ctypes.CDLL(None)
    libc.printf(text.encode())
    libc.fflush(None)


def test_c_printf_is_silenced_and_python_output_comes_back(
    capfd: pytest.CaptureFixture[str],
) -> None:
    with native_output_silenced():
        _c_print("native chatter\n")
    print("after")
    out, _ = capfd.readouterr()
    assert "native chatter" not in out and "after" in out


def test_c_printf_shows_with_info_logging(capfd: pytest.CaptureFixture[str]) -> None:
    root = logging.getLogger()
    level = root.level
    root.setLevel(logging.INFO)
    try:
        with native_output_silenced():
            _c_print("native detail\n")
    finally:
        root.setLevel(level)
    assert "native detail" in capfd.readouterr().out
