"""Gear backlash between the motor and the wheel.

The motor and gear's reflected inertia (``rotor_fraction`` of B_w) is a separate rotor link on the wheel
axle, driven by the motor torque and read by the motor encoder. It reaches the wheel only through the gap:
a stiff unilateral spring-damper (the tooth contact) engages when the rotor leads or lags the wheel by
more than gap/2. The wheel keeps its friction and the remaining inertia."""
from __future__ import annotations

import math

import numpy as np

from .base import BuildPlan, Effect, EffectsError, Param, Plant

DAMPING_RATIO = 0.2  # of the tooth contact, for the lifted rotor against the free wheel
#: The wheel link keeps only (1 − rotor_fraction)·B_w. At the default 50 solver iterations its tyre's
#: friction constraint does not converge: steering at rest, the wheels creep 1.3 % in their rolling
#: direction at rotor_fraction 0.7, with or without a gap (0.15 % at 100 iterations, none at 300).
SOLVER_ITERATIONS = 300


class Backlash(Effect):
    name = "backlash"
    stage = 40
    #: Blind-suite entries: the (weak, strong) ends of the realistic range (docs/effects.md).
    suite = {"backlash": ({"gap": 0.002}, {"gap": 0.02})}
    summary = "gear backlash: motor rotor and wheel coupled through a gap"
    params = {
        "gap": Param("rad", 0.0, 0.1, doc="total backlash, wheel side of the gear"),
        "stiffness": Param("N m/rad", 1e3, 1e5, default=2e4,
                           doc="torsional stiffness of the engaged gear, wheel side"),
        "rotor_fraction": Param("-", 0.1, 0.95, default=0.7,
                                doc="share of B_w on the motor side of the gap (motor + gear)"),
    }

    def configure(self, plan: BuildPlan, description) -> None:
        plan.rotor_fraction = self.values["rotor_fraction"]
        plan.solver_iterations = max(plan.solver_iterations, SOLVER_ITERATIONS)

    def attach(self, plant: Plant) -> None:
        f, k = self.values["rotor_fraction"], self.values["stiffness"]
        inertia = f * (1 - f) * plant.description.truth.B_w  # rotor against the free wheel
        if math.sqrt(k / inertia) * plant.time_step > 1.0:
            raise EffectsError(f"[{self.name}] stiffness: {k} N m/rad is too stiff for the physics step "
                               f"{plant.time_step} s (rotor against wheel: {inertia:.3g} kg m²)")
        self._damping = 2 * DAMPING_RATIO * math.sqrt(k * inertia)
        self._rotor = plant.torque_slots(plant.rotor)
        self._wheel = plant.torque_slots(plant.wheel)
        self._joints = plant.rotor + plant.wheel

    def before_step(self, plant: Plant) -> None:
        q, qd = plant.joint_states(self._joints)
        lead, rate = q[:4] - q[4:], qd[:4] - qd[4:]
        side = np.sign(lead)
        depth = np.maximum(np.abs(lead) - self.values["gap"] / 2, 0.0)
        # unilateral tooth contact: pushes, never pulls
        push = np.maximum(self.values["stiffness"] * depth + self._damping * rate * side, 0.0)
        torque = np.where(depth > 0, push * side, 0.0)
        plant.torque[self._rotor] -= torque
        plant.torque[self._wheel] += torque
