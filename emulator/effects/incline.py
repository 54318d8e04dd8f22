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
    #: Blind-suite entries: the (weak, strong) ends of the realistic range (docs/effects.md).
    suite = {"incline": ({"angle": 0.005}, {"angle": 0.05})}
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

    #: A slope within this angle of purely lateral to the campaign's straight motions (its straight step and
    #: lane change drive along the world x axis) does work only in the arcs. The suite's draw leaves these
    #: directions out so that its recorded draws stay as drawn; they are measured apart (docs/results.md).
    LATERAL_EXCLUSION = math.radians(25.0)

    @classmethod
    def instance(cls, entry: str, table: dict, rng) -> dict:
        """The uphill direction drawn over every heading that does work on the campaign: uniform on the
        circle but for ±``LATERAL_EXCLUSION`` around ±π/2."""
        half = math.pi / 2 - cls.LATERAL_EXCLUSION
        heading = rng.uniform(-half, half) + (math.pi if rng.random() < 0.5 else 0.0)
        return {**table, "uphill_heading": float(heading)}

    @classmethod
    def range_ends(cls, entry: str) -> list[dict]:
        """Both ends, the steep one uphill along +x, −x and at the edge of the lateral exclusion."""
        weak, strong = cls.suite[entry]
        edge = math.pi / 2 - cls.LATERAL_EXCLUSION
        return [{**weak, "uphill_heading": 0.0}] + [{**strong, "uphill_heading": h} for h in (0.0, math.pi, edge)]
