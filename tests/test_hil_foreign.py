"""The project's master code against a device built on another CANopen stack: a responder node of the
``durand`` library (its own SDO server, NMT, object dictionary) on python-can's virtual bus. ``qomni
probe`` reads it, the concise DCF writer configures it and names what it refuses."""
from __future__ import annotations

import threading

import can
import canopen
import pytest
from durand import CANBusNetwork, DatatypeEnum as DT, Node, Variable, set_scheduler
from durand.scheduler import SyncScheduler

from qomni.hil.master import dcf
from qomni.hil.master.errors import CommunicationError
from qomni.hil.tools.probe import probe


@pytest.fixture
def durand_drive(channel):
    """A durand node 7 posing as a CiA 402 drive in SWITCH ON DISABLED, with one writable gain 0x2001."""
    scheduler = SyncScheduler()
    set_scheduler(scheduler)
    thread = threading.Thread(target=scheduler.run, daemon=True)
    thread.start()
    bus = can.Bus(interface="virtual", channel=channel)
    network = CANBusNetwork(bus)
    node = Node(network, 7)
    od = node.object_dictionary
    od.write(0x1000, 0, 0x00020192)
    od.write(0x1018, 1, 0x1234)                      # vendor-ID
    od[0x6041] = Variable(DT.UNSIGNED16, "ro", 0x0250, name="Statusword")
    od[0x6061] = Variable(DT.INTEGER8, "ro", 10, name="Modes of operation display")
    od[0x6502] = Variable(DT.UNSIGNED32, "ro", 0x200, name="Supported drive modes")
    od[0x2001] = Variable(DT.UNSIGNED32, "rw", 5, name="Gain")
    yield node
    scheduler.stop()
    network._notifier.stop()
    bus.shutdown()


def test_probe_reads_a_foreign_device(channel, durand_drive):
    bus = can.Bus(interface="virtual", channel=channel)
    try:
        [report] = probe(bus, range(1, 20), timeout=0.2, samples=5)
    finally:
        bus.shutdown()
    assert report.node_id == 7 and report.profile == 402
    assert report.modes == [10] and report.mode == 10 and report.state == "SWITCH ON DISABLED"
    assert report.identity[0] == 0x1234
    assert report.sdo_p50 is not None


def test_concise_dcf_configures_a_foreign_device(channel, durand_drive):
    network = canopen.Network()
    network.connect(interface="virtual", channel=channel)
    try:
        node = network.add_node(7, canopen.ObjectDictionary())
        data = dcf.build([dcf.Entry(0x2001, 0, (1234).to_bytes(4, "little"))])
        assert dcf.apply(node, data) == 1
        assert durand_drive.object_dictionary.read(0x2001, 0) == 1234
        refused = dcf.build([dcf.Entry(0x2001, 0, (7).to_bytes(4, "little")),
                             dcf.Entry(0x6041, 0, (0).to_bytes(2, "little"))])
        with pytest.raises(CommunicationError, match=r"entry 2 of 2 \(0x6041:00.*0x06010002"):
            dcf.apply(node, refused)
        assert durand_drive.object_dictionary.read(0x2001, 0) == 7          # entry 1 was written
    finally:
        network.disconnect()
