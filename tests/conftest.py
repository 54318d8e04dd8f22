"""Fixtures shared by the test modules (test doubles themselves: doubles.py)."""
from __future__ import annotations

import os
import uuid

import pytest

# pytest-xdist starts its workers with COLUMNS set (80 without a terminal). Rich reads it once, when the
# CLI's console is made, and would fix every CLI test's width there; unset, the console reads the width
# whenever it prints, as in a terminal, and a test's own COLUMNS applies.
os.environ.pop("COLUMNS", None)

from doubles import FakePlant, Master
from qomni.hil.device.server import VehicleServer


def pytest_configure(config):
    # Under --dist loadfile, xdist hands out the files with the most tests first by default. The files that
    # run campaigns hold few tests but most of the suite's time; handed out last, one of them leaves a
    # single worker running alone at the end. The collection order below is kept instead.
    if hasattr(config.option, "loadscopereorder"):
        config.option.loadscopereorder = False


def pytest_collection_modifyitems(config, items):
    """The files holding a test marked ``slow`` first; otherwise the files and their tests in their order."""
    slow = {item.path for item in items if item.get_closest_marker("slow")}
    files = {path: k for k, path in enumerate(dict.fromkeys(item.path for item in items))}
    items.sort(key=lambda item: (item.path not in slow, files[item.path]))


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
