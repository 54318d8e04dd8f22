"""Concise DCF (CiA 302 0x1F22): building from a DCF's ParameterValue entries, parsing, and the client
writing it to the emulated devices at connect; the devices honour ParameterValue of their own EDS/DCF."""
from __future__ import annotations

import struct
import uuid

import pytest

from qomni.hil.device.drive402 import Drive402
from qomni.hil.device.server import VehicleServer
from qomni.hil.layout import DRIVE_EDS
from qomni.hil.master.client import VehicleClient
from qomni.hil.master.dcf import ConciseDcfError, Entry, build, from_dcf, parse
from qomni.hil.master.errors import CommunicationError

from doubles import BITS, INCREMENTS, T_S, FakePlant


def _dcf(tmp_path, values):
    """The drive's EDS turned into a DCF with ParameterValue lines {section: value}."""
    text = DRIVE_EDS.read_text()
    for section, value in values.items():
        head = f"[{section}]\n"
        assert head in text
        text = text.replace(head, f"{head}ParameterValue={value}\n", 1)
    path = tmp_path / "drive.dcf"
    path.write_text(text)
    return path


def test_build_parse_round_trip_and_malformed_input():
    entries = [Entry(0x6065, 0, struct.pack("<I", 500)), Entry(0x2020, 0, b"x" * 300), Entry(0x1017, 0, b"")]
    data = build(entries)
    assert parse(data) == entries
    assert data[:4] == b"\x03\x00\x00\x00" and data[4:11] == struct.pack("<HBI", 0x6065, 0, 4)
    for bad in (b"\x01\x00", data[:-1], data + b"\x00", b"\x05" + data[1:]):
        with pytest.raises(ConciseDcfError):
            parse(bad)


def test_from_dcf_takes_the_writable_parameter_values(tmp_path):
    path = _dcf(tmp_path, {"2010sub1": 30000, "6065": "0x1000", "6041": 7})    # 0x6041 is read-only
    entries = parse(from_dcf(path, node_id=1))
    assert entries == [Entry(0x2010, 1, struct.pack("<I", 30000)), Entry(0x6065, 0, struct.pack("<I", 0x1000))]
    with pytest.raises(ConciseDcfError):
        from_dcf(DRIVE_EDS, node_id=1)                               # an EDS without ParameterValue


def test_device_honours_parameter_value_of_its_dcf(tmp_path):
    drive = Drive402(1, _dcf(tmp_path, {"6065": 1234, "2010sub1": 5000}), sync_timeout=None)
    assert drive.values[(0x6065, 0)] == 1234 and drive.values[(0x2010, 1)] == 5000


def test_client_writes_the_concise_dcf_at_connect(tmp_path):
    spec = f"virtual:hil-dcf-{uuid.uuid4().hex[:10]}"
    dcf = from_dcf(_dcf(tmp_path, {"2010sub1": 30000, "6065": 4096}), node_id=2)
    kwargs = dict(encoder_increments=INCREMENTS, steering_sensor_bits=BITS, cycle_time=T_S)
    with VehicleServer(FakePlant(), spec) as server:
        with VehicleClient(spec, concise_dcf={2: dcf}, **kwargs):
            assert server.drives[1].values[(0x2010, 1)] == 30000
            assert server.drives[1].values[(0x6065, 0)] == 4096
            assert server.drives[0].values[(0x2010, 1)] == 20000       # the others keep the EDS default
        refused = build([Entry(0x6060, 0, b"\x02")])                  # mode 2: the drive aborts
        with pytest.raises(CommunicationError, match=r"entry 1 of 1 \(0x6060:00"):
            VehicleClient(spec, concise_dcf={1: refused}, **kwargs).connect()
    with pytest.raises(ConciseDcfError):
        VehicleClient(spec, concise_dcf={1: b"\x01"}, **kwargs)
