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
    #: Blind-suite entries: the (weak, strong) ends of the realistic range (docs/effects.md).
    suite = {"payload": ({"mass": 50.0, "com_offset": [0.05, 0.05], "height": 0.05},
                         {"mass": 400.0, "com_offset": [0.4, 0.4], "height": 0.5})}
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

    @classmethod
    def instance(cls, entry: str, table: dict, rng) -> dict:
        """The centre-of-mass offset in any quadrant (each coordinate's sign drawn)."""
        return {**table, "com_offset": [float(v * rng.choice((-1.0, 1.0))) for v in table["com_offset"]]}

    @classmethod
    def drawn(cls, entry: str, table: dict) -> dict:
        """The offset back in the first quadrant."""
        return {**table, "com_offset": [abs(float(v)) for v in table["com_offset"]]}

    @classmethod
    def range_ends(cls, entry: str) -> list[dict]:
        """Both ends, the strong one in every quadrant."""
        weak, strong = cls.suite[entry]
        return [dict(weak)] + [{**strong, "com_offset": [sx * strong["com_offset"][0], sy * strong["com_offset"][1]]}
                               for sx in (1.0, -1.0) for sy in (1.0, -1.0)]
