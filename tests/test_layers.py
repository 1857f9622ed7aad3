"""Layering (ARCHITECTURE.md section 1): geometry never loads the CAD kernel or upper layers."""

from __future__ import annotations

import pkgutil
import subprocess
import sys

import drawstring.geometry


def test_importing_all_of_geometry_leaves_the_cad_kernel_unloaded() -> None:
    modules = [
        m.name for m in pkgutil.walk_packages(drawstring.geometry.__path__, "drawstring.geometry.")
    ]
    assert "drawstring.geometry.solve.solver" in modules
    code = (
        "import importlib, sys\n"
        f"for name in {modules!r}:\n"
        "    importlib.import_module(name)\n"
        "bad = [m for m in sys.modules if m.split('.')[0] in ('OCP', 'build123d', 'cadquery')]\n"
        "upper = [m for m in sys.modules if m.startswith(('drawstring.cad', 'drawstring.fab'))]\n"
        "print(bad, upper)\n"
        "sys.exit(1 if bad or upper else 0)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
