"""Effective wheel radius different from the nominal r of the data sheet (tyre wear, compression, tread).

The physical wheel (collision sphere, ride height) gets ``radius``; the data sheet, and so odometry and
the identification, keep the nominal r. The vehicle travels 2π·radius per wheel revolution."""
from __future__ import annotations

from .base import BuildPlan, Effect, Param


class WheelRadius(Effect):
    name = "wheel_radius"
    stage = 30
    #: Blind-suite entries: (low, high) realistic magnitudes as effects-file tables (docs/effects.md).
    suite = {
        "wheel_radius": ({"radius": 0.098},
                         {"radius": 0.096}),
    }
    summary = "physical rolling radius differs from the data sheet's r"
    params = {
        "radius": Param("m", 0.05, 0.2, doc="effective rolling radius of all four wheels"),
    }

    def configure(self, plan: BuildPlan, description) -> None:
        plan.wheel_radius = self.values["radius"]
