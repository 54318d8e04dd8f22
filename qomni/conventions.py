"""The shared vocabulary of the vehicle: wheel and side order, the dynamic parameters p of (18) with their
units, the friction smoothing ε and gravity. Every package reads these names from here.

A leaf module (standard library only), importable from the emulator, the CANopen layer, the
identification, the FMUs and the diagnosis alike. Frames, signs and units: docs/conventions.md.
"""
from __future__ import annotations

#: Wheel order everywhere (arrays of shape (4,), CAN drive nodes 1–4): front-left, rear-left,
#: front-right, rear-right.
WHEELS: tuple[str, ...] = ("fl", "rl", "fr", "rr")
#: Steering sides, α_l then α_r (arrays of shape (2,), CAN encoder nodes 5, 6).
SIDES: tuple[str, ...] = ("left", "right")
#: s_i per wheel: +1 left wheels, −1 right wheels.
SIDE_SIGN: tuple[int, ...] = (1, 1, -1, -1)
#: σ_i per wheel: +1 front (φ_i = α_side, P_x = +l/2), −1 rear (φ_i = −α_side, P_x = −l/2).
FRONT_SIGN: tuple[int, ...] = (1, -1, 1, -1)
#: Index into SIDES of each wheel's steering side.
SIDE_INDEX: tuple[int, ...] = (0, 0, 1, 1)

#: Dynamic parameters p of (18), in this order.
PARAMETER_NAMES: tuple[str, ...] = (
    "C_l", "d_vl", "d_cl", "C_r", "d_vr", "d_cr", "m_ch", "C_ch", "d_vw", "d_cw", "B_w",
)
#: Identified parameters p₁ and fixed (dependent) parameters p₂ of (23).
P1_NAMES: tuple[str, ...] = PARAMETER_NAMES[:10]
P2_NAMES: tuple[str, ...] = ("B_w",)
#: SI unit of each parameter (rotational ones on the wheel or steering joint side of the gear).
PARAMETER_UNITS: dict[str, str] = {
    "C_l": "kg m^2", "d_vl": "N m s/rad", "d_cl": "N m",
    "C_r": "kg m^2", "d_vr": "N m s/rad", "d_cr": "N m",
    "m_ch": "kg", "C_ch": "kg m^2",
    "d_vw": "N m s/rad", "d_cw": "N m", "B_w": "kg m^2",
}

#: rad/s (m/s for chassis translation): tanh smoothing of Coulomb friction, tanh(v/ε) in (16), the
#: paper's ε (section 7).
EPSILON: float = 0.01
#: m/s², standard gravity.
GRAVITY: float = 9.81
