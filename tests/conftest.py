"""Fixtures shared by the test modules (test doubles themselves: doubles.py)."""
from __future__ import annotations

import uuid

import pytest

from doubles import FakePlant, Master
from qomni.hil.device.server import VehicleServer


@pytest.fixture
def channel():
    return f"hil-test-{uuid.uuid4().hex[:10]}"


@pytest.fixture
def master(channel):
    m = Master(channel)
    yield m
    m.close()


@pytest.fixture
def plant():
    return FakePlant()


@pytest.fixture
def server(channel, master, plant):
    with VehicleServer(plant, f"virtual:{channel}") as srv:
        yield srv


@pytest.fixture
def unsupervised_server(channel, master, plant):
    """The vehicle without SYNC-loss supervision: for masters that pause between SYNCs (SDO set-up in
    lock-step) on a loaded machine; the supervision itself is tested with ``server``."""
    with VehicleServer(plant, f"virtual:{channel}", sync_timeout=None) as srv:
        yield srv
