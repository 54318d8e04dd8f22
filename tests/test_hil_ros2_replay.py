"""The start-up and mode sequences of ros2_canopen's CiA 402 driver (canopen_402_driver ``Motor402``,
``DefaultHomingMode``, ``ProfiledPositionMode``), replayed as raw frames against the emulated drive.

ros2_canopen cannot be installed here (ROS 2 and Lely CANopen); the sequences are taken as facts from
its public source: ``handleInit`` reads the state, pulses the fault reset, walks the controlword to
OPERATION ENABLED with bit 8 (halt) set while no mode handler writes, checks 0x6502 bit (mode − 1),
writes 0x6060 and polls 0x6061, then homes: reads 0x6098, waits (≤ 1 s) for statusword bit 10 or 13,
sets bit 4, waits for the homing to leave "not started", for bit 12 (attained) and bit 10 (reached)
without bit 13 (error), and switches to no mode. Profile position sets bit 5 (immediate) always,
writes 0x607A and sets bit 4 while bit 12 (acknowledge) is clear, clears bit 4 once it is set. The
controlword travels in RPDO1 each SYNC; objects not mapped go by SDO.
"""
from __future__ import annotations

import struct

import numpy as np

from doubles import INCREMENTS, T_S

HALT, START, IMMEDIATE, FAULT_RESET = 1 << 8, 1 << 4, 1 << 5, 1 << 7


class Cia402Replay:
    """One drive, one SYNC per :meth:`cycle`, the controlword in RPDO1 (lock-step)."""

    def __init__(self, master, node_id=1):
        self.master, self.node = master, master.drive[node_id]
        self.id = node_id
        self.node.sdo[0x1400][5].raw = 0            # no RPDO deadline: SDO pauses between SYNCs
        self.cw = 0
        self.sw = self.position = 0
        self.cycles = 0

    def cycle(self):
        tpdos = self.master.cycle([(0x200 + self.id, struct.pack("<Hh", self.cw, 0))])
        self.sw, self.position = struct.unpack("<Hi", tpdos[0x180 + self.id])
        self.cycles += 1
        return self.sw

    def wait(self, predicate, cycles):
        for _ in range(cycles):
            if predicate(self.cycle()):
                return True
        return False

    def state(self):
        for name, mask, value in (("OE", 0x6F, 0x27), ("SO", 0x6F, 0x23), ("RTSO", 0x6F, 0x21),
                                  ("SOD", 0x4F, 0x40), ("FAULT", 0x4F, 0x08)):
            if self.sw & mask == value:
                return name
        return "?"

    def enable(self):
        """Motor402::switchState(Operation_Enable) with halt set (no mode handler writing)."""
        for command, reached in ((0x06, "RTSO"), (0x07, "SO"), (0x0F, "OE")):
            if self.state() == "OE":
                break
            self.cw = command | HALT
            assert self.wait(lambda sw: self.state() == reached, 50), f"no {reached}: sw 0x{self.sw:04X}"

    def switch_mode(self, mode):
        """Motor402::switchMode: 0x6502 bit, 0x6060 by SDO, poll 0x6061."""
        assert self.node.sdo[0x6502].raw & 1 << (mode - 1)
        self.node.sdo[0x6060].raw = mode
        assert self.wait(lambda sw: self.node.sdo[0x6061].raw == mode, 10)


def test_cia402_driver_init_homes_then_profile_position(master, unsupervised_server, plant):
    drive = Cia402Replay(master)
    master.nmt(0x01)
    drive.cycle()
    assert drive.state() == "SOD" and master.drive[1].sdo[0x6061].raw == 0            # readState
    drive.cw = FAULT_RESET
    drive.cycle()
    drive.cw = 0                                                                     # fault reset pulse
    drive.enable()
    # homing at start-up (method 34 configured beforehand, e.g. by the DCF)
    master.drive[1].sdo[0x6098].raw = 34
    master.drive[1].sdo[0x6099][2].raw = INCREMENTS
    master.drive[1].sdo[0x609A].raw = 20 * INCREMENTS
    drive.switch_mode(6)
    assert master.drive[1].sdo[0x6098].raw == 34
    one_second = int(1 / T_S)
    assert drive.wait(lambda sw: sw & 0x2400, one_second)                            # prepared: not started
    assert not drive.sw & 1 << 13
    drive.cw = 0x0F | START                                                          # mode handler: halt off
    assert drive.wait(lambda sw: sw & 0x3400 != 0x0400, one_second)                  # started
    assert drive.wait(lambda sw: sw & 0x3000, 5 * one_second) and not drive.sw & 1 << 13   # attained
    assert drive.wait(lambda sw: sw & 0x2400, 5 * one_second)                        # stopped
    assert drive.sw & 0x3400 == 0x1400                                               # reached + attained
    assert abs(drive.position) <= master.drive[1].sdo[0x6067].raw                   # at home offset 0
    tolerance = 2 * np.pi * 200 / INCREMENTS                                          # 200 increments
    assert abs(plant.theta[0] - 2 * np.pi) < tolerance                               # the next index pulse
    drive.cw = 0x0F | HALT
    master.drive[1].sdo[0x6060].raw = 0                                              # switchMode(No_Mode)
    drive.cycle()
    # profile position: bit 5 always, bit 4 until acknowledged
    drive.switch_mode(1)
    master.drive[1].sdo[0x6081].raw = 2 * INCREMENTS
    target, last_target, start = INCREMENTS // 2, None, plant.theta[0]
    for _ in range(400):
        cw = 0x0F | IMMEDIATE
        if not drive.sw & 1 << 12 and target != last_target:
            master.drive[1].sdo[0x607A].raw = target
            cw |= START
            last_target = target
        drive.cw = cw
        drive.cycle()
        if last_target == target and drive.sw & 1 << 10 and not drive.sw & 1 << 12:
            break
    assert drive.sw & 1 << 10 and abs(drive.position - target) <= master.drive[1].sdo[0x6067].raw
    assert abs(plant.theta[0] - start - np.pi) < tolerance                           # half a revolution


def test_cia402_driver_cyclic_position_stream(master, unsupervised_server, plant):
    """CSP as the cyclic mode helper drives it: 0x607A each cycle, halt off, after init without homing."""
    drive = Cia402Replay(master, 2)
    master.nmt(0x01)
    drive.cycle()
    drive.enable()
    drive.switch_mode(8)
    node = master.drive[2]
    start = drive.position
    for k in range(150):
        node.sdo[0x607A].raw = start + int(0.5 * INCREMENTS * k * T_S)                # 0.5 rev/s ramp
        drive.cw = 0x0F
        drive.cycle()
        assert not drive.sw & 1 << 13                                                # no following error
    assert drive.sw & 1 << 12                                                        # follows the command
    moved = drive.position - start
    assert abs(moved - 0.5 * INCREMENTS * 149 * T_S) < 0.02 * INCREMENTS
