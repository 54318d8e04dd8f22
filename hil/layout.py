"""The vehicle's CANopen network layout: node IDs, wheel/side order and the EDS files shipped with hil.

Source: docs/conventions.md, "CANopen mapping (hil)". Import-light (standard library only).
"""
from __future__ import annotations

from pathlib import Path

from qomni.conventions import SIDES, WHEELS  # noqa: F401  (the layout names them with the node IDs)

#: CiA 402 drive node IDs, wheel order fl, rl, fr, rr (index 0..3).
DRIVE_NODE_IDS: tuple[int, ...] = (1, 2, 3, 4)
#: CiA 406 steering encoder node IDs, left (α_l) then right (α_r).
ENCODER_NODE_IDS: tuple[int, ...] = (5, 6)

#: COB-ID of the SYNC object (CiA 301 §7.2.5, default of 0x1005).
SYNC_COB_ID = 0x80

_EDS_DIR = Path(__file__).resolve().parent / "eds"
#: EDS (CiA 306) of the wheel drive: RPDO1 = 0x6040 + 0x6071, TPDO1 = 0x6041 + 0x6064,
#: TPDO2 = 0x606C + 0x6077, all synchronous (transmission type 1).
DRIVE_EDS: Path = _EDS_DIR / "drive402.eds"
#: EDS (CiA 306) of the steering encoder: TPDO1 = 0x6004, synchronous.
ENCODER_EDS: Path = _EDS_DIR / "encoder406.eds"
