"""The architecture's boundaries (docs/architecture.md).

The one rule: the emulator stands in for the hardware, so ``qomni.ident``, ``qomni.fmu`` and
``qomni.diagnosis`` never import ``qomni.emulator`` — not directly, and not through anything they import.
Beyond it, each package depends only on the packages the architecture names, the shared vocabulary is a leaf,
and no two modules import each other in a circle.
"""
import ast
import graphlib
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("emulator", "hil", "ident", "fmu", "diagnosis")
#: The package-level arrows: who may import whom (besides itself). The leaves ``qomni.conventions`` (the
#: vocabulary), ``qomni.vehicle_interface`` (Measurement, VehicleInterface) and ``qomni.datasheet`` (what an
#: engineer knows of the vehicle) import nothing of the project;
#: the composition root (``qomni.*`` other than the leaves) may import everything.
ALLOWED = {
    "conventions": set(),
    "vehicle_interface": set(),
    "datasheet": set(),
    "emulator": {"conventions", "datasheet"},
    "hil": {"conventions", "vehicle_interface"},
    "ident": {"conventions", "vehicle_interface", "datasheet"},
    "fmu": {"conventions", "vehicle_interface", "datasheet", "ident"},
    "diagnosis": {"conventions", "datasheet", "ident"},
}
LEAVES = {"conventions", "vehicle_interface", "datasheet"}


def _modules():
    """{dotted module name: path} of every project module under the qomni namespace."""
    found = {}
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            rel = path.relative_to(ROOT).with_suffix("")
            parts = [p for p in rel.parts if p != "__init__"]
            found[".".join(["qomni", *parts])] = path
    for path in (ROOT / "qomni").rglob("*.py"):
        parts = [p for p in path.relative_to(ROOT).with_suffix("").parts if p != "__init__"]
        found[".".join(parts)] = path
    return found


def _imports(name: str, path: Path, *, top_level_only: bool):
    """Project modules that ``name`` imports (absolute and relative), optionally only at module level."""
    tree = ast.parse(path.read_text(), str(path))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    nodes = tree.body if top_level_only else list(ast.walk(tree))
    out = []
    for node in nodes:
        if isinstance(node, ast.Import):
            out += [(a.name, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            out.append((module, node.lineno))
            out += [(f"{module}.{a.name}", node.lineno) for a in node.names]     # submodules imported by name
    return [(m, line) for m, line in out if m.split(".")[0] in ("qomni", *PACKAGES)]


def _area(module: str) -> str | None:
    """The architectural area of a qomni module: a package, a leaf, or None for the composition root."""
    parts = module.split(".")
    if parts[0] != "qomni" or len(parts) < 2:
        return None
    return parts[1] if parts[1] in PACKAGES or parts[1] in LEAVES else None


@pytest.mark.parametrize("package", PACKAGES + tuple(sorted(LEAVES)))
def test_each_package_imports_only_what_the_architecture_allows(package):
    modules = _modules()
    offenders = []
    for name, path in modules.items():
        if _area(name) != package:
            continue
        for imported, line in _imports(name, path, top_level_only=False):
            where = f"{path.relative_to(ROOT)}:{line}"
            parts = imported.split(".")
            if parts[0] != "qomni":
                offenders.append(f"{where}: bare import {imported!r} (write qomni.{imported})")
            elif len(parts) > 1 and _area(imported) is None:
                offenders.append(f"{where}: imports the composition root ({imported})")
            elif _area(imported) not in (None, package, *ALLOWED[package]):
                offenders.append(f"{where}: {package} -> {_area(imported)} ({imported})")
    assert not offenders, "\n".join(offenders)


def test_no_import_circle_between_modules():
    """Module-level imports form no cycle (lazy imports inside functions are how the root defers work)."""
    modules = _modules()
    graph = {}
    for name, path in modules.items():
        deps = {m for m, _ in _imports(name, path, top_level_only=True) if m in modules and m != name}
        graph[name] = {d for d in deps if not name.startswith(d + ".")}   # a package's own __init__
    try:
        tuple(graphlib.TopologicalSorter(graph).static_order())
    except graphlib.CycleError as exc:
        pytest.fail(f"import circle: {' -> '.join(exc.args[1])}")


def test_importing_every_module_of_ident_fmu_and_diagnosis_loads_no_emulator():
    code = """
import importlib, pkgutil, sys
from qomni import ident, fmu, diagnosis
import qomni.hil.master.client, qomni.vehicle_interface
for pkg in (ident, fmu, diagnosis):
    for mod in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + "."):
        importlib.import_module(mod.name)
loaded = sorted(m for m in sys.modules if m == "qomni.emulator" or m.startswith("qomni.emulator.") or m == "pybullet")
print(",".join(loaded))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                         check=True)
    assert out.stdout.strip() == ""


@pytest.mark.parametrize("side, other", [("device", "master"), ("master", "device"), ("tools", "device"),
                                         ("tools", "master")])
def test_hil_sides_stay_apart(side, other):
    """The master side works against a real vehicle, so it never reaches into the emulated devices, nor
    they into it; the tools (hub, recorder, DBC, bus load) serve both and depend on neither."""
    offenders = []
    for name, path in _modules().items():
        if not name.startswith(f"qomni.hil.{side}."):
            continue
        offenders += [f"{path.relative_to(ROOT)}:{line}: {imported}"
                      for imported, line in _imports(name, path, top_level_only=False)
                      if imported.startswith(f"qomni.hil.{other}.") or imported == f"qomni.hil.{other}"]
    assert not offenders, "\n".join(offenders)


def test_every_package_folder_is_installed():
    """pyproject.toml lists its packages explicitly (package-dir maps the top-level folders under qomni):
    every folder with an ``__init__.py`` must be in that list, or the installed CLI misses it."""
    import tomllib

    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {name for name, path in _modules().items() if path.name == "__init__.py"}
    assert found == listed, f"not installed: {sorted(found - listed)}; listed but absent: {sorted(listed - found)}"
