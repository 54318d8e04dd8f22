"""URDF of the vehicle generated from its description.

Bodies: the chassis (base link), four steering forks (revolute about z at the corners P_i, stops at
±steering_limit) and four wheels (continuous joint about the axle, offset a outward of the steering axis,
sphere collision shape — cylinders scrub and lock the steering at rest, see DESIGN.md).

The true parameters (paper Table 2, eq. (18)) are distributed over the bodies so that the paper's
lumped model sees exactly them at α = 0:

- m_ch = chassis + 4·(fork + wheel) masses;
- C_l/2 = fork I_zz + wheel transverse inertia + m_wheel·a² for each left unit (likewise C_r);
- C_ch = chassis I_zz + Σ [m_fork·|P_i|² + m_wheel·(|c_i|² − a²)] at α = 0 (parallel-axis terms; the
  steering units' own inertia is in C_l, C_r);
- B_w = wheel inertia about its axle (motor and gear reflected through i_G included).

Away from α = 0 the wheel offset makes the real yaw inertia configuration dependent (≈0.5 % in mode 4 for
the prototype) — an effect the paper's model neglects.

Where the masses come from: ``[body]`` of the description, or a ``BuildPlan`` (emulator/effects) that the
active effects edited — the ideal vehicle's negligible steering-unit masses, heavy steering units, the
physical wheel radius, a payload fixed to the chassis, a motor rotor behind a gear with backlash.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from xml.sax.saxutils import quoteattr

from .description import DescriptionError, VehicleDescription

from qomni.conventions import SIDE_SIGN as _SIDE_SIGN, WHEELS

SIDE_SIGN = {w: float(s) for w, s in zip(WHEELS, _SIDE_SIGN)}


@dataclass(frozen=True)
class FixedLink:
    """A rigid body fixed to the chassis (mass at ``origin`` in the chassis frame, box inertia)."""

    name: str
    mass: float
    origin: tuple[float, float, float]
    size: tuple[float, float, float]  # box edges x, y, z in m (visual and inertia)

    def inertia(self) -> tuple[float, float, float]:
        x, y, z = self.size
        m = self.mass / 12
        return m * (y * y + z * z), m * (x * x + z * z), m * (x * x + y * y)


@dataclass
class BuildPlan:
    """What the emulator builds the rigid bodies from; effects edit it in ``configure``.

    Attributes:
        steering_unit_mass: kg per steering fork, centre on the steering axis.
        wheel_mass: kg per wheel (rotor included), centre at the wheel centre.
        wheel_radius: m, the physical rolling radius (collision sphere and ride height).
        rotor_fraction: share of B_w on a separate motor+gear rotor link behind the gear (0: none, the
            gear is rigid and B_w sits on the wheel).
        fixed_links: extra bodies fixed to the chassis.
        solver_iterations: PyBullet's constraint-solver iterations per physics step. A wheel link that
            carries only part of B_w (``rotor_fraction`` > 0) needs more for its tyre's friction to
            converge: at 50 it creeps 1.3 % in its rolling direction when steering at rest.
    """

    steering_unit_mass: float
    wheel_mass: float
    wheel_radius: float
    rotor_fraction: float = 0.0
    fixed_links: list[FixedLink] = field(default_factory=list)
    solver_iterations: int = 50


@dataclass(frozen=True)
class BodyInertias:
    """Mass properties of the rigid bodies (kg, kg m², about each body's centre of mass)."""

    chassis_mass: float
    chassis_inertia: tuple[float, float, float]
    fork_mass: float
    fork_izz: dict[str, float]
    wheel_mass: float
    wheel_inertia: tuple[float, float, float]  # (transverse x, axle y, transverse z)


def corner(description: VehicleDescription, wheel: str) -> tuple[float, float]:
    """Steering axis position P_i in the chassis frame, m (docs/conventions.md)."""
    g = description.geometry
    x = g.l / 2 if wheel[0] == "f" else -g.l / 2
    y = g.b / 2 if wheel[1] == "l" else -g.b / 2
    return x, y


def prototype_plan(description: VehicleDescription) -> BuildPlan:
    """The bodies as ``[body]`` describes them (steering-unit and wheel masses), nominal wheel radius."""
    bd = description.body
    return BuildPlan(steering_unit_mass=bd.steering_unit_mass, wheel_mass=bd.wheel_mass,
                     wheel_radius=description.geometry.r)


def body_inertias(description: VehicleDescription, plan: BuildPlan | None = None) -> BodyInertias:
    """Distribute the truth over the bodies as the module docstring says (masses from ``plan``,
    default ``prototype_plan``; extra fixed links are on top of the truth and not included here).

    Raises:
        DescriptionError: if the body masses leave a negative chassis or fork inertia.
    """
    g, t, bd = description.geometry, description.truth, description.body
    plan = plan or prototype_plan(description)
    m_f, m_w, i_wt = plan.steering_unit_mass, plan.wheel_mass, bd.wheel_transverse_inertia
    if 4 * (m_f + m_w) >= t.m_ch:
        raise DescriptionError(
            f"{description.source}: 4·(steering_unit_mass + wheel_mass) = {4 * (m_f + m_w)} kg "
            f"must be below truth.m_ch = {t.m_ch} kg")
    fork_izz = {}
    for w in WHEELS:
        c_side = t.C_l if w[1] == "l" else t.C_r
        fork_izz[w] = c_side / 2 - i_wt - m_w * g.a**2
        if fork_izz[w] <= 0:
            raise DescriptionError(
                f"{description.source}: steering inertia {c_side} too small for wheel_mass and "
                f"wheel_transverse_inertia (fork inertia would be {fork_izz[w]:.4g} kg m²)")
    r2 = (g.l**2 + g.b**2) / 4
    chassis_izz = t.C_ch - 4 * (m_f * r2 + m_w * (r2 + g.a * g.b))
    chassis_mass = t.m_ch - 4 * (m_f + m_w)
    if chassis_izz <= 0:
        raise DescriptionError(f"{description.source}: C_ch too small for the body masses")
    length, width, height = g.l + 0.2, g.b, bd.chassis_height
    ixx = chassis_mass / 12 * (width * width + height * height)   # (a float's ** raises on overflow)
    iyy = chassis_mass / 12 * (length * length + height * height)
    if not (math.isfinite(ixx) and math.isfinite(iyy)):
        raise DescriptionError(f"{description.source}: body.chassis_height = {height} m gives the chassis a "
                               f"roll or pitch inertia that is not finite")
    scale = max(1.0, 1.05 * chassis_izz / (ixx + iyy))  # triangle inequality I_xx + I_yy >= I_zz
    return BodyInertias(
        chassis_mass=chassis_mass,
        chassis_inertia=(ixx * scale, iyy * scale, chassis_izz),
        fork_mass=m_f,
        fork_izz=fork_izz,
        wheel_mass=m_w,
        wheel_inertia=(i_wt, t.B_w, i_wt),
    )


def _inertial(mass: float, ixx: float, iyy: float, izz: float) -> str:
    return (f'<inertial><origin xyz="0 0 0"/><mass value="{mass:.10g}"/>'
            f'<inertia ixx="{ixx:.10g}" iyy="{iyy:.10g}" izz="{izz:.10g}" ixy="0" ixz="0" iyz="0"/>'
            f'</inertial>')


def vehicle_urdf(description: VehicleDescription, plan: BuildPlan | None = None) -> str:
    """The vehicle as a URDF document (string). Joint names: ``steer_<w>``, ``wheel_<w>``; with a
    separate motor rotor (``plan.rotor_fraction > 0``) also ``motor_<w>``; fixed links by their names.

    Joint friction is not in the URDF: the emulator sets viscous damping and Coulomb friction (as a
    velocity motor with target 0) itself, so both equal the truth exactly.
    """
    g, bd = description.geometry, description.body
    plan = plan or prototype_plan(description)
    inert = body_inertias(description, plan)
    radius, f = plan.wheel_radius, plan.rotor_fraction
    length, width, height = g.l + 0.2, g.b, bd.chassis_height
    parts = [f'<robot name={quoteattr(description.name)}>',
             '<material name="body"><color rgba="0.25 0.45 0.7 1"/></material>',
             '<material name="tire"><color rgba="0.1 0.1 0.1 1"/></material>',
             '<material name="fork"><color rgba="0.8 0.5 0.1 1"/></material>',
             '<link name="chassis">',
             _inertial(inert.chassis_mass, *inert.chassis_inertia),
             f'<visual><origin xyz="0 0 {0.05 + height / 2:.6g}"/><geometry>'
             f'<box size="{length:.6g} {width:.6g} {height:.6g}"/></geometry>'
             '<material name="body"/></visual>',
             '</link>']
    for link in plan.fixed_links:
        parts += [
            f'<joint name="{link.name}_joint" type="fixed"><parent link="chassis"/>'
            f'<child link="{link.name}"/><origin xyz="{" ".join(f"{v:.10g}" for v in link.origin)}"/>'
            '</joint>',
            f'<link name="{link.name}">', _inertial(link.mass, *link.inertia()),
            f'<visual><geometry><box size="{" ".join(f"{v:.6g}" for v in link.size)}"/></geometry>'
            '<material name="fork"/></visual></link>']
    wheel_inertia = tuple(i * (1 - f) for i in inert.wheel_inertia)
    for w in WHEELS:
        px, py = corner(description, w)
        side = SIDE_SIGN[w]
        izz = inert.fork_izz[w]
        parts += [
            f'<joint name="steer_{w}" type="revolute"><parent link="chassis"/><child link="fork_{w}"/>'
            f'<origin xyz="{px:.10g} {py:.10g} 0"/><axis xyz="0 0 1"/>'
            f'<limit lower="{-g.steering_limit:.10g}" upper="{g.steering_limit:.10g}" effort="1e6" '
            f'velocity="100"/></joint>',
            f'<link name="fork_{w}">',
            _inertial(inert.fork_mass, max(izz, 0.05), max(izz, 0.05), izz),
            f'<visual><origin xyz="0 0 0.12"/><geometry><cylinder radius="0.04" length="0.1"/>'
            '</geometry><material name="fork"/></visual>',
            '</link>',
            f'<joint name="wheel_{w}" type="continuous"><parent link="fork_{w}"/>'
            f'<child link="wheel_{w}"/><origin xyz="0 {side * g.a:.10g} 0"/><axis xyz="0 1 0"/>'
            '</joint>',
            f'<link name="wheel_{w}">',
            _inertial(inert.wheel_mass * (1 - f), *wheel_inertia),
            f'<visual><origin rpy="{math.pi / 2:.10g} 0 0"/><geometry>'
            f'<cylinder radius="{radius:.10g}" length="0.06"/></geometry><material name="tire"/></visual>',
            f'<collision><geometry><sphere radius="{radius:.10g}"/></geometry></collision>',
            '</link>',
        ]
        if f > 0:  # motor + gear rotor, reflected to the wheel side, coupled to the wheel by effects
            parts += [
                f'<joint name="motor_{w}" type="continuous"><parent link="fork_{w}"/>'
                f'<child link="rotor_{w}"/><origin xyz="0 {side * g.a:.10g} 0"/><axis xyz="0 1 0"/>'
                '</joint>',
                f'<link name="rotor_{w}">',
                _inertial(inert.wheel_mass * f, *(i * f for i in inert.wheel_inertia)),
                '</link>',
            ]
    parts.append('</robot>')
    return "\n".join(parts)
