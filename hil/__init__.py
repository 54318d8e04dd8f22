"""hil — the vehicle's CANopen network: emulated devices around a plant, and the master that talks to
either the emulator or the real vehicle.

Shared by both sides: ``bus`` (bus spec → python-can bus), ``cia`` (the CiA object catalogue), ``layout``
(node IDs, EDS files), ``units`` (device units ↔ SI), ``pdo_codec`` (PDO mapping → struct).
``device``: ``node301`` / ``drive402`` / ``encoder406`` (the devices), ``server`` (:class:`VehicleServer`,
lock-step host of a plant), ``plant`` (the plant contract), ``faults`` (fault injection).
``master``: ``client`` (:class:`VehicleClient`), ``decode`` (bus logs → measurements).
``tools``: ``hub`` (socketcand loopback hub), ``recorder`` (BLF/candump logs, replay), ``dbc``, ``busload``.

Importing ``hil`` is light: names below load their module on first use, and nothing in ``hil`` imports
``emulator`` (the server takes any :class:`~qomni.hil.device.plant.Plant`).
"""
from __future__ import annotations

import importlib

_EXPORTS = {
    "VehicleClient": "qomni.hil.master.client",
    "CommunicationError": "qomni.hil.master.client",
    "DriveFaultError": "qomni.hil.master.client",
    "VehicleServer": "qomni.hil.device.server",
    "Measurement": "qomni.vehicle_interface",
    "VehicleInterface": "qomni.vehicle_interface",
    "open_bus": "qomni.hil.bus",
    "parse_bus_spec": "qomni.hil.bus",
    "BusSpec": "qomni.hil.bus",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'hil' has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + __all__)
