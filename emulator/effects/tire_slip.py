"""Tyre lateral slip: the wheels carry side force through a slip angle instead of rigid contact.

The wheel/floor contact keeps PyBullet's friction along the rolling direction but (almost) none along the
axle (anisotropic friction; the emulator's box friction keeps the directions independent). Each physics
step every loaded wheel gets the lateral tyre force F = −C_α·atan(v_lat / max(|v_long|, v_min)),
saturated at μ·N, at its contact point, from the contact point's velocity across (v_lat) and along
(v_long) the wheel and its contact normal force N. The vehicle drifts and under-steers in a steered
circle by the slip angles F/C_α the side forces need; straight driving and steering at rest need no side
force and are unaffected."""
from __future__ import annotations

import math


from .base import Effect, Param, Plant
from .rolling_resistance import wheel_loads
from ..bullet import pybullet

LATERAL_FRICTION_SCALE = 1e-3  # PyBullet's remaining Coulomb friction along the axle
V_MIN = 0.05  # m/s, slip-angle denominator floor at standstill (keeps the force finite and stable)


class TireSlip(Effect):
    name = "tire_slip"
    stage = 70
    #: Blind-suite entries: the (weak, strong) ends of the realistic range (docs/effects.md).
    suite = {"tire_slip": ({"cornering_stiffness": 30000.0}, {"cornering_stiffness": 5000.0})}
    summary = "lateral tyre force from the slip angle (cornering stiffness) instead of rigid contact"
    params = {
        "cornering_stiffness": Param("N/rad", 500.0, 2e5, doc="C_α per wheel"),
    }

    def attach(self, plant: Plant) -> None:
        # Relies on the emulator's box friction: cone friction couples the two friction rows in impulse
        # space, and with the axle row scaled down its impulses would grow by 1/scale and starve the
        # rolling direction (no traction at α = 0).
        for j in plant.wheel:
            plant.pb.changeDynamics(plant.body, j, anisotropicFriction=[1.0, LATERAL_FRICTION_SCALE, 1.0])
        self._link = {j: i for i, j in enumerate(plant.wheel)}
        self._mu = plant.description.body.tire_friction  # × the floor's 1.0
        self._radius = plant.plan.wheel_radius
        # stiffest the explicit force may act at standstill: half the chassis mass share per wheel per step
        self._max_damping = 0.5 * plant.description.truth.m_ch / 4 / plant.time_step

    def before_step(self, plant: Plant) -> None:
        # Four wheels of scalar arithmetic: plain floats are several times faster than numpy here.
        pb, radius, stiffness = plant.pb, self._radius, self.values["cornering_stiffness"]
        load = wheel_loads(plant, self._link).tolist()
        if not any(load):
            return
        states = pb.getLinkStates(plant.body, plant.wheel, computeLinkVelocity=1,
                                  computeForwardKinematics=1)
        for joint, state, normal in zip(plant.wheel, states, load):
            if normal <= 0:
                continue
            x, y, z, w = state[5]
            lat_x, lat_y = 2 * (x * y - w * z), 1 - 2 * (x * x + z * z)  # axle, horizontal part
            norm = math.hypot(lat_x, lat_y)
            lat_x, lat_y = lat_x / norm, lat_y / norm
            (vx, vy, _), (wx, wy, _) = state[6], state[7]
            # contact point r below the centre: v = v_centre + ω × (0, 0, −r); e_long = e_lat × z
            v_lat = lat_x * (vx - radius * wy) + lat_y * (vy + radius * wx)
            v_long = abs(lat_y * vx - lat_x * vy)
            force = -stiffness * math.atan(v_lat / max(v_long, V_MIN))
            limit = min(self._max_damping * abs(v_lat), self._mu * normal)
            force = max(-limit, min(limit, force))
            cx, cy, cz = state[4]
            pb.applyExternalForce(plant.body, joint, (force * lat_x, force * lat_y, 0.0),
                                  (cx, cy, cz - radius), pybullet.WORLD_FRAME)
