"""The CLI's console and its one way to fail: the error printed plainly, exit status 2, no traceback.

User text (paths, section and key names, units in brackets) is never read as rich console markup: the
console has markup off and styles are applied with :class:`rich.text.Text`.
"""
from __future__ import annotations

import typer
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.text import Text

console = Console(markup=False, highlight=False)


def fail(message: str) -> None:
    """Print ``error: message`` plainly and end the command with exit status 2."""
    console.print(Text.assemble(("error:", "bold red"), " ", str(message)))
    raise typer.Exit(2)


def guarded(fn):
    """``fn()``, or :func:`fail` with the message of a run-directory, recording, data-sheet or identifiability
    error, or of the operating system's refusal to read or write a path (a directory where a file is read,
    a file where a folder is written, no permission)."""
    from qomni.datasheet import DataSheetError
    from qomni.ident.least_squares import IdentifiabilityError
    from qomni.ident.rundir import RunDirectoryError
    from qomni.ident.recording import RecordingError

    try:
        return fn()
    except (RunDirectoryError, RecordingError, IdentifiabilityError, DataSheetError, FileNotFoundError) as exc:
        fail(str(exc))
    except OSError as exc:
        fail(f"{exc.filename}: {exc.strerror}" if exc.filename and exc.strerror else str(exc))


def progress() -> Progress:
    return Progress(TextColumn("{task.description:<14}", markup=False), BarColumn(),
                    TextColumn("{task.percentage:>5.1f} %"), TimeElapsedColumn(), TimeRemainingColumn(),
                    console=console, transient=False)


def run_with_progress(label: str, make_runner):
    """``make_runner(on_progress)`` under a progress bar; ``on_progress(done, total, step_name)``."""
    with progress() as bar:
        task = bar.add_task(label, total=None)

        def on_progress(done: int, total: int, name: str) -> None:
            if done % 25 == 0 or done == total:
                bar.update(task, completed=done, total=total, description=name)

        return make_runner(on_progress)
