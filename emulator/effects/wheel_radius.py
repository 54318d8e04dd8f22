"""Effective wheel radius different from the nominal r of the data sheet (tyre wear, compression, tread).

The physical wheel (collision sphere, ride height) gets ``radius``; the data sheet, and so odometry and
the identification, keep the nominal r. The vehicle travels 2π·radius per wheel revolution."""
from __future__ import annotations

from .base import BuildPlan, Effect, Param, mirrored


class WheelRadius(Effect):
    name = "wheel_radius"
    stage = 30
    #: Blind-suite entries: the (weak, strong) ends of the realistic range (docs/effects.md).
    suite = {"wheel_radius": ({"radius": 0.098}, {"radius": 0.095})}
    summary = "physical rolling radius differs from the data sheet's r"
    params = {
        "radius": Param("m", 0.05, 0.2, doc="effective rolling radius of all four wheels"),
    }

    def configure(self, plan: BuildPlan, description) -> None:
        plan.wheel_radius = self.values["radius"]

    #: The data sheet's nominal r, m, that the drawn radius deviates from.
    NOMINAL = 0.1

    @classmethod
    def instance(cls, entry: str, table: dict, rng) -> dict:
        """A worn (smaller) or a larger wheel by the drawn deviation from the nominal 0.1 m."""
        radius = table["radius"] if rng.random() < 0.5 else mirrored(table["radius"], cls.NOMINAL)
        return {**table, "radius": float(radius)}

    @classmethod
    def drawn(cls, entry: str, table: dict) -> dict:
        """A larger wheel mirrored to the smaller one of the same deviation from the nominal radius."""
        radius = float(table["radius"])
        return {**table, "radius": radius if radius <= cls.NOMINAL else mirrored(radius, cls.NOMINAL)}

    @classmethod
    def range_ends(cls, entry: str) -> list[dict]:
        """Smaller and larger wheels at both ends."""
        return [{"radius": r} for t in cls.suite[entry] for r in (t["radius"], mirrored(t["radius"], cls.NOMINAL))]
