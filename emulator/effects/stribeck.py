"""Stribeck friction: the Coulomb friction of the wheel or steering joints peaks at low speed.

The joints' stiction (a velocity motor holding speed 0 up to its force limit) gets the limit
d_c·(1 + (ratio − 1)·exp(−(v/v_s)²)) from the joint speed v every physics step: breakaway takes
ratio × d_c, and the friction falls to d_c once the joint slides faster than v_s."""
from __future__ import annotations

import numpy as np

from .base import Effect, Param, Plant


class Stribeck(Effect):
    name = "stribeck"
    stage = 80
    #: Blind-suite entries: the (weak, strong) ends of the realistic range (docs/effects.md).
    suite = {f"stribeck_{joints}": ({"joints": joints, "breakaway_ratio": 1.2, "stribeck_velocity": 0.01},
                                    {"joints": joints, "breakaway_ratio": 2.5, "stribeck_velocity": 0.2})
             for joints in ("wheels", "steering", "both")}
    summary = "low-speed friction peak (breakaway above Coulomb) in the wheel or steering joints"
    params = {
        "joints": Param("-", kind="choice", choices=("wheels", "steering", "both"),
                        doc="the wheel joints (wheel side of the gear), the steering joints, or both"),
        "breakaway_ratio": Param("-", 1.0, 5.0, doc="static / Coulomb friction"),
        "stribeck_velocity": Param("rad/s", 1e-3, 1.0, doc="joint speed at which the peak decays"),
    }

    def attach(self, plant: Plant) -> None:
        plant.dynamic_friction()
        which = self.values["joints"]
        self._joints = ((plant.steer if which != "wheels" else [])
                        + (plant.wheel if which != "steering" else []))
        self._slots = np.array([plant.coulomb_joints.index(j) for j in self._joints])
        self._peak = plant.coulomb_base[self._slots] * (self.values["breakaway_ratio"] - 1)

    def before_step(self, plant: Plant) -> None:
        _, speed = plant.joint_states(self._joints)
        plant.coulomb[self._slots] += self._peak * np.exp(-(speed / self.values["stribeck_velocity"])**2)
