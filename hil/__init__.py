"""hil — the vehicle's CANopen network: emulated devices around a plant, and the master that talks to
either the emulator or the real vehicle.

Modules: ``bus`` (bus spec → python-can bus), ``layout`` (node IDs, EDS files), ``units`` (device units
↔ SI), ``pdo_codec`` (PDO mapping → struct), ``node301`` / ``drive402`` / ``encoder406`` (devices),
``server`` (:class:`VehicleServer`, lock-step host of a plant), ``client`` (:class:`VehicleClient`),
``measurement`` (:class:`Measurement`, :class:`VehicleInterface`), ``recorder`` (BLF bus log).

Importing ``hil`` is light: names below load their module on first use, and nothing in ``hil`` imports
``emulator`` (the server takes a duck-typed plant).
"""
from __future__ import annotations

import importlib

_EXPORTS = {
    "VehicleClient": "qomni.hil.client",
    "CommunicationError": "qomni.hil.client",
    "DriveFaultError": "qomni.hil.client",
    "VehicleServer": "qomni.hil.server",
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
