"""LSS (CiA 305) of the emulated nodes against canopen's LssMaster: switch state global and selective,
inquire identity and node-ID, configure node-ID and bit timing, store, identify remote slave, fastscan of
a node without node-ID."""
from __future__ import annotations

import canopen
import pytest
from canopen.lss import LssError, LssMaster

from qomni.hil.device.lss import CONFIGURATION, WAITING
from qomni.hil.layout import DRIVE_EDS

from doubles import wait_for

DRIVE_ADDRESS = (0x00000000, 0x00000402, 0x00010000)                 # vendor, product, revision (EDS)


@pytest.fixture
def lss(master, server):
    master.net.lss.RESPONSE_TIMEOUT = 0.5         # fastscan reads a missing answer as a 1 bit: no early give-up
    return master.net.lss


def _lss_frames(master, start):
    return [bytes(m.data) for m in master.frames[start:] if m.arbitration_id == 0x7E4]


def test_selective_switch_inquire_and_global_switch(lss, server):
    assert lss.send_switch_state_selective(*DRIVE_ADDRESS, 3)
    assert [n.lss_state for n in server.nodes] == [WAITING, WAITING, CONFIGURATION, WAITING, WAITING, WAITING]
    assert lss.inquire_node_id() == 3
    assert lss.inquire_lss_address(canopen.lss.CS_INQUIRE_PRODUCT_CODE) == 0x402
    assert lss.inquire_lss_address(canopen.lss.CS_INQUIRE_SERIAL_NUMBER) == 3
    lss.send_switch_state_global(LssMaster.WAITING_STATE)
    with pytest.raises(LssError):
        lss.inquire_node_id()                                        # nobody in configuration state
    with pytest.raises(LssError):
        lss.send_switch_state_selective(*DRIVE_ADDRESS, 99)          # no such serial: no answer
    lss.send_switch_state_global(LssMaster.CONFIGURATION_STATE)
    wait_for(lambda: all(n.lss_state == CONFIGURATION for n in server.nodes))
    lss.send_switch_state_global(LssMaster.WAITING_STATE)


def test_configure_node_id_takes_effect_at_reset_communication(master, lss, server):
    assert lss.send_switch_state_selective(*DRIVE_ADDRESS, 3)
    with pytest.raises(LssError):
        lss.configure_node_id(0)                                     # out of range: error code 1
    lss.configure_node_id(10)
    lss.store_configuration()
    lss.send_switch_state_global(LssMaster.WAITING_STATE)
    assert master.drive[3].sdo[0x1000].raw == 0x00020192             # still node 3 until the reset
    start = len(master.frames)
    master.nmt(0x82, 3)                                              # reset communication
    wait_for(lambda: any(m.arbitration_id == 0x70A for m in master.frames[start:]))
    node = canopen.RemoteNode(10, str(DRIVE_EDS))
    master.net.add_node(node)
    assert node.sdo[0x1800][1].raw == 0x180 + 10                     # $NODEID-relative COB-IDs follow
    assert node.sdo[0x1014].raw == 0x80 + 10
    assert server.drives[2].stored == (10, None)
    master.drive[3].sdo.RESPONSE_TIMEOUT = 0.1
    master.drive[3].sdo.MAX_RETRIES = 1
    with pytest.raises(canopen.SdoCommunicationError):
        master.drive[3].sdo[0x1000].raw                               # node 3 is gone


def test_bit_timing_of_the_eds_rates_only(lss, server):
    assert lss.send_switch_state_selective(*DRIVE_ADDRESS, 1)
    lss.configure_bit_timing(2)                                      # 500 kbit/s: BaudRate_500=1
    with pytest.raises(LssError):
        lss.configure_bit_timing(1)                                  # 800 kbit/s: not in the EDS
    lss.activate_bit_timing(10)
    wait_for(lambda: server.drives[0].bit_rate == 500)                # activation has no answer
    assert server.drives[1].bit_rate is None
    lss.send_switch_state_global(LssMaster.WAITING_STATE)


def test_identify_remote_slave_by_serial_range(master, lss):
    start = len(master.frames)
    lss.send_identify_remote_slave(0, 0x406, 0, 0xFFFFFFFF, 5, 6)   # both encoders
    wait_for(lambda: len(_lss_frames(master, start)) == 2)
    assert _lss_frames(master, start) == [b"\x4F" + bytes(7)] * 2
    start = len(master.frames)
    lss.send_identify_remote_slave(0, 0x402, 0x20000, 0xFFFFFFFF, 0, 0xFFFFFFFF)   # newer revisions
    lss.send_identify_non_configured_remote_slave()                 # every node has a node-ID
    assert _lss_frames(master, start) == []


def test_fastscan_finds_a_node_without_node_id_and_configures_it(master, lss, server):
    assert lss.send_switch_state_selective(0, 0x406, 0x10000, 6)     # right encoder
    lss.configure_node_id(0xFF)                                      # not configured
    lss.send_switch_state_global(LssMaster.WAITING_STATE)
    start = len(master.frames)
    master.nmt(0x82, 6)
    wait_for(lambda: server.encoders[1].id == 0xFF)
    assert not [m for m in master.frames[start:] if m.arbitration_id == 0x706]   # silent, no boot-up
    start = len(master.frames)
    lss.send_identify_non_configured_remote_slave()
    wait_for(lambda: _lss_frames(master, start) == [b"\x50" + bytes(7)])
    found, address = lss.fast_scan()
    assert found and address == [0, 0x406, 0x10000, 6]
    assert server.encoders[1].lss_state == CONFIGURATION             # the scan's last step selects it
    lss.configure_node_id(20)
    start = len(master.frames)
    lss.send_switch_state_global(LssMaster.WAITING_STATE)            # no node-ID before: boots at once
    wait_for(lambda: any(m.arbitration_id == 0x714 for m in master.frames[start:]))
    assert master.net.add_node(20, str(DRIVE_EDS)).sdo[0x1000].raw == server.encoders[1].values[(0x1000, 0)]
