"""Floor inclination: the vehicle drives on a plane tilted by ``angle`` rising towards ``uphill_heading``.

Implemented as the tilted gravity vector in the world frame (equivalent to a tilted floor): a downhill
force m·g·sin(angle) on every body, wheel loads g·cos(angle)."""
from __future__ import annotations

import math

from .base import Effect, Param, Plant

from qomni.conventions import GRAVITY


class Incline(Effect):
    name = "incline"
    stage = 50
    #: Blind-suite entries: (low, high) realistic magnitudes as effects-file tables (docs/effects.md).
    suite = {
        "incline": ({"angle": 0.01},
                    {"angle": 0.02}),
    }
    summary = "floor inclination (tilted gravity)"
    params = {
        "angle": Param("rad", 0.0, 0.3, doc="inclination of the floor"),
        "uphill_heading": Param("rad", -2 * math.pi, 2 * math.pi, default=0.0,
                                doc="world-frame direction of steepest ascent (0: +x)"),
    }

    def gravity(self) -> tuple[float, float, float]:
        """World-frame gravity vector, m/s²."""
        theta, psi = self.values["angle"], self.values["uphill_heading"]
        down = GRAVITY * math.sin(theta)
        return -down * math.cos(psi), -down * math.sin(psi), -GRAVITY * math.cos(theta)

    def attach(self, plant: Plant) -> None:
        plant.pb.setGravity(*self.gravity())
