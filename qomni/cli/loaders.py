"""The CLI's readers of user files (data sheet, vehicle description, effects, fault plan) and the vehicle
link: each a bad file ends the command with the reader's message (:func:`qomni.cli.console.fail`)."""
from __future__ import annotations

import shutil
from pathlib import Path
from typing import Iterable, Optional

from .console import fail


def load_datasheet(vehicle: Optional[Path], datasheet: Optional[Path]):
    """The :class:`~qomni.datasheet.DataSheet` of ``datasheet`` or ``vehicle`` (default: the prototype's)."""
    from qomni.datasheet import DataSheet, DataSheetError

    try:
        return DataSheet.load(datasheet or vehicle)
    except (DataSheetError, FileNotFoundError) as exc:
        fail(str(exc))


def load_description(vehicle: Optional[Path]):
    """The emulator's :class:`~qomni.emulator.description.VehicleDescription` (default: the prototype)."""
    from qomni.emulator.description import DescriptionError, VehicleDescription

    try:
        return VehicleDescription.load(vehicle)
    except (DescriptionError, FileNotFoundError) as exc:
        fail(str(exc))


def load_effects(path: Optional[Path]):
    """The effects file's :class:`~qomni.emulator.effects.EffectSet`, or None (the vehicle as described)."""
    if path is None:
        return None
    from qomni.emulator.effects import EffectSet, EffectsError

    try:
        return EffectSet.load(path)
    except (EffectsError, FileNotFoundError) as exc:
        fail(str(exc))


def check_effects(description, effects) -> None:
    """Build the emulated vehicle once with ``effects`` before anything is written or started: the checks
    that need its physics step (a delay or report lag on its 1 ms grid, a backlash stiffness it can
    integrate) run where it is built."""
    if effects is None:
        return
    from qomni.emulator.description import DescriptionError
    from qomni.emulator.effects import EffectsError
    from qomni.emulator.vehicle import Emulator

    try:
        Emulator(description, effects=effects).close()
    except (EffectsError, DescriptionError) as exc:    # an effect's bodies that the vehicle's truth cannot hold
        fail(str(exc))


def load_faults(path: Optional[Path]):
    """The :class:`~qomni.hil.device.faults.FaultPlan` of ``path``, or None."""
    if path is None:
        return None
    from qomni.hil.device.faults import FaultPlan, FaultPlanError

    try:
        return FaultPlan.load(path)
    except (FaultPlanError, FileNotFoundError) as exc:
        fail(str(exc))


def vehicle_link(bus: Optional[str], vehicle: Optional[Path], sheet, seed: int, lifted: bool,
                  gui: bool, record: Path, effects=None, faults=None, plant_process: bool = False):
    """Context manager yielding a connected client: embedded emulator (``plant_process``: its physics in
    a process of its own) or the vehicle on ``bus``."""
    record = [record, record.with_suffix(".log")]         # BLF and candump -L
    if bus is None:
        from qomni.embedded import embedded_vehicle

        return embedded_vehicle(load_description(vehicle), seed=seed, lifted=lifted, gui=gui, record=record,
                                effects=effects, faults=faults, plant_process=plant_process)
    from qomni.hil.master.client import VehicleClient

    return VehicleClient.from_drive(sheet.drive, bus, record=record)


PLANT_PROCESS_HELP = ("Run the embedded emulator's physics in a process of its own, overlapped with the "
                      "CANopen stack (same frames and data bit for bit; pays where a core is free, see "
                      "docs/hil.md).")


def check_bus_spec(bus: Optional[str]) -> None:
    """A ``--bus`` value that python-can can open (checked before anything is created on disk)."""
    if bus is None:
        return
    from qomni.hil.bus import parse_bus_spec

    try:
        parse_bus_spec(bus)
    except ValueError as exc:
        fail(str(exc))


def prepare_out(out: Path, owned: Iterable[str], force: bool) -> None:
    """Make ``out`` a directory to write a new run into; nothing is ever appended to an old run.

    ``owned``: the files and folders the command writes. If any exists, the command is refused unless
    ``force``, which removes exactly those (a campaign keeps a single-axis run beside it and vice versa).
    """
    if out.exists() and not out.is_dir():
        fail(f"--out {out} is a file, not a directory")
    present = [name for name in owned if (out / name).exists()]
    if present and not force:
        fail(f"{out} already holds {', '.join(present)} of an earlier run; choose a new --out or pass "
             "--force to replace them")
    try:
        for name in present:
            target = out / name
            shutil.rmtree(target) if target.is_dir() else target.unlink()
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".qomni-write-test"
        probe.touch()
        probe.unlink()
    except OSError as exc:
        fail(f"cannot write into {out}: {exc.strerror or exc}")
