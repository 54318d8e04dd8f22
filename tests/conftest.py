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
