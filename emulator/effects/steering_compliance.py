"""Compliant front/rear steering coupling: the mirror linkage of each side is a torsional spring-damper.

The rigid coupling (a gear constraint holding q_rear = −q_front) is replaced by the torque
−k·(q_front + q_rear) − c·(q̇_front + q̇_rear) on both steering joints of a side, so the rear follows the
front only as the linkage deflects under the torque it transmits. Only the front joints are measured."""
from __future__ import annotations

import numpy as np

from .base import Effect, Param, Plant


class SteeringCompliance(Effect):
    name = "steering_compliance"
    stage = 60
    #: Blind-suite entries: the (weak, strong) ends of the realistic range (docs/effects.md).
    suite = {"steering_compliance": ({"stiffness": 5000.0}, {"stiffness": 300.0})}
    summary = "front/rear steering linkage as a torsional spring-damper instead of rigid"
    params = {
        "stiffness": Param("N m/rad", 50.0, 1e5, doc="torsional stiffness of a side's linkage"),
        "damping": Param("N m s/rad", 0.0, 100.0, default=2.0, doc="its damping"),
    }

    def attach(self, plant: Plant) -> None:
        for constraint in plant.couplings:
            plant.pb.removeConstraint(constraint)
        plant.couplings = []
        self._slots = plant.torque_slots(plant.steer)
        self._pair = np.array([[1.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 1.0]])  # q_f + q_r per side

    def before_step(self, plant: Plant) -> None:
        q, qd = plant.joint_states(plant.steer)
        torque = -(self.values["stiffness"] * self._pair @ q + self.values["damping"] * self._pair @ qd)
        plant.torque[self._slots] += torque @ self._pair
