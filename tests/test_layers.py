"""Layering (docs/architecture.md): every import points down, and no module imports itself back.

The layers, lowest first, are the geometry subpackages in stage order, then ``cad``, then
``fabrication``, ``pipeline``, ``output``, ``app`` and the ``drawstring`` package's API.  Every
import counts: at module level, inside functions, and under ``TYPE_CHECKING``.
"""

from __future__ import annotations

import ast
import pkgutil
import subprocess
import sys
import tomllib
from pathlib import Path

import networkx as nx

import drawstring.geometry

ROOT = Path(__file__).resolve().parents[1]

#: Layers, lowest first: a module may import from its own layer and the ones before it.
LAYERS = (
    "geometry.core",
    "geometry.solve",
    "geometry.target",
    "geometry.flatten",
    "geometry.tiling",
    "geometry.assembled",
    "geometry.flat",
    "geometry.hinges",
    "geometry.route",
    "geometry.simulate",
    "cad",
    "fabrication",
    "pipeline",
    "output",
    "app",
    "drawstring",
)
#: The top folders holding the layers (``drawstring/`` holds only the API's ``__init__``).
FOLDERS = ("geometry", "cad", "fabrication", "pipeline", "output", "app", "drawstring")


def module_files() -> dict[str, Path]:
    """Every module of the package, by dotted name."""
    found = {}
    for folder in FOLDERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            if parts[0] != "drawstring":
                parts = ["drawstring", *parts]
            found[".".join(parts)] = path
    return found


def layer(module: str) -> int:
    """Index in :data:`LAYERS` of the layer holding ``module`` (the longest matching prefix)."""
    name = module.removeprefix("drawstring.") if module != "drawstring" else module
    best = -1
    for i, prefix in enumerate(LAYERS):
        if (name == prefix or name.startswith(prefix + ".")) and (
            best < 0 or len(prefix) > len(LAYERS[best])
        ):
            best = i
    if best < 0 and name.startswith("geometry"):
        return 0  # geometry/__init__.py: only a docstring
    assert best >= 0, f"{module} is in no layer"
    return best


def imports(module: str, path: Path, known: set[str]) -> set[str]:
    """The package's modules that ``module`` imports, anywhere in its source."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            names = [base] + [f"{base}.{alias.name}" for alias in node.names]
        else:
            continue
        for name in names:
            if name in known and name != module:
                found.add(name)
    return found


def import_graph() -> nx.DiGraph:
    files = module_files()
    graph = nx.DiGraph()
    graph.add_nodes_from(files)
    for module, path in files.items():
        for target in imports(module, path, set(files)):
            graph.add_edge(module, target)
    return graph


def test_the_layers_cover_every_module() -> None:
    files = module_files()
    assert "drawstring.geometry.solve.solver" in files and "drawstring.app.cli" in files
    for module in files:
        layer(module)


def test_no_import_cycles() -> None:
    cycles = [sorted(c) for c in nx.strongly_connected_components(import_graph()) if len(c) > 1]
    assert cycles == []


def test_every_import_points_down() -> None:
    upward = [
        f"{source} -> {target}"
        for source, target in import_graph().edges
        if layer(target) > layer(source)
    ]
    assert upward == []


def test_the_checker_sees_a_cycle_and_an_upward_import(tmp_path: Path) -> None:
    """The graph reads imports inside functions and under TYPE_CHECKING, relative or not."""
    (tmp_path / "a.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from drawstring.app import cli\n"
    )
    (tmp_path / "b.py").write_text("def f():\n    from . import a\n")
    known = {"drawstring.app.cli", "drawstring.geometry.x.a", "drawstring.geometry.x.b"}
    assert imports("drawstring.geometry.x.a", tmp_path / "a.py", known) == {"drawstring.app.cli"}
    assert imports("drawstring.geometry.x.b", tmp_path / "b.py", known) == {
        "drawstring.geometry.x.a"
    }
    assert layer("drawstring.app.cli") > layer("drawstring.geometry.tiling.grid")


def test_pyproject_lists_every_package_folder() -> None:
    """The wheel holds exactly the package folders (setuptools is given an explicit list)."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    folders = {module for module, path in module_files().items() if path.name == "__init__.py"} | {
        "drawstring.profiles"
    }
    assert set(config["packages"]) == folders


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
        "upper = [m for m in sys.modules if m.startswith(('drawstring.cad', 'drawstring.fab',\n"
        "    'drawstring.pipeline', 'drawstring.output', 'drawstring.app'))]\n"
        "print(bad, upper)\n"
        "sys.exit(1 if bad or upper else 0)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr


def test_every_module_imports() -> None:
    """Every module imports: a name moved out of a module that an importer still names fails
    here, in the CAD and export modules a ``--no-cad`` run never loads too."""
    code = (
        "import importlib, sys\n"
        f"for name in {sorted(module_files())!r}:\n"
        "    importlib.import_module(name)\n"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr[-2000:]


#: Modules allowed over :data:`MAX_MODULE_LINES` and functions over :data:`MAX_FUNCTION_LINES`
#: (``module`` or ``module:function``); each must be named, with its reason, in
#: docs/architecture.md's "Size limits".
SIZE_EXCEPTIONS: frozenset[str] = frozenset()
MAX_MODULE_LINES = 600
MAX_FUNCTION_LINES = 100


def oversized() -> list[str]:
    """Modules and functions over the size limits, as ``module`` and ``module:function``."""
    found = []
    for name, path in module_files().items():
        text = path.read_text()
        if text.count("\n") > MAX_MODULE_LINES:
            found.append(name)
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                assert node.end_lineno is not None
                if node.end_lineno - node.lineno + 1 > MAX_FUNCTION_LINES:
                    found.append(f"{name}:{node.name}")
    return sorted(found)


def test_modules_and_functions_stay_short() -> None:
    assert set(oversized()) <= SIZE_EXCEPTIONS
    architecture = (ROOT / "docs" / "architecture.md").read_text()
    assert all(f"`{name}`" in architecture for name in SIZE_EXCEPTIONS)
