"""Payload: a rigid load fixed on the chassis, with its centre of mass off the chassis centre.

It adds mass and yaw inertia (its own and m·|offset|²), moves the vehicle's centre of mass away from the
chassis centre (the paper's model has it there) and shifts the wheel loads. Built as a URDF link
(uniform box 0.6 m × 0.5 m × 2·height, resting on the chassis top) on a fixed joint."""
from __future__ import annotations

from .base import BuildPlan, Effect, FixedLink, Param

FOOTPRINT = (0.6, 0.5)  # m, x and y edges of the payload box


class Payload(Effect):
    name = "payload"
    stage = 20
    #: Blind-suite entries: (low, high) realistic magnitudes as effects-file tables (docs/effects.md).
    suite = {
        "payload": ({"mass": 150.0, "com_offset": [0.25, 0.15], "height": 0.3},
                    {"mass": 300.0, "com_offset": [0.25, 0.15], "height": 0.3}),
    }
    summary = "extra rigid mass on the chassis with a centre-of-mass offset"
    params = {
        "mass": Param("kg", 0.0, 2000.0, doc="payload mass"),
        "com_offset": Param("m", -0.5, 0.5, default=(0.0, 0.0), kind="vector2",
                            doc="(x, y) of its centre of mass in the chassis frame"),
        "height": Param("m", 0.02, 1.0, default=0.2,
                        doc="height of its centre of mass above the chassis top"),
    }

    def configure(self, plan: BuildPlan, description) -> None:
        x, y = self.values["com_offset"]
        h = self.values["height"]
        top = 0.05 + description.body.chassis_height  # the chassis box's top in the chassis frame
        plan.fixed_links.append(FixedLink("payload", self.values["mass"], (x, y, top + h),
                                          (*FOOTPRINT, 2 * h)))
