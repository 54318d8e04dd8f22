"""``qomni``, the command line: one typer app (:mod:`.app`) over one console and error path
(:mod:`.console`), with the commands in modules by subject. Composition root: the only place that wires the
emulator, the bus, the campaign, the FMU export and the diagnosis together.
"""
from . import campaign, diagnose, fmu, hil, probe  # noqa: F401  (each registers its commands on the app)
from .app import app

__all__ = ["app", "main"]


def main() -> None:  # pragma: no cover
    app()
