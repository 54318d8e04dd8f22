"""The digital twin of an identified vehicle: the emulator configured with the identified parameters.

The sim-to-real gap is the difference between a simulator and the vehicle. The twin is the simulator a
user of a real vehicle always has: the paper's model as a physical vehicle, so its campaign shows what
the model's structure (tanh friction against real stick-slip, the filter, the solver) leaves in the data
when nothing is missing. The diagnosis uses the twin's campaign as its reference run.

What the twin is made of:

* ``[truth]``: the identified p (C_l … d_cw) and B_w as the identification used it;
* ``[geometry]``, ``[drive]``, ``[nominal]``: the data sheet (the run's ``metadata.json``, or a given one);
* the bodies as the paper idealises them: the lumped inertias and masses are the truth, the steering
  units and wheels carry negligible mass (the emulator's ideal vehicle, ``EffectSet.ideal()``), so the
  twin has no unmodelled effect by construction;
* a model identified on the data run whose least-squares estimate is not physical (a negative friction,
  e.g. a long actuator delay acts as negative damping in the steering steps) cannot be a vehicle: the
  twin reference is then made from the same run re-identified with the ``consistent`` estimator (every
  inertia, mass and friction ≥ 0, docs/identification.md) at the model's torque lag, and ``twin.json``
  in the twin's directory says so (``parameters``);
* ``[body]``'s contact (tyre friction, contact stiffness and damping, chassis height) and ``[noise]``: the
  built-in prototype's, since neither a data sheet nor an identification gives them; its masses the ideal
  vehicle's, and the wheels' transverse inertia the prototype's where the identified steering inertias
  and B_w allow it (:func:`_wheel_transverse_inertia`: a smaller vehicle's is less, a larger one's more).

The twin's *reference run* (:func:`twin_reference`) draws its torque ripple and sensor noise from a
stream of its own (:func:`reference_seed`), not from the campaign's seed. A real vehicle's noise is never
the twin's; an emulated vehicle run with the campaign's seed would otherwise share its noise sample for
sample with its twin, and the paired residual (``diagnosis.paired``) would cancel what no real user's
pairing cancels. The campaign itself (excitation, segments) keeps the recorded seed. The reference may
be run more than once (:func:`twin_references`), each repeat on a further stream of its own: the
diagnosis then subtracts the repeats' mean residual, whose noise is the single run's over √runs, while
what the model's structure leaves (the same in every repeat) stays whole.

Composition root: it imports the emulator and the identification; ``ident``, ``fmu`` and ``diagnosis``
never do.
"""
from __future__ import annotations

import tomllib
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from qomni.conventions import PARAMETER_NAMES
from qomni.datasheet import DataSheet, DataSheetError, vehicle_differences
from qomni.emulator.description import Body, DescriptionError, Truth, VehicleDescription
from qomni.emulator.effects import EffectSet
from qomni.emulator.effects.base import IDEAL_STEERING_UNIT_MASS, IDEAL_WHEEL_MASS
from qomni.ident.result import IdentificationResult
from qomni.ident.recording import RecordingError
from qomni.ident.rundir import (METADATA, SIGNALS, TWIN_STAMP, RunDirectoryError, check_identification_vehicle,
                                datasheet_from_metadata, file_sha256, load_identification, load_run, read_json)

if TYPE_CHECKING:                   # the campaign is imported where a twin runs, not on import
    from qomni.ident.campaign import CampaignSettings
    from qomni.ident.controller import ControllerSettings

#: Folder of a diagnosis' output where the twin's reference campaign is kept (and found again).
TWIN_REFERENCE = "twin_reference"

#: Entropy mixed into the campaign's seed for the reference run's emulator noise (:func:`reference_seed`).
REFERENCE_NOISE_STREAM = 0x7A1C


class TwinError(ValueError):
    """The twin cannot be built: an identified parameter is not physical for the emulator (names it)."""


def twin_description(result: IdentificationResult, sheet: DataSheet, source: str = "twin") -> VehicleDescription:
    """The emulator description whose truth is ``result`` on ``sheet``'s vehicle (module docstring).

    Raises:
        TwinError: an identified inertia or mass is not positive, or a friction coefficient negative, or a
            parameter lies more than :data:`NOMINAL_FACTOR` off the data sheet's nominal value.
    """
    prototype = VehicleDescription.load()
    truth = Truth(**{name: float(value) for name, value in zip(PARAMETER_NAMES, result.p)})
    if not truth.B_w > 0:
        raise TwinError(f"{source}: B_w = {truth.B_w} is not a positive inertia")
    wrong = result.not_physical()
    if wrong:
        raise TwinError(f"{source}: identified {', '.join(wrong)}: not physical (an inertia or mass not "
                        f"positive, or a negative friction); {result.not_physical_remedy()}")
    _check_order_of_magnitude(truth, sheet, source)
    body = replace(prototype.body, steering_unit_mass=IDEAL_STEERING_UNIT_MASS, wheel_mass=IDEAL_WHEEL_MASS,
                   wheel_transverse_inertia=_wheel_transverse_inertia(truth, sheet, prototype.body))
    description = replace(prototype, datasheet=replace(sheet, name=f"twin of {sheet.name}"), truth=truth,
                          body=body, source=source)
    try:
        description._check()
    except DescriptionError as exc:
        raise TwinError(f"{source}: the identified inertias make no rigid-body vehicle: {exc}") from exc
    return description


#: The share of a steering unit's inertia (C_l/2, C_r/2) the twin's wheel may take about the steering axis;
#: the fork keeps the rest. The prototype's own forks keep 28 % of theirs.
WHEEL_SHARE_OF_UNIT = 0.75
#: The twin wheels' least inertia about a diameter, per B_w: a wheel of no width has 1/2, which the physics
#: engine refuses (a degenerate tensor); one as wide as its radius 2/3; the prototype's 0.58.
WHEEL_TRANSVERSE_PER_B_W = 0.55


def _wheel_transverse_inertia(truth: Truth, sheet: DataSheet, prototype: Body) -> float:
    """The twin wheels' inertia about a diameter (kg m²): the prototype's, as long as the identified
    steering inertias leave the forks a quarter of each unit's (:data:`WHEEL_SHARE_OF_UNIT`), else that
    share of the smaller unit; never below :data:`WHEEL_TRANSVERSE_PER_B_W` · B_w, since a wheel's inertia
    about its axle is less than twice that about a diameter (a smaller vehicle's wheels are lighter in
    both, a larger one's heavier)."""
    unit = min(truth.C_l, truth.C_r) / 2 - IDEAL_WHEEL_MASS * sheet.geometry.a ** 2
    return max(WHEEL_TRANSVERSE_PER_B_W * truth.B_w,
               min(prototype.wheel_transverse_inertia, WHEEL_SHARE_OF_UNIT * unit))


#: How far an identified parameter may lie from the data sheet's nominal value, as a factor, before the
#: twin takes it for another vehicle's identification or another unit: the campaign's vehicles differ
#: from their data sheets by tens of per cent (a 300 kg payload: m_ch 1.36 ×).
NOMINAL_FACTOR = 10.0
#: Parameters bounded from below as well: every vehicle has inertia and mass; a friction coefficient may
#: be identified near 0 (a long actuator delay takes viscous friction out of the steering steps).
_INERTIAS = ("C_l", "C_r", "m_ch", "C_ch", "B_w")


def _check_order_of_magnitude(truth: Truth, sheet: DataSheet, source: str) -> None:
    """Every identified parameter within :data:`NOMINAL_FACTOR` of ``sheet``'s nominal value (inertias
    and masses both ways, frictions from above).

    Raises: TwinError: names the parameter, both values and the data sheet."""
    for name in PARAMETER_NAMES:
        value, nominal = getattr(truth, name), getattr(sheet.nominal, name)
        low = nominal / NOMINAL_FACTOR if name in _INERTIAS else 0.0
        if nominal > 0 and not low <= value <= NOMINAL_FACTOR * nominal:
            raise TwinError(f"{source}: identified {name} = {value:.6g} is more than {NOMINAL_FACTOR:g} × off "
                            f"the data sheet's nominal {nominal:.6g} ({sheet.name}): the identification of "
                            "another vehicle, or another unit")


def reference_seed(seed: int, run: int = 0) -> int:
    """The emulator noise seed of the twin's reference run number ``run`` for a campaign of seed ``seed``: a
    stream of its own (``numpy.random.SeedSequence`` of the seed, :data:`REFERENCE_NOISE_STREAM` and, for
    a repeat ``run`` ≥ 1, the run number), so that an emulated vehicle's noise and its twin's are
    independent, as a real vehicle's and its twin's are, and so are the twin's repeats.

    Returns: an integer in [0, 2³²).
    Raises: ValueError: ``run`` is negative."""
    if run < 0:
        raise ValueError(f"reference run number {run} is negative")
    entropy = [int(seed), REFERENCE_NOISE_STREAM] + ([int(run)] if run else [])
    return int(np.random.SeedSequence(entropy).generate_state(1)[0])


def repeat_dir(cache: str | Path, run: int) -> Path:
    """Where the twin's reference run number ``run`` is kept: ``cache`` itself for run 0, the sibling
    ``<cache>_<run>`` for a repeat."""
    cache = Path(cache)
    return cache if run == 0 else cache.with_name(f"{cache.name}_{run}")


def twin_toml(description: VehicleDescription) -> str:
    """The description as a vehicle TOML file (``emulator/data/prototype.toml``'s format)."""
    sheet = description.datasheet
    sections = {"geometry": asdict(sheet.geometry), "drive": asdict(sheet.drive),
                "nominal": asdict(sheet.nominal), "truth": asdict(description.truth),
                "body": asdict(description.body), "noise": asdict(description.noise)}
    lines = ["# A digital twin: the emulator configured with identified parameters (qomni twin).",
             "# [truth] is the identification; [geometry], [drive], [nominal] the data sheet; the bodies are",
             "# the paper's idealisation (run it with the ideal effects set); [body] contact and [noise] are",
             "# the built-in prototype's.", "", "[vehicle]", f'name = "{sheet.name}"']
    for name, table in sections.items():
        lines += ["", f"[{name}]", *(f"{key} = {value!r}" for key, value in table.items())]
    text = "\n".join(lines) + "\n"
    tomllib.loads(text)                                   # written as it will be read
    return text


def write_twin(identification: str | Path, out: str | Path, datasheet: str | Path | None = None) -> Path:
    """Write the twin of ``identification`` (a file or its run directory) to ``out`` (a vehicle TOML).

    The data sheet is ``datasheet`` if given, else the one in the identification's run directory's
    metadata.json.

    Raises:
        RunDirectoryError: identification.json or metadata.json missing or invalid; the identification
            belongs to another vehicle than the data sheet's (:func:`.ident.rundir.check_identification_vehicle`).
        DataSheetError: the given data sheet is invalid. TwinError: a parameter is not physical.
    """
    result = load_identification(identification)
    sheet, name = _sheet_for(Path(identification), datasheet)
    other = f"--datasheet {datasheet}" if datasheet is not None else f"the run {_run_of(Path(identification))}"
    check_identification_vehicle(identification, sheet, name, other,
                                 "a twin is the vehicle its model was identified on")
    text = twin_toml(twin_description(result, sheet, str(identification)))
    out = Path(out)
    tmp = out.with_name(f".{out.name}.tmp")
    tmp.write_text(text)
    tmp.replace(out)
    return out


def _run_of(identification: Path) -> Path:
    return identification if identification.is_dir() else identification.parent


def _sheet_for(identification: Path, datasheet: str | Path | None) -> tuple[DataSheet, str | None]:
    """The twin's data sheet, ``datasheet`` if given, else the one the identification's run recorded, and
    the vehicle name the run recorded (None for a data sheet file, whose name is its file's)."""
    if datasheet is not None:
        return DataSheet.load(datasheet), None
    run = _run_of(identification)
    meta = read_json(run / METADATA)
    return datasheet_from_metadata(meta, str(run / METADATA)), meta.get("vehicle")


@dataclass(frozen=True)
class _TwinCampaign:
    """What every reference run of one model on one data run shares: the twin, its data sheet, and the
    campaign settings and controller the data's run recorded."""
    identification: Path
    sheet: DataSheet
    description: VehicleDescription
    parameters: str
    settings: CampaignSettings
    recorded: dict
    controller: ControllerSettings
    completed: tuple[str, ...] | None      # the planned segments a stopped data run completed, in order


def _twin_campaign(identification: str | Path, data_dir: str | Path,
                   datasheet: str | Path | None) -> _TwinCampaign:
    """The twin of ``identification`` and the campaign of ``data_dir``, the data run read and checked
    whole first: a run cut short or gone bad is refused before the twin's campaign spends its minutes.

    Raises: RunDirectoryError, RecordingError, DataSheetError: the data run; TwinError: ``datasheet`` gives
    another geometry or drive than the data's run recorded, or the run records no
    campaign settings, or as :func:`_twin_of`."""
    data_dir = Path(data_dir)
    source = data_dir / METADATA
    _, _, meta = load_run(data_dir)
    if not meta.get("settings"):
        raise TwinError(f"{source} records no campaign settings (a decoded bus log without its run's "
                        "metadata.json?): the twin cannot drive the data's campaign")
    if datasheet is None:
        sheet = datasheet_from_metadata(meta, str(source))
    else:
        sheet, _ = _sheet_for(Path(identification), datasheet)
        if "datasheet" in meta:
            differ = vehicle_differences(sheet, datasheet_from_metadata(meta, str(source)))
            if differ:
                raise TwinError(f"{datasheet}: differs from the data sheet the data's run recorded ({source}) "
                                f"in {', '.join(differ)}: the twin must be the data's vehicle")
    description, parameters = _twin_of(Path(identification), data_dir, sheet)
    return _TwinCampaign(Path(identification), sheet, description, parameters, _settings_of(meta, source),
                         meta["settings"], _controller_of(meta, source), _completed(meta))


def _completed(meta: dict) -> tuple[str, ...] | None:
    """The segments a data run that stopped (status other than complete) completed, its dead-time probe
    and limit-cycle recoveries left out (the twin has neither); None for a complete run."""
    from qomni.ident.campaign import LIMIT_CYCLE_STEP

    if meta.get("status", "complete") == "complete":
        return None
    return tuple(seg["name"] for seg in meta["segments"] if seg["name"] not in ("probe", LIMIT_CYCLE_STEP))


def twin_references(identification: str | Path, data_dir: str | Path, cache: str | Path, runs: int = 1,
                    datasheet: str | Path | None = None, on_progress=None) -> list[Path]:
    """``runs`` reference runs of the twin (:func:`twin_reference` with run numbers 0 … runs − 1), kept in
    ``cache`` and its siblings ``<cache>_1`` … (:func:`repeat_dir`): the same campaign under independent
    noise draws, whose mean residual is the twin's residual with its noise shrunk by √runs
    (``qomni.diagnosis.paired``). The twin is built once for all runs; ``on_progress(done, total, name)``
    sees each run's steps, ``name`` prefixed by ``run k/runs:`` when there is more than one.

    Returns: the run directories, run 0 first.
    Raises:
        ValueError: ``runs`` < 1. RunDirectoryError, TwinError, CampaignAborted: as :func:`twin_reference`.
    """
    if runs < 1:
        raise ValueError(f"the twin needs at least one reference run, not {runs}")
    campaign = _twin_campaign(identification, data_dir, datasheet)
    dirs = []
    for k in range(runs):
        progress = on_progress
        if on_progress is not None and runs > 1:
            def progress(done, total, name, k=k):
                on_progress(done, total, f"run {k + 1}/{runs}: {name}")
        dirs.append(_reference_run(campaign, repeat_dir(cache, k), k, progress))
    return dirs


def twin_reference(identification: str | Path, data_dir: str | Path, cache: str | Path,
                   datasheet: str | Path | None = None, on_progress=None, run: int = 0) -> Path:
    """The twin's campaign with the settings, excitation and seed recorded in ``data_dir/metadata.json``,
    run in ``cache`` or found there from an earlier diagnosis of the same model and settings; the twin's
    noise drawn from a stream of its own, ``run`` numbering independent draws (:func:`reference_seed`).

    Returns:
        the run directory of the twin's campaign (signals.csv, metadata.json).
    Raises:
        RunDirectoryError, RecordingError, DataSheetError: the data run is incomplete or invalid (it is read
        whole before the twin drives). TwinError: it records no campaign settings, a setting the campaign
        or its controller refuses, or a model that is not physical. CampaignAborted: the twin's campaign.
    """
    return _reference_run(_twin_campaign(identification, data_dir, datasheet), Path(cache), run, on_progress)


def _reference_run(campaign: _TwinCampaign, cache: Path, run: int, on_progress) -> Path:
    """Reference run number ``run`` of ``campaign`` in ``cache``: found there when its stamp holds the same
    twin, settings, controller, noise seed and, for a data run that stopped, the segments it completed
    (the twin drives those alone), and the run completed; else run afresh in an emptied ``cache`` and
    stamped once it has ended."""
    from qomni.embedded import embedded_vehicle
    from qomni.ident.campaign import Campaign, PlanPrefixError
    from qomni.ident.rundir import write_json

    cache = Path(cache)
    noise_seed = reference_seed(campaign.settings.seed, run)
    key = {"twin": twin_toml(campaign.description), "settings": campaign.recorded,
           "controller": asdict(campaign.controller), "parameters": campaign.parameters,
           "noise_seed": noise_seed}
    if campaign.completed is not None:
        key["completed"] = list(campaign.completed)
    stamp = cache / TWIN_STAMP
    if _finished(cache, key):
        return cache
    if cache.exists():
        import shutil

        shutil.rmtree(cache)
    cache.mkdir(parents=True)
    (cache / "twin.toml").write_text(key["twin"])
    source = f"digital twin of {campaign.identification}"
    try:        # a data run that stopped: the twin drives the segments it completed (the diagnosis pairs them)
        steps = Campaign(campaign.sheet, cache, campaign.settings, campaign.controller, source=source,
                         until=campaign.completed)
    except PlanPrefixError:              # segments not the plan's: the whole campaign, paired where it can be
        steps = Campaign(campaign.sheet, cache, campaign.settings, campaign.controller, source=source)
    if on_progress is not None:
        steps.on_progress = on_progress
    with embedded_vehicle(campaign.description, seed=noise_seed, effects=EffectSet.ideal()) as link:
        steps.run(link)
    write_json(stamp, _stamp(cache, key))
    return cache


def _stamp(cache: Path, key: dict) -> dict:
    """``key`` and the SHA-256 of the run's recording as it was written (``recording``), so that a file
    edited since is told apart from the one the stamp vouches for.

    Raises: RunDirectoryError: a file of the recording is missing."""
    return {**key, "recording": {name: file_sha256(cache / name) for name in (SIGNALS, METADATA)}}


def _finished(cache: Path, key: dict) -> bool:
    """Whether ``cache`` holds the finished reference run stamped with ``key``, its files whole and as
    written: a stamp left beside a recording that has since gone bad (cut short, edited) is no cache hit,
    and the run is made again."""
    stamp = cache / TWIN_STAMP
    try:
        if not stamp.exists() or read_json(stamp) != _stamp(cache, key):
            return False
        _, _, meta = load_run(cache)
    except (RunDirectoryError, RecordingError, DataSheetError):
        return False
    return meta.get("status") == "complete"


def _twin_of(identification: Path, data_dir: Path, sheet: DataSheet) -> tuple[VehicleDescription, str]:
    """The twin of the model, or, where the model was identified on ``data_dir`` and is not physical, of
    that run re-identified with the ``consistent`` estimator at the model's torque lag; and which.

    Raises: TwinError: the model is not physical and was not identified on ``data_dir`` (or the
    consistent estimate is not physical either)."""
    from qomni.diagnosis.diagnose import identified_on
    from qomni.ident.identify import identify
    from qomni.ident.torque_timing import model_lag

    result = load_identification(identification)
    try:
        return twin_description(result, sheet, str(identification)), "the model as identified"
    except TwinError as exc:
        if not identified_on(identification, data_dir):
            raise
        consistent, _ = identify(data_dir, torque_lag=model_lag(result), estimator="consistent")
        held = ", ".join(consistent.estimator_info.get("active_bounds", [])) or "none"
        return (twin_description(consistent, sheet, f"{identification} (consistent estimator)"),
                f"the data run re-identified with the consistent estimator (parameters held at 0: {held}); "
                f"the model as identified is not physical: {exc}")


def _settings_of(meta: dict, source: Path):
    """The campaign settings the data's run recorded (``metadata.json`` ``settings``). A run that does not
    record its number of lane changes drove a single one, one that does not record its arcs drove
    none, and one that does not record its excitation criterion used the richness design.

    Raises:
        TwinError: a recorded setting the campaign does not know, or one it refuses."""
    from qomni.ident.campaign import recorded_settings

    try:
        return recorded_settings(meta.get("settings", {}))
    except (TypeError, ValueError) as exc:
        raise TwinError(f"{source}: {exc}") from exc


def _controller_of(meta: dict, source: Path):
    """The campaign controller the data's run used (``metadata.json`` ``controller``), so the twin's
    campaign is the same: with the dead-time probe the twin probes as well but keeps the steering
    bandwidth the data's run recorded. Settings a run did not record keep their defaults, except the probe:
    a run that does not record it has no probe step.

    Raises:
        TwinError: a recorded controller setting that is not a field, or one the controller refuses."""
    from dataclasses import fields

    from qomni.ident.controller import ControllerSettings

    recorded = meta.get("controller") or {}
    known = {f.name for f in fields(ControllerSettings)}
    values = {"probe": False, **{k: v for k, v in recorded.items() if k in known}}  # no record: no probe step
    try:
        return ControllerSettings(**{**values, "probe_retunes": False, "probe_on_limit_cycle": False})
    except (TypeError, ValueError) as exc:
        raise TwinError(f"{source}: {exc}") from exc


__all__ = ["REFERENCE_NOISE_STREAM", "TWIN_REFERENCE", "TwinError", "reference_seed", "repeat_dir",
           "twin_description", "twin_reference", "twin_references", "twin_toml", "write_twin"]
