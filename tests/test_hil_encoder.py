"""CiA 406 objects of the steering encoders a master expects: operating parameters 0x6000 (code sequence,
scaling), resolution 0x6001/0x6002 against the physical 0x6501, preset 0x6003 — raw SYNCs, fake plant."""
from __future__ import annotations

import struct

import numpy as np

from doubles import BITS


def _position(master, node_id=5):
    return struct.unpack("<I", master.cycle()[0x180 + node_id])[0]


def test_resolution_code_sequence_and_preset(master, unsupervised_server, plant):
    encoder = master.encoder[5]
    master.nmt(0x01)
    physical = int(np.rint(plant.alpha[0] / (2 * np.pi) * 2**BITS))
    assert encoder.sdo[0x6501].raw == 2**BITS and encoder.sdo[0x6000].raw & 0x4
    assert _position(master) == physical % 2**BITS
    encoder.sdo[0x6001].raw = encoder.sdo[0x6002].raw = 3600                 # 0.1° per unit
    assert _position(master) == physical * 3600 // 2**BITS
    assert abs(_position(master) / 3600 * 2 * np.pi - plant.alpha[0]) < 2 * np.pi / 3600
    encoder.sdo[0x6000].raw = 0x4 | 0x1                                       # counting down
    assert _position(master) == -(physical * 3600 // 2**BITS) % 3600
    encoder.sdo[0x6003].raw = 1000                                            # preset: reads 1000 here
    assert _position(master) == 1000
    plant.alpha[0] += 2 * np.pi * 10 / 3600                                   # 1° more: 10 units down
    assert _position(master) == 990
    encoder.sdo[0x6000].raw = 0x0                                             # scaling off: physical
    assert encoder.sdo[0x6001].raw == 3600 and _position(master) != 990
    master.nmt(0x81, 5)                                                       # reset node: defaults
    master.barrier()
    master.nmt(0x01)
    assert _position(master) == int(np.rint(plant.alpha[0] / (2 * np.pi) * 2**BITS)) % 2**BITS
