"""The run directory of a campaign: its file names and the readers of what analysis needs from it.

A run directory is the interface between recording (the campaign, ``qomni decode``) and analysis
(``qomni identify``, ``validate``, ``export-fmu``, ``diagnose``); its files are listed in the README.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from qomni.conventions import WHEELS
from qomni.datasheet import DataSheet, DataSheetError, vehicle_differences

from .result import IdentificationResult
from .recording import Signals, read_signals
from .plausibility import check_coverage, check_drives, check_modes, check_ranges
from .wheel_slip import check_rolling

METADATA = "metadata.json"
#: The run-directory format this version writes and reads (metadata.json ``format``).
RUN_FORMAT = "qomni-run/1"
SIGNALS = "signals.csv"
IDENTIFICATION_JSON = "identification.json"
#: A digital twin reference run's stamp: what the twin and its campaign were made from (qomni.twin).
TWIN_STAMP = "twin.json"
VALIDATION_JSON = "validation.json"
SINGLE_AXIS_JSON = "single_axis.json"
SINGLE_AXIS_DIR = "single_axis"
BUS_BLF = "bus.blf"
BUS_CANDUMP = "bus.log"
BUS_DBC = "bus.dbc"
FIG_IDENTIFICATION = "fig5_identification.png"
FIG_VALIDATION = "fig6_validation.png"
COMPARISON_JSON = "comparison.json"
#: What a campaign writes into its run directory; a single-axis run writes SINGLE_AXIS_FILES beside it.
CAMPAIGN_FILES = (SIGNALS, METADATA, BUS_BLF, BUS_CANDUMP, BUS_DBC, IDENTIFICATION_JSON, VALIDATION_JSON,
                  FIG_IDENTIFICATION, FIG_VALIDATION, COMPARISON_JSON)
SINGLE_AXIS_FILES = (SINGLE_AXIS_DIR, SINGLE_AXIS_JSON)


class RunDirectoryError(ValueError):
    """A run directory is missing a file or a campaign step, or a file of it is invalid; the message names
    the file and the key."""


def file_sha256(path: Path) -> str:
    """Hex SHA-256 of a file's bytes (identifies the recording a model was identified from).

    Raises:
        RunDirectoryError: the file does not exist."""
    digest = hashlib.sha256()
    try:
        with open(path, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                digest.update(chunk)
    except FileNotFoundError:
        raise RunDirectoryError(f"{path} does not exist") from None
    return digest.hexdigest()


class _DuplicateKey(Exception):
    pass


def _unique_keys(pairs: list[tuple[str, object]]) -> dict:
    """A JSON object's pairs as a dict, refusing a key given twice (``json`` would keep the last)."""
    out: dict = {}
    for key, value in pairs:
        if key in out:
            raise _DuplicateKey(key)
        out[key] = value
    return out


def read_json(path: Path) -> dict:
    """A JSON object from ``path``.

    Raises:
        RunDirectoryError: the file is missing, truncated, not JSON, not an object, or gives a key twice in
            one object (file and position or key).
    """
    try:
        data = json.loads(path.read_text(), object_pairs_hook=_unique_keys)
    except FileNotFoundError:
        raise RunDirectoryError(f"{path} does not exist") from None
    except _DuplicateKey as exc:
        raise RunDirectoryError(f"{path}: key {exc.args[0]!r} appears twice in one object; which value holds "
                                "is not defined (an edited file?)") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise RunDirectoryError(f"{path}: not valid JSON ({exc}); a truncated or edited file?") from None
    if not isinstance(data, dict):
        raise RunDirectoryError(f"{path}: expected a JSON object, got {type(data).__name__}")
    return data


def write_json(path: Path, data: dict) -> None:
    """Write ``data`` as JSON atomically: a temporary file beside ``path``, then renamed over it, so a
    reader never sees a half-written file and a failed write leaves the old one."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(data, indent=2))
    os.replace(tmp, path)


def completed_steps(meta: dict, source: str) -> list[dict]:
    """The steps the run completed, from ``segments`` of metadata.json: each ``{name, k, t_start, t_end}``
    with finite, ordered times, one segment after the other.

    Raises:
        RunDirectoryError: no list, or the list or an entry is malformed (file and entry named).
    """
    if "segments" not in meta:
        raise RunDirectoryError(f"{source}: no 'segments' (the steps the campaign completed, [] for a decoded "
                                "log): without them no step's rows can be checked complete")
    segments = meta["segments"]
    if not isinstance(segments, list):
        raise RunDirectoryError(f"{source}: 'segments' must be a list")
    out = []
    for i, seg in enumerate(segments):
        try:
            name, k, t0, t1 = str(seg["name"]), int(seg["k"]), float(seg["t_start"]), float(seg["t_end"])
        except (TypeError, KeyError, ValueError) as exc:
            raise RunDirectoryError(f"{source}: segments[{i}] is incomplete or not numeric: {exc}") from None
        if not (math.isfinite(t0) and math.isfinite(t1) and t0 <= t1):
            raise RunDirectoryError(f"{source}: segments[{i}] ('{name}'): t_start {t0} must not exceed "
                                    f"t_end {t1}, both finite")
        if k not in (1, 2, 3, 4):
            raise RunDirectoryError(f"{source}: segments[{i}] ('{name}'): motion mode k = {k} is not one of "
                                    "the paper's four (1 to 4)")
        if out and t0 < out[-1]["t_end"] - 1e-9:
            raise RunDirectoryError(f"{source}: segments[{i}] ('{name}') starts at {t0} s, before "
                                    f"segments[{i - 1}] ('{out[-1]['name']}') ends at {out[-1]['t_end']} s: the "
                                    "campaign completes its segments one after the other, in time order")
        out.append({"name": name, "k": k, "t_start": t0, "t_end": t1})
    return out


def check_status(meta: dict, source: str) -> None:
    """``status`` of metadata.json, where recorded, is one a campaign writes: ``running`` (it never
    ended: killed), ``complete``, or ``aborted: …``.

    Raises:
        RunDirectoryError: any other value (file and value named)."""
    status = meta.get("status", "complete")
    if not isinstance(status, str) or not (status in ("complete", "running") or status.startswith("aborted")):
        raise RunDirectoryError(f"{source}: status {status!r} is not one a campaign writes ('complete', "
                                "'running' or 'aborted: …')")


def check_settings(meta: dict, source: str) -> None:
    """The campaign and controller settings metadata.json records, where it records them, are ones a
    campaign drives (:class:`.campaign.CampaignSettings`, :class:`.controller.ControllerSettings`). The
    digital twin drives them again; a run whose settings are edited to something no campaign drives
    (NaN, a string, a negative duration) did not come from one.

    Raises:
        RunDirectoryError: a setting refused or unknown (file and key named)."""
    from dataclasses import fields

    from .campaign import recorded_settings
    from .controller import ControllerSettings

    known = {f.name for f in fields(ControllerSettings)}     # a setting since retired is not driven again

    def controller(values: dict) -> ControllerSettings:
        return ControllerSettings(**{k: v for k, v in values.items() if k in known})

    for key, read in (("settings", recorded_settings), ("controller", controller)):
        if key not in meta:
            continue
        if not isinstance(meta[key], dict):
            raise RunDirectoryError(f"{source}: '{key}' must be a table of settings")
        try:
            read(meta[key])
        except TypeError as exc:
            raise RunDirectoryError(f"{source}: '{key}' holds a setting no campaign knows: {exc}") from None
        except ValueError as exc:
            raise RunDirectoryError(f"{source}: {exc}") from None


def step_signals(signals: Signals, name: str) -> Signals:
    """The rows of step ``name``.

    Raises:
        RunDirectoryError: the recording has no complete step of that name.
    """
    try:
        return signals.of_step(name)
    except KeyError as exc:
        raise RunDirectoryError(f"the recording has no complete '{name}' step: {exc}") from None


def require_complete(meta: dict, steps, source: str) -> None:
    """Refuse a run whose metadata says the campaign did not complete ``steps``.

    Raises:
        RunDirectoryError: a step is not among the completed segments (names the run's status).
    """
    done = {seg["name"] for seg in completed_steps(meta, source)}
    missing = [name for name in steps if name not in done]
    if missing:
        status = meta.get("status", "unknown")
        raise RunDirectoryError(f"{source}: the campaign did not complete {', '.join(missing)} "
                                f"(status: {status}); the rows of an incomplete step are never used")


def load_run(run_dir: str | Path) -> tuple[Signals, DataSheet, dict]:
    """Signals, data sheet and metadata of a run directory.

    Raises:
        RunDirectoryError: a file is missing, or metadata.json's status, segments or settings are not a
        campaign's;
        RecordingError/DataSheetError: a file is invalid, signals.csv
        lacks rows (of a step the metadata says completed, or between two rows), a drive's signals are
        dead or disagree, a torque or steering angle lies beyond the data sheet's limits, a step's
        steering is off its mode's configuration (:mod:`.plausibility`), or a wheel did not roll
        (:mod:`.wheel_slip`).
    """
    run_dir = Path(run_dir)
    for name in (SIGNALS, METADATA):
        if not (run_dir / name).exists():
            raise RunDirectoryError(f"{run_dir}: no {name} (not a campaign run directory?)")
    meta = read_json(run_dir / METADATA)
    sheet = datasheet_from_metadata(meta, str(run_dir / METADATA))
    check_status(meta, str(run_dir / METADATA))
    check_settings(meta, str(run_dir / METADATA))
    signals = read_signals(run_dir / SIGNALS)
    check_coverage(signals, completed_steps(meta, str(run_dir / METADATA)), sheet.drive.cycle_time,
                   str(run_dir / SIGNALS))
    check_drives(signals, str(run_dir / SIGNALS))
    check_ranges(signals, sheet.drive.max_torque, sheet.geometry.steering_limit, str(run_dir / SIGNALS))
    check_modes(signals, sheet.geometry, str(run_dir / SIGNALS))
    check_rolling(signals, sheet, str(run_dir / SIGNALS))
    return complete_rows(signals, meta, str(run_dir / METADATA)), sheet, meta


def load_repaired_run(run_dir: str | Path, repair: bool = True):
    """:func:`load_run` with isolated glitches in the drives' signals repaired (:mod:`.spikes`).

    Returns (signals, data sheet, metadata, :class:`~.spikes.SpikeReport`); with ``repair`` false the
    signals as recorded and the report of what would have been repaired.
    Raises: as :func:`load_run`; RecordingError: a column more corrupt than single glitches."""
    from .spikes import repair_spikes

    signals, sheet, meta = load_run(run_dir)
    signals, report = repair_spikes(signals, str(Path(run_dir) / SIGNALS), repair)
    return signals, sheet, meta, report


def complete_rows(signals: Signals, meta: dict, source: str) -> Signals:
    """The rows of the steps the run completed. A run that stopped (Ctrl-C, a fault, the steering near
    its stops) keeps every row it recorded, but the step it stopped in never reached its end: its rows
    are left out, so no later step finds a partial step to fit (``step_signals`` then names the step
    and the run's status). A recording without segments (a decoded foreign log) is kept whole.

    Raises:
        RunDirectoryError: the segments are malformed.
    """
    segments = completed_steps(meta, source)
    if not segments:
        return signals
    done = {seg["name"] for seg in segments}
    keep = np.isin(signals.step, sorted(done)) | np.isin(signals.step, ["align", "rest"])
    return signals if keep.all() else signals.select(keep)


def datasheet_from_metadata(meta: dict, source: str) -> DataSheet:
    """The data sheet stored in a run's metadata (its ``datasheet`` entry), checked as a data-sheet file is.

    Raises:
        RunDirectoryError: the metadata's ``format`` is not :data:`RUN_FORMAT`; the entry is missing, a
            table or key is missing or unknown, a value is not a number or impossible (:meth:`DataSheet.from_tables`); the message names the file and key.
    """
    if meta.get("format", RUN_FORMAT) != RUN_FORMAT:
        raise RunDirectoryError(f"{source}: format {meta['format']!r} is not one this version reads ({RUN_FORMAT})")
    ds = meta.get("datasheet")
    if not isinstance(ds, dict):
        raise RunDirectoryError(f"{source}: 'datasheet' entry missing or not an object")
    try:
        return DataSheet.from_tables(ds, str(meta.get("vehicle", "vehicle")), f"{source} datasheet")
    except DataSheetError as exc:
        raise RunDirectoryError(str(exc)) from None


def _measured(path: Path, data: dict, keys: tuple[str, ...], positive: bool,
              with_std: bool = True, signed: bool = False) -> tuple[float, float | None]:
    """``(value, std)`` of the measurement at ``keys`` in ``data`` (a JSON object read from ``path``): a
    finite value, positive or non-negative (any sign where ``signed``), and (``with_std``) a positive,
    finite std; std None without.

    Raises:
        RunDirectoryError: missing, not a number or out of range; the message names the file and key."""
    key = ".".join(keys)
    fields = "value/std" if with_std else "value"
    try:
        node = data
        for k in keys:
            node = node[k]
        value = float(node["value"])
        std = float(node["std"]) if with_std else None
    except (KeyError, TypeError, ValueError) as exc:
        raise RunDirectoryError(f"{path}: {key}.{fields} missing or not a number: {exc}") from None
    value_ok = math.isfinite(value) and (signed or (value > 0 if positive else value >= 0))
    if not (value_ok and (std is None or (math.isfinite(std) and std > 0))):
        what = "finite" if signed else "finite, positive" if positive else "finite, non-negative"
        raise RunDirectoryError(f"{path}: {key} must be a {what} value"
                                + (f" with a positive, finite std, got value {value}, std {std}" if with_std
                                   else f", got {value}"))
    return value, std


def b_w_source(run_dir: Path, sheet: DataSheet) -> tuple[float, str]:
    """B_w for (24): the single-axis result of this run if there is one, else the data sheet's.

    Raises:
        RunDirectoryError: ``single_axis.json`` has no positive, finite ``pooled.B_w.value``, or was measured
        on another vehicle (:func:`check_lifted_vehicle`)."""
    path = run_dir / SINGLE_AXIS_JSON
    if path.exists():
        data = read_json(path)
        _check_lifted_of_run(path, data, run_dir)
        value, _ = _measured(path, data, ("pooled", "B_w"), positive=True, with_std=False)
        return value, "single-axis identification (lifted vehicle)"
    return sheet.nominal.B_w, "data sheet"


def check_lifted_vehicle(path: Path, data: dict, sheet: DataSheet) -> None:
    """``single_axis.json`` (``data``, read from ``path``) measured the wheels of ``sheet``'s vehicle: the
    vehicle name and data sheet geometry and drive it records are ``sheet``'s. A campaign replaced with
    ``--force --no-single-axis`` keeps the lifted measurement beside it, and another vehicle's wheels would
    set B_w and the wheels' friction without a word. A file that does not record its vehicle is taken as
    the run's.

    Raises: RunDirectoryError: names both vehicles and what differs."""
    if not isinstance(data.get("vehicle"), str):
        return
    differ = [f"vehicle name ('{data['vehicle']}' against '{sheet.name}')"] \
        if data["vehicle"] != sheet.name else []
    if isinstance(data.get("datasheet"), dict):
        tables = {"nominal": asdict(sheet.nominal), **data["datasheet"]}
        differ += vehicle_differences(DataSheet.from_tables(tables, data["vehicle"], f"{path} datasheet"), sheet)
    if differ:
        raise RunDirectoryError(f"{path}: measured on the lifted wheels of '{data['vehicle']}', the run is of "
                                f"'{sheet.name}' (they differ in {', '.join(differ)}): measure this vehicle's "
                                "wheels (qomni single-axis) or remove the file")


def _check_lifted_of_run(path: Path, data: dict, run_dir: Path) -> None:
    """:func:`check_lifted_vehicle` against the vehicle ``run_dir``'s metadata.json records, where it does."""
    meta_path = run_dir / METADATA
    if not meta_path.is_file():
        return
    meta = read_json(meta_path)
    if isinstance(meta.get("vehicle"), str) and "datasheet" in meta:
        check_lifted_vehicle(path, data, datasheet_from_metadata(meta, str(meta_path)))   # named as recorded


#: Parameters of p₁ that the single-axis run measures on lifted wheels (``single_axis.json``, pooled).
LIFTED_WHEEL_PARAMETERS = ("d_vw", "d_cw")


@dataclass(frozen=True)
class LiftedMeasurement:
    """What the campaign's single-axis run measured on the lifted vehicle (``single_axis.json``), wheel
    side: ``friction`` ``{"d_vw": (value [N m s/rad], std), "d_cw": (value [N m], std)}`` pooled over the
    wheels, and ``wheels`` ``{wheel: {"B_w" | "d_vw" | "d_cw": (value, std)}}`` each with its own drive
    (kg m², N m s/rad, N m); ``breakaway``: the wheel joints' breakaway excess (breakaway / d_cw − 1,
    its standard error) from the lifted breakaway ramps (:mod:`qomni.ident.breakaway`), None for a run
    without them."""

    friction: dict[str, tuple[float, float]]
    wheels: dict[str, dict[str, tuple[float, float]]]
    breakaway: tuple[float, float] | None = None


def read_lifted(run_dir: str | Path) -> LiftedMeasurement | None:
    """The run's lifted-vehicle measurement (:class:`LiftedMeasurement`), the file read once; None when
    the run has no ``single_axis.json``.

    Raises:
        RunDirectoryError: a value or std is missing or not finite, a B_w not positive, a friction
            negative or a std not positive, a breakaway excess not finite or below −1 (the message names
            the file and key); the wheels of another vehicle (:func:`check_lifted_vehicle`)."""
    path = Path(run_dir) / SINGLE_AXIS_JSON
    if not path.exists():
        return None
    data = read_json(path)
    _check_lifted_of_run(path, data, Path(run_dir))
    breakaway = None
    if isinstance(data.get("breakaway"), dict) and data["breakaway"].get("excess") is not None:
        excess, std = _measured(path, data, ("breakaway", "excess"), positive=False, signed=True)
        if excess < -1.0:
            raise RunDirectoryError(f"{path}: breakaway.excess must be >= -1 (a breakaway torque >= 0), "
                                    f"got {excess}")
        breakaway = (excess, std)
    friction = {name: _measured(path, data, ("pooled", name), positive=False)
                for name in LIFTED_WHEEL_PARAMETERS}
    wheels = {wheel: {name: _measured(path, data, ("wheels", wheel, name), positive=name == "B_w")
                      for name in ("B_w", *LIFTED_WHEEL_PARAMETERS)}
              for wheel in WHEELS}
    return LiftedMeasurement(friction, wheels, breakaway)


def identification_vehicle(path: str | Path) -> tuple[str, DataSheet] | None:
    """The vehicle an identification belongs to: its name and data sheet, from ``identification.json``'s
    ``run.vehicle`` and ``run.datasheet`` (``qomni identify`` records them), else from the run's
    ``metadata.json`` beside it; None where neither records them.

    Raises: RunDirectoryError: a recorded data sheet that does not read (file and key named)."""
    path = Path(path)
    file = path / IDENTIFICATION_JSON if path.is_dir() else path
    run = read_json(file).get("run", {})
    if isinstance(run, dict) and isinstance(run.get("vehicle"), str) and isinstance(run.get("datasheet"), dict):
        try:
            return run["vehicle"], DataSheet.from_tables(run["datasheet"], run["vehicle"], f"{file} run.datasheet")
        except DataSheetError as exc:
            raise RunDirectoryError(str(exc)) from None
    beside = file.parent / METADATA
    if beside.is_file():
        meta = read_json(beside)
        if isinstance(meta.get("vehicle"), str) and "datasheet" in meta:
            return meta["vehicle"], datasheet_from_metadata(meta, str(beside))
    return None


def check_identification_vehicle(path: str | Path, sheet: DataSheet, name: str | None, other: str,
                                 advice: str) -> None:
    """The identification at ``path`` belongs to the vehicle of ``sheet``: the same data sheet geometry and
    drive, and where ``name`` is given (a run's recorded vehicle) the same vehicle name. Its parameters hold
    for the vehicle they were identified on; simulated, exported or compared on another (another wheel
    radius, gear ratio or axle distance, another vehicle's run) they give another vehicle's behaviour
    without a word. An identification that records no vehicle is taken as ``sheet``'s.

    Args: ``other`` names the other side in the message ("the data RUN", "--vehicle FILE"); ``advice`` ends it.
    Raises: RunDirectoryError: names both vehicles and what differs."""
    recorded = identification_vehicle(path)
    if recorded is None:
        return
    own, own_sheet = recorded
    differ = [f"vehicle name ('{own}' against '{name}')"] if isinstance(name, str) and name != own else []
    differ += vehicle_differences(own_sheet, sheet)
    if differ:
        raise RunDirectoryError(f"{path}: identified on vehicle '{own}', {other} is "
                                f"{repr(name) if name else 'another data sheet'} (they differ in "
                                f"{', '.join(differ)}): {advice}")


def load_identification(path: str | Path) -> IdentificationResult:
    """Read ``identification.json`` (a file or the run directory holding it)."""
    path = Path(path)
    if path.is_dir():
        path = path / IDENTIFICATION_JSON
    if not path.exists():
        raise RunDirectoryError(f"{path} does not exist: run 'qomni identify' first")
    data = read_json(path)
    try:
        return IdentificationResult.from_json_dict(data)
    except ValueError as exc:
        raise RunDirectoryError(f"{path}: not an identification result: {exc}") from None
