"""qomni — emulator, CANopen HIL, identification, FMU export and gap diagnosis of a motion-mode-changing
quasi-omnidirectional mobile platform, under one import namespace.

The subpackages ``qomni.emulator``, ``qomni.hil``, ``qomni.ident``, ``qomni.fmu`` and
``qomni.diagnosis`` live in the repository's top-level folders of the same name; the installed package
maps them under ``qomni`` (``[tool.setuptools] package-dir`` in pyproject.toml). The modules of this
folder are the composition root and the CLI.
"""
from pathlib import Path as _Path

# A source checkout (tests, benchmarks, ``python -m qomni.cli`` from the repository root) keeps the
# subpackages beside this folder, not in it: let the package find them there, as the installed
# package-dir mapping does. An installed qomni has no pyproject.toml beside it and is left alone.
_checkout = _Path(__file__).resolve().parent.parent
if (_checkout / "pyproject.toml").is_file() and (_checkout / "emulator" / "__init__.py").is_file():
    __path__.append(str(_checkout))
