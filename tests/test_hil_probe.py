"""``qomni probe`` and :mod:`qomni.hil.tools.probe` against the emulated vehicle (fake plant) on a virtual
bus in-process: every node found, identity, profile, CiA 402 modes and SDO timing; an empty bus fails
plainly."""
from __future__ import annotations

import json

import can
import canopen
import pytest
from typer.testing import CliRunner

from qomni.cli import app
from qomni.hil.device.server import VehicleServer
from qomni.hil.tools.probe import probe, scan
from qomni.hil.tools.timing_probe import measure

from doubles import BITS, FakePlant


def test_probe_reports_every_node(channel):
    with VehicleServer(FakePlant(), f"virtual:{channel}") as server:
        server.drives[2].write_value(0x6060, 0, 8)                     # CSP on one drive
        bus = can.Bus(interface="virtual", channel=channel)
        try:
            reports = probe(bus, timeout=0.2, samples=10)
        finally:
            bus.shutdown()
    assert [r.node_id for r in reports] == [1, 2, 3, 4, 5, 6]
    drives, encoders = reports[:4], reports[4:]
    assert all(r.profile == 402 and r.modes == [1, 3, 6, 8, 9, 10] for r in drives)
    assert [r.mode for r in drives] == [0, 0, 8, 0]
    assert all(r.state == "SWITCH ON DISABLED" for r in drives)
    assert [r.identity for r in encoders] == [(0, 0x406, 0x10000, 5), (0, 0x406, 0x10000, 6)]
    assert all(r.profile == 406 and r.units_per_revolution == 2**BITS and not r.modes for r in encoders)
    assert all(0 < r.sdo_p50 <= r.sdo_p99 < 0.2 for r in reports)
    assert drives[0].name == "qomni drive402" and drives[0].heartbeat_ms == 1000


def test_scan_skips_silent_ids(channel):
    with VehicleServer(FakePlant(), f"virtual:{channel}") as server:
        server.drives[0].power_off()
        network = canopen.Network()
        network.connect(interface="virtual", channel=channel)
        try:
            assert scan(network, range(1, 10), timeout=0.2) == [2, 3, 4, 5, 6]
        finally:
            network.disconnect()


def test_cli_probe_table_json_and_empty_bus(channel, tmp_path):
    runner = CliRunner()
    out = tmp_path / "probe.json"
    with VehicleServer(FakePlant(), f"virtual:{channel}"):
        result = runner.invoke(app, ["probe", "--bus", f"virtual:{channel}", "--node", "1", "--node", "5",
                                     "--samples", "5", "--json", str(out)], env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    assert "PP PV HM CSP CSV CST" in result.output and "CiA 406" in result.output
    assert [r["node_id"] for r in json.loads(out.read_text())["nodes"]] == [1, 5]
    result = runner.invoke(app, ["probe", "--bus", f"virtual:{channel}-empty", "--timeout", "0.05"])
    assert result.exit_code == 2 and "error: " in result.output and "no node answered" in result.output
    assert "Traceback" not in result.output
    result = runner.invoke(app, ["probe", "--bus", "udp_multicast:x"])
    assert result.exit_code == 2 and "error: " in result.output


def test_timing_as_master_latency_sync_loss_and_reset(channel):
    with VehicleServer(FakePlant(), f"virtual:{channel}") as server:
        server.drives[0].set_default(0x1017, 0, 50)                   # heartbeat every 50 ms
        server.drives[0].nmt.start_heartbeat(50)
        bus = can.Bus(interface="virtual", channel=channel)
        try:
            report = measure(bus, 1, cycle=0.005, syncs=100, pause=0.3)
        finally:
            bus.shutdown()
    assert report.syncs_answered == 100                              # lock-step: every SYNC answered
    assert 0 < report.tpdo_first_p50 <= report.tpdo_last_p50 < 0.005
    assert report.tpdo_last_p99 >= report.tpdo_last_p50
    assert 0x8100 in report.emcy_on_missed_sync                       # SYNC loss, CiA 301 EMCY
    assert report.tpdo_after_sync_returns
    # the producer's 50 ms, seen through a loaded 2-core machine's thread scheduling
    assert report.heartbeat_period == pytest.approx(0.05, rel=0.2) and report.heartbeat_jitter < 0.025
    assert 0 <= report.boot_up_after_reset < 0.5


def test_cli_timing_table(channel):
    with VehicleServer(FakePlant(), f"virtual:{channel}"):
        result = CliRunner().invoke(app, ["probe", "--bus", f"virtual:{channel}", "--node", "5", "--timing", "5",
                                          "--syncs", "50", "--cycle", "0.005"], env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    assert "SYNC → first TPDO" in result.output and "NMT reset node → boot-up" in result.output
    result = CliRunner().invoke(app, ["probe", "--bus", f"virtual:{channel}-none", "--timeout", "0.05",
                                      "--timing", "3"])
    assert result.exit_code == 2
