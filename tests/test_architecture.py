"""The one rule of architecture: the emulator stands in for the hardware, so ``ident``, ``fmu`` and the
gap ``diagnosis`` never import ``emulator`` — not directly, and not through anything they import (hil.client included)."""
import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("package", ["ident", "fmu", "diagnosis"])
def test_no_module_mentions_emulator_in_an_import(package):
    offenders = []
    for path in (ROOT / package).rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                names = [node.module or ""]
            offenders += [f"{path.relative_to(ROOT)}:{node.lineno}" for n in names
                          if n in ("emulator", "qomni.emulator") or n.startswith(("emulator.", "qomni.emulator."))
                          or (n == "qomni" and any(a.name == "emulator" for a in node.names))]
    assert not offenders


def test_importing_every_module_of_ident_fmu_and_diagnosis_loads_no_emulator():
    code = """
import importlib, pkgutil, sys
from qomni import ident, fmu, diagnosis
import qomni.hil.client, qomni.hil.measurement
for pkg in (ident, fmu, diagnosis):
    for mod in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + "."):
        importlib.import_module(mod.name)
loaded = sorted(m for m in sys.modules if m == "qomni.emulator" or m.startswith("qomni.emulator.") or m == "pybullet")
print(",".join(loaded))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                         check=True)
    assert out.stdout.strip() == ""
