"""Fault injection (qomni.hil.device.faults): the plan file, each fault kind, the drives' reaction (CiA 301/402) and the
master's: detect, torque 0, drives disabled, clean abort, everything recorded."""
from __future__ import annotations

import time
import uuid

import can
import numpy as np
import pytest

from qomni.hil.master.client import CommunicationError, VehicleClient
from qomni.hil.device.drive402 import PowerState
from qomni.hil.device.faults import FaultInjector, FaultPlan, FaultPlanError, FrameLoss
from qomni.hil.device.server import VehicleServer
from doubles import BITS, INCREMENTS, T_S, FakePlant, wait_for

S = PowerState


@pytest.fixture
def spec():
    return f"virtual:faults-{uuid.uuid4().hex[:10]}"


def client_for(spec, **kwargs):
    kwargs.setdefault("timeout", 0.3)
    return VehicleClient(spec, encoder_increments=INCREMENTS, steering_sensor_bits=BITS, cycle_time=T_S,
                         **kwargs)


def run_until_error(client, cycles=400, torque=0.5):
    """Exchange until the client raises; return (cycles done, the error)."""
    for k in range(cycles):
        try:
            client.exchange(np.full(4, torque))
        except CommunicationError as exc:
            return k, exc
    return cycles, None


# ------------------------------------------------------------------------------------ plan file
def test_plan_file(tmp_path):
    path = tmp_path / "faults.toml"
    path.write_text("""
seed = 3
[frame_loss]
rate = 0.01
burst_rate = 0.001
burst_length = 4
[latency]
mean = 0.0002
jitter = 0.00005
[[power_cycle]]
node = 3
at = 1.5
off = 0.2
[[bus_off]]
at = 2
duration = 0.1
[[sync_loss]]
at = 3.0
duration = 0.25
""")
    plan = FaultPlan.load(path)
    assert plan.seed == 3 and plan.frame_loss.burst_length == 4 and plan.latency.mean == 0.0002
    assert plan.power_cycle[0].node == 3 and plan.bus_off[0].at == 2.0 and plan.sync_loss[0].duration == 0.25
    for text, message in [
        ("[frame_loss]\nrate = 1.5", "[frame_loss] rate must be in [0, 1]"),
        ("[latency]\nmean = -1.0", "[latency] mean must be ≥ 0"),
        ("[frame_los]\nrate = 0.1", "unknown entries ['frame_los']"),
        ("[[power_cycle]]\nnode = 200\nat = 1.0\noff = 0.1", "node must be 1…127"),
        ("[[sync_loss]]\nat = 1.0", "missing ['duration']"),
        ("[latency]\nmean = 'fast'", "[latency] mean must be a number"),
        ("seed = ", "not valid TOML"),
    ]:
        path.write_text(text)
        with pytest.raises(FaultPlanError) as info:
            FaultPlan.load(path)
        assert str(path) in str(info.value) and message in str(info.value), str(info.value)


def test_frame_loss_rate_and_bursts():
    frame = can.Message(arbitration_id=0x181)
    injector = FaultInjector(FaultPlan(seed=1, frame_loss=FrameLoss(rate=0.05)), lambda: 0.0)
    lost = [injector.drop_received(frame) for _ in range(20000)]
    assert np.mean(lost) == pytest.approx(0.05, abs=0.006)
    injector = FaultInjector(FaultPlan(seed=2, frame_loss=FrameLoss(burst_rate=0.002, burst_length=7)),
                             lambda: 0.0)
    lost = np.array([injector.drop_sent(frame) for _ in range(20000)])
    edges = np.flatnonzero(np.diff(np.r_[0, lost.astype(int), 0]))
    runs = edges[1::2] - edges[::2]
    assert len(runs) > 10 and np.all(runs % 7 == 0)                       # whole bursts (may touch)
    assert injector.counters.lost_tx == lost.sum()


# ------------------------------------------------------------------------- each fault kind
def test_a_lossy_bus_is_ridden_through_holding_the_last_sample(spec):
    """2 % of the frames lost: a real master holds a missing TPDO's last sample and goes on. A lost SYNC
    costs the client its ``timeout`` (0.1 s), within the drives' SYNC supervision (0.5 s; wide enough that
    a loaded machine's scheduling pauses are no bus fault)."""
    plant = FakePlant()
    plan = FaultPlan(seed=4, frame_loss=FrameLoss(rate=0.02, start=0.1))   # lossless configuration
    with VehicleServer(plant, spec, faults=plan, sync_timeout=0.5, watchdog_period=0.01) as server:
        client = client_for(spec).connect()
        client.timeout = 0.1
        done, error = run_until_error(client)
        assert done == 400 and error is None
        assert sum(client.missed.values()) > 0
        assert server.injector.counters.lost_rx + server.injector.counters.lost_tx > 0
        client.stop()


def test_a_bus_that_stays_silent_aborts_after_the_allowed_misses_and_drives_stop(spec):
    plant = FakePlant()
    plan = FaultPlan(seed=4, frame_loss=FrameLoss(rate=1.0, start=0.1))   # from 0.1 s nothing gets through
    with VehicleServer(plant, spec, faults=plan, sync_timeout=0.05, watchdog_period=0.005) as server:
        client = client_for(spec, timeout=0.05, max_missed=3).connect()
        done, error = run_until_error(client)
        assert error is not None and "for 4 cycle(s) in a row" in str(error)
        client.stop()
        wait_for(lambda: np.all(plant.tau == 0.0), 2.0)                    # 0x6007: SYNC loss stops them
        assert all(d.state is not S.OPERATION_ENABLED for d in server.drives)


def test_latency_and_jitter_delay_but_keep_order(spec):
    plant = FakePlant()
    plan = FaultPlan.from_dict({"seed": 5, "latency": {"mean": 0.002, "jitter": 0.0005}})
    with VehicleServer(plant, spec, faults=plan) as server, client_for(spec, timeout=0.5) as client:
        durations = []
        for k in range(30):
            t = time.perf_counter()
            m = client.exchange(np.full(4, 0.1))
            durations.append(time.perf_counter() - t)
        assert np.median(durations) > 0.0015
        assert m.time == pytest.approx(29 * T_S)
        assert server.injector.counters.delayed > 30 * 10


def test_power_cycle_of_a_drive(spec):
    plant = FakePlant()
    plan = FaultPlan.from_dict({"power_cycle": [{"node": 3, "at": 0.05, "off": 0.2}]})
    with VehicleServer(plant, spec, faults=plan) as server:
        client = client_for(spec).connect()
        done, error = run_until_error(client)
        # node 3 falls silent at cycle 25: its TPDOs are held for max_missed cycles, then the campaign stops
        assert 24 + client.max_missed <= done <= 27 + client.max_missed and "node(s) 3" in str(error)
        assert plant.torque_log[26][2] == 0.0 and plant.torque_log[26][0] == pytest.approx(0.5)  # at once
        wait_for(lambda: server.drives[2].powered and server.drives[2].nmt_state == 127, 2.0)
        assert server.drives[2].state is S.SWITCH_ON_DISABLED                # rebooted with its defaults
        assert server.drives[2].values[(0x6060, 0)] == 0
        with pytest.raises(CommunicationError, match=r"node\(s\) \[3\] sent a boot-up"):
            client.exchange(np.zeros(4))
        client.stop()
        assert all(d.state in (S.READY_TO_SWITCH_ON, S.FAULT) for d in server.drives)
        wait_for(lambda: np.all(plant.tau == 0.0), 1.0)       # the server applies it between SYNCs


@pytest.mark.parametrize("kind", ["bus_off", "sync_loss"])
def test_bus_off_and_sync_loss_fault_the_drives(spec, kind):
    """No SYNC reaches the drives (their controller is bus-off, or SYNCs are lost): SYNC-loss fault 0x8100
    per 0x6007, torque 0; a bus-off ends with EMCY 0x8140 "recovered from bus-off"."""
    plant = FakePlant()
    plan = FaultPlan.from_dict({kind: [{"at": 0.02, "duration": 0.25}]})
    with VehicleServer(plant, spec, faults=plan, sync_timeout=0.05, watchdog_period=0.005) as server:
        client = client_for(spec).connect()
        done, error = run_until_error(client)
        assert 10 <= done <= 20 and "0x8100" in str(error)                 # the real cause: SYNC loss
        wait_for(lambda: all(d.state is S.FAULT for d in server.drives), 1.0)
        assert np.all(plant.tau == 0.0)
        assert all(d.values[(0x603F, 0)] == 0x8100 for d in server.drives)
        counters = server.injector.counters
        if kind == "bus_off":
            wait_for(lambda: any(code == 0x8140 for _, code, _, _ in client.emcy), 2.0)
            assert counters.bus_offs == 1 and counters.bus_off_dropped > 0
        else:
            assert counters.sync_losses == 1 and counters.sync_dropped >= 1
        client.stop()


# ------------------------------------------------------------- campaign: abort, keep the record
def test_campaign_aborts_cleanly_on_a_fault_and_keeps_the_recording(tmp_path):
    from qomni.ident.campaign import Campaign, CampaignAborted, CampaignSettings
    from qomni.datasheet import DataSheet
    from qomni.ident.recording import read_signals
    import json

    from qomni.emulator.description import VehicleDescription
    from qomni.emulator.vehicle import Emulator

    description = VehicleDescription.load()
    plan = FaultPlan.from_dict({"power_cycle": [{"node": 2, "at": 0.6, "off": 0.1}]})
    spec = f"virtual:faults-campaign-{uuid.uuid4().hex[:8]}"
    run = Campaign(DataSheet.load(), tmp_path, CampaignSettings.quick())
    with Emulator(description, seed=0) as emulator:
        server = VehicleServer(emulator, spec, faults=plan, sync_timeout=1.0).start()
        try:
            client = VehicleClient.from_drive(description.drive, spec, record=[tmp_path / "bus.blf",
                                                                              tmp_path / "bus.log"])
            with pytest.raises(CampaignAborted, match="no TPDO|boot-up"):
                with client:
                    run.run(client)
            assert all(d.state is not S.OPERATION_ENABLED for d in server.drives)   # shut down / faulted
            assert all(d.applied_torque == 0 for d in server.drives)
        finally:
            server.stop()
    meta = json.loads((tmp_path / "metadata.json").read_text())
    assert meta["status"].startswith("aborted: CommunicationError")
    signals = read_signals(tmp_path / "signals.csv")
    assert 0.5 < signals.time[-1] <= 0.62                                  # rows up to the fault
    frames = list(can.LogReader(str(tmp_path / "bus.log")))
    assert len(frames) == len(list(can.LogReader(str(tmp_path / "bus.blf")))) > 300 * 10
