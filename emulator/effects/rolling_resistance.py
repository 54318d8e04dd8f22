"""Load-dependent rolling resistance: each wheel resists rolling with c_rr·N_i·r.

N_i is the wheel's contact normal force as PyBullet computed it in the last step, so the resistance
follows the load (payload, incline, load transfer); a lifted wheel has none. Added every physics step to
the wheel joint's Coulomb friction limit (its stiction velocity motor), r is the physical wheel radius."""
from __future__ import annotations

import numpy as np

from .base import Effect, Param, Plant


class RollingResistance(Effect):
    name = "rolling_resistance"
    stage = 90
    #: Blind-suite entries: the (weak, strong) ends of the realistic range (docs/effects.md).
    suite = {"rolling_resistance": ({"c_rr": 0.005}, {"c_rr": 0.02})}
    summary = "rolling resistance torque c_rr·N·r from each wheel's contact normal force"
    params = {
        "c_rr": Param("-", 0.0, 0.1, doc="rolling resistance coefficient"),
    }

    def attach(self, plant: Plant) -> None:
        plant.dynamic_friction()
        self._slots = np.array([plant.coulomb_joints.index(j) for j in plant.wheel])
        self._link = {j: i for i, j in enumerate(plant.wheel)}
        self._arm = self.values["c_rr"] * plant.plan.wheel_radius

    def before_step(self, plant: Plant) -> None:
        plant.coulomb[self._slots] += self._arm * wheel_loads(plant, self._link)


def wheel_loads(plant: Plant, link_index: dict[int, int]) -> np.ndarray:
    """Contact normal force on each wheel (N, order of ``link_index``'s values) from the last step."""
    load = np.zeros(len(link_index))
    for contact in plant.pb.getContactPoints(bodyA=plant.body, bodyB=plant.plane):
        i = link_index.get(contact[3])
        if i is not None:
            load[i] += contact[9]
    return load
