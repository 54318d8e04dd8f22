"""The run directory of a campaign: its file names and the readers of what analysis needs from it.

A run directory is the interface between recording (the campaign, ``qomni decode``) and analysis
(``qomni identify``, ``validate``, ``export-fmu``, ``diagnose``); its files are listed in the README.
"""
from __future__ import annotations

import json
from pathlib import Path

from qomni.datasheet import DataSheet, Drive, Geometry, Nominal

from .result import IdentificationResult
from .recording import Signals, read_signals

METADATA = "metadata.json"
SIGNALS = "signals.csv"
IDENTIFICATION_JSON = "identification.json"
VALIDATION_JSON = "validation.json"
SINGLE_AXIS_JSON = "single_axis.json"


class RunDirectoryError(ValueError):
    """A run directory is missing a file or a campaign step."""


def step_signals(signals: Signals, name: str) -> Signals:
    """The rows of step ``name``.

    Raises:
        RunDirectoryError: the recording has no complete step of that name.
    """
    try:
        return signals.of_step(name)
    except KeyError as exc:
        raise RunDirectoryError(f"the recording has no complete '{name}' step: {exc}") from None


def load_run(run_dir: str | Path) -> tuple[Signals, DataSheet, dict]:
    """Signals, data sheet and metadata of a run directory.

    Raises:
        RunDirectoryError: a file is missing; RecordingError/DataSheetError: a file is invalid.
    """
    run_dir = Path(run_dir)
    for name in (SIGNALS, METADATA):
        if not (run_dir / name).exists():
            raise RunDirectoryError(f"{run_dir}: no {name} (not a campaign run directory?)")
    meta = json.loads((run_dir / METADATA).read_text())
    sheet = datasheet_from_metadata(meta, str(run_dir / METADATA))
    return read_signals(run_dir / SIGNALS), sheet, meta


def datasheet_from_metadata(meta: dict, source: str) -> DataSheet:
    """The data sheet stored in a run's metadata.

    Raises:
        RunDirectoryError: the entry is missing or incomplete.
    """
    ds = meta.get("datasheet")
    try:
        sheet = DataSheet(name=str(meta.get("vehicle", "vehicle")),
                          geometry=Geometry(**ds["geometry"]), drive=Drive(**ds["drive"]),
                          nominal=Nominal(**ds["nominal"]), source=source)
    except (TypeError, KeyError) as exc:
        raise RunDirectoryError(f"{source}: 'datasheet' entry missing or incomplete: {exc}") from None
    sheet._check()
    return sheet


def b_w_source(run_dir: Path, sheet: DataSheet) -> tuple[float, str]:
    """B_w for (24): the single-axis result of this run if there is one, else the data sheet's."""
    path = run_dir / SINGLE_AXIS_JSON
    if path.exists():
        data = json.loads(path.read_text())
        return float(data["pooled"]["B_w"]["value"]), "single-axis identification (lifted vehicle)"
    return sheet.nominal.B_w, "data sheet"


def load_identification(path: str | Path) -> IdentificationResult:
    """Read ``identification.json`` (a file or the run directory holding it)."""
    path = Path(path)
    if path.is_dir():
        path = path / IDENTIFICATION_JSON
    if not path.exists():
        raise RunDirectoryError(f"{path} does not exist: run 'qomni identify' first")
    return IdentificationResult.from_json_dict(json.loads(path.read_text()))
