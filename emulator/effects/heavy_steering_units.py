"""Heavy steering units: the real mass of the steering forks (motor, gearbox, fork) and wheels.

The paper adds the steering units' masses to the chassis and so assumes a constant total yaw inertia
C_ch + C_l + C_r and no coupling between α and γ_ch (a ≪ √(l² + b²)/2). With heavy units the wheel
centres, a outward of the steering axes, move with α: the yaw inertia depends on the configuration and
steering accelerates the chassis and vice versa. The lumped values at α = 0 stay the truth (the masses
are taken out of the chassis, see ``emulator.urdf.body_inertias``)."""
from __future__ import annotations

from .base import BuildPlan, Effect, Param


class HeavySteeringUnits(Effect):
    name = "heavy_steering_units"
    stage = 10
    #: Blind-suite entries: the (weak, strong) ends of the realistic range (docs/effects.md).
    suite = {"heavy_steering_units": ({"steering_unit_mass": 5.0, "wheel_mass": 2.0},
                                      {"steering_unit_mass": 40.0, "wheel_mass": 15.0})}
    summary = "real steering-unit and wheel masses: configuration-dependent yaw inertia, α–γ coupling"
    params = {
        "steering_unit_mass": Param("kg", 0.05, 100.0, doc="per steering fork, centre on the steering axis"),
        "wheel_mass": Param("kg", 0.05, 50.0, doc="per wheel, centre at the wheel centre"),
    }

    def configure(self, plan: BuildPlan, description) -> None:
        plan.steering_unit_mass = self.values["steering_unit_mass"]
        plan.wheel_mass = self.values["wheel_mass"]
