"""The embedded vehicle: the emulator served as CANopen nodes on an in-process virtual bus, and the
client connected to it — the same client and protocol that drive a real vehicle on ``socketcan:can0``.

This module is part of the composition root (the CLI); ``ident`` and ``fmu`` never import it.
"""
from __future__ import annotations

import contextlib
import functools
import itertools
import os
from pathlib import Path
from typing import Iterator

from qomni.emulator.description import VehicleDescription
from qomni.emulator.effects import EffectSet
from qomni.emulator.vehicle import Emulator
from qomni.hil.master.client import VehicleClient
from qomni.hil.device.plant_process import PlantProcess
from qomni.hil.device.server import VehicleServer

_channels = itertools.count()

#: SYNC-loss supervision of the embedded (lock-step) drives, s. In lock-step the physics does not
#: advance without SYNC, so the timeout only has to detect a dead master; a shared 2-core machine can
#: deschedule a Python master (or the emulator's thread) for longer than a real drive's 0.1 s. The client
#: waits as long for the TPDOs of a SYNC.
LOCKSTEP_SYNC_TIMEOUT = 5.0
#: s the client waits for a SYNC's first TPDO when a fault plan may lose frames (a lost SYNC is no stall).
LOSSY_TIMEOUT = 0.5


@contextlib.contextmanager
def embedded_vehicle(description: VehicleDescription, *, seed: int = 0, lifted: bool = False,
                     gui: bool = False, record: str | Path | None = None,
                     effects: EffectSet | None = None, faults=None, plant_process: bool = False,
                     spin: float | None = None) -> Iterator[VehicleClient]:
    """Start the emulated vehicle on a private virtual bus and yield a connected client.

    Args:
        description: the vehicle to emulate.
        seed: the emulator's noise seed.
        lifted: chassis jacked up, wheels free (single-axis identification).
        gui: show PyBullet's GUI.
        record: log file(s) for every frame on the bus (``.blf``, ``.log`` candump; qomni.hil.tools.recorder).
        effects: unmodelled effects on the ideal vehicle (``None``: the prototype as described).
        faults: a :class:`qomni.hil.device.faults.FaultPlan` injected on the emulator's side of the bus.
        plant_process: run the emulator in a process of its own (:class:`qomni.hil.device.plant_process.
            PlantProcess`): its physics overlaps the bus side's work; same frames and states bit for bit.
        spin: with ``plant_process``, s each side polls before it blocks (default: by the CPU count).
    """
    bus = f"virtual:qomni-embedded-{os.getpid()}-{next(_channels)}"
    factory = functools.partial(Emulator, description, seed=seed, lifted=lifted, gui=gui, effects=effects)
    emulator = PlantProcess(factory, spin=spin) if plant_process else factory()
    server = VehicleServer(emulator, bus, sync_timeout=LOCKSTEP_SYNC_TIMEOUT, faults=faults)
    try:
        server.start()
        # Without a fault plan no frame is lost: the client waits for every TPDO (deterministic lock-step).
        # With one, a lost SYNC is given up after LOSSY_TIMEOUT, well inside the drives' SYNC supervision.
        timeout = LOCKSTEP_SYNC_TIMEOUT if faults is None else LOSSY_TIMEOUT
        grace = LOCKSTEP_SYNC_TIMEOUT if faults is None else None
        with VehicleClient.from_drive(description.drive, bus, record=record, timeout=timeout,
                                      tpdo_grace=grace) as client:
            yield client
    finally:
        server.stop()
        emulator.close()
