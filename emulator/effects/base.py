"""The contract every unmodelled effect implements, and what it may touch.

An effect is physics the paper's model leaves out. It acts on the emulated vehicle only through the hooks
below, which the :class:`~emulator.vehicle.Emulator` calls in this order:

1. ``configure(plan, description)`` before the URDF is generated: change the rigid bodies (masses,
   wheel radius, an extra payload link, a separate motor rotor behind a gear);
2. ``attach(plant)`` once the body is loaded, before the vehicle settles: gravity, contact parameters,
   constraints, and which joints the effect puts torque on;
3. every physics step, ``drive_torque(applied)`` maps the torque the drive reports (motor side) to the
   torque its motor really applies, then ``before_step(plant)`` sets joint friction limits, joint torques
   and external forces from the current physical state.

Nothing here touches the sensors: an effect shows on the bus only through the motion it causes.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from ..urdf import WHEELS, BuildPlan, FixedLink  # noqa: F401  (re-exported for effects)


class EffectsError(ValueError):
    """An effects file names an unknown effect or parameter, lacks one, or has a wrong type or value."""


@dataclass(frozen=True)
class Param:
    """One parameter of an effect: its unit, allowed range and default (``None``: required).

    ``kind`` is ``"number"``, ``"vector2"`` (two numbers, each within [low, high]) or ``"choice"``
    (one of ``choices``). ``low``/``high`` bound the physically allowed values, not only the realistic
    range the docs give.
    """

    unit: str
    low: float = -math.inf
    high: float = math.inf
    default: Any = None
    kind: str = "number"
    choices: tuple[str, ...] = ()
    doc: str = ""


# The ideal vehicle's steering units and wheels: negligible masses, so the paper's assumption
# a ≪ √(l² + b²)/2 (constant yaw inertia, no α–γ coupling) holds; the lumped inertias stay the truth.
IDEAL_STEERING_UNIT_MASS = 0.2  # kg
IDEAL_WHEEL_MASS = 0.3  # kg


def ideal_plan(description) -> BuildPlan:
    """The ideal vehicle's bodies: negligible steering-unit and wheel masses, nominal wheel radius."""
    return BuildPlan(steering_unit_mass=IDEAL_STEERING_UNIT_MASS, wheel_mass=IDEAL_WHEEL_MASS,
                     wheel_radius=description.geometry.r)


class Plant:
    """The loaded vehicle as effects see it (built by the emulator; effects read and set, never sense).

    Attributes:
        pb: the PyBullet client; body, plane: body ids.
        time_step: s.
        description: the vehicle description; plan: the build plan it was built with.
        steer, wheel: joint indices in wheel order fl, rl, fr, rr.
        drive_joints: where the motor torque acts (the wheels, or the motor rotors behind a gear).
        encoder_joints: what the motor encoders read (the same joints as ``drive_joints``).
        couplings: the two front/rear mirror constraints (left, right).
        coulomb_joints: ``steer + wheel``; coulomb_base: their Coulomb friction limits (N m);
        coulomb: this step's limits — effects add to it in ``before_step`` when they said
            ``dynamic_friction()`` in ``attach``.
        torque_joints: joints that get a torque each step; torque: this step's torques (N m), effects add
            to it at ``torque_slots(...)``.
    """

    def __init__(self, pb, body: int, plane: int, time_step: float, description, plan: BuildPlan,
                 steer: list[int], wheel: list[int], rotor: list[int] | None, couplings: list[int],
                 coulomb_base: np.ndarray):
        self.pb, self.body, self.plane = pb, body, plane
        self.time_step = time_step
        self.description, self.plan = description, plan
        self.steer, self.wheel, self.rotor = steer, wheel, rotor
        self.drive_joints = rotor if rotor else wheel
        self.encoder_joints = self.drive_joints
        self.couplings = couplings
        self.coulomb_joints = steer + wheel
        self.coulomb_base = coulomb_base
        self.coulomb = coulomb_base.copy()
        self.friction_dynamic = False
        self.torque_joints = list(self.drive_joints)
        self.torque = np.zeros(len(self.torque_joints))

    def dynamic_friction(self) -> None:
        """The Coulomb limits change every step (resent after ``before_step``)."""
        self.friction_dynamic = True

    def torque_slots(self, joints: list[int]) -> np.ndarray:
        """Indices into ``torque`` for ``joints``, adding them to ``torque_joints`` where new."""
        for j in joints:
            if j not in self.torque_joints:
                self.torque_joints.append(j)
        self.torque = np.zeros(len(self.torque_joints))
        return np.array([self.torque_joints.index(j) for j in joints])

    def joint_states(self, joints: list[int]) -> tuple[np.ndarray, np.ndarray]:
        """(positions, velocities) of ``joints`` now."""
        states = self.pb.getJointStates(self.body, joints)
        return np.array([s[0] for s in states]), np.array([s[1] for s in states])


class Effect:
    """One unmodelled effect; subclasses set ``name``, ``params``, ``stage`` and override the hooks they need.

    A subclass in a module of this package is registered by being there (``effect_set.REGISTRY``); its
    ``stage`` orders it among the others where the emulator applies effects in turn (lower first: the
    body's masses before the floor, the drive's torque path last).

    Instances hold their parameter values (``self.values``) and, once attached, their run-time state;
    the emulator builds a fresh instance per vehicle (``fresh``).
    """

    name: ClassVar[str] = ""
    params: ClassVar[dict[str, Param]] = {}
    summary: ClassVar[str] = ""
    stage: ClassVar[int] = 100
    #: Blind-suite entries of the effect: entry name → the (weak, strong) ends of its realistic range
    #: (docs/effects.md), each an effects-file table (usually one entry named as the effect; several
    #: where the effect has variants). ``draw`` samples between them.
    suite: ClassVar[dict[str, tuple[dict, dict]]] = {}

    def __init__(self, **values):
        self.values = {key: values.get(key, spec.default) for key, spec in self.params.items()}

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.values})"

    def fresh(self) -> "Effect":
        return type(self)(**self.values)

    # -- the realistic range ----------------------------------------------------------------
    @classmethod
    def draw(cls, entry: str, rng: np.random.Generator) -> dict:
        """An effects-file table for suite ``entry`` drawn over its realistic range: each number
        independently log-uniform between the two ends' values (lists element by element; equal ends
        stay), then :meth:`instance` picks the direction or instance.

        Raises:
            KeyError: ``entry`` is not one of the effect's suite entries.
        """
        weak, strong = cls.suite[entry]
        table = {key: _between(value, strong.get(key, value), rng) for key, value in weak.items()}
        return cls.instance(entry, table, rng)

    @classmethod
    def instance(cls, entry: str, table: dict, rng: np.random.Generator) -> dict:
        """The drawn table with its direction or instance chosen (a payload's quadrant, the faulty
        drive); the default has none."""
        return table

    @classmethod
    def range_ends(cls, entry: str) -> list[dict]:
        """Effects-file tables at the ends of ``entry``'s realistic range, every direction that bounds it
        (the campaign must complete at each)."""
        return [dict(t) for t in cls.suite[entry]]

    @classmethod
    def drawn(cls, entry: str, table: dict) -> dict:
        """``table`` as :meth:`draw` drew it before :meth:`instance` chose its direction or instance (a
        payload's offset back in the first quadrant, a torque-constant factor above 1 mirrored below it);
        the default has none to undo."""
        return table

    @classmethod
    def range_position(cls, entry: str, table: dict) -> float | None:
        """Where ``table`` lies in ``entry``'s realistic range: 0 at the weak end, 1 at the strong end.

        Each number whose two ends differ is placed on the scale :meth:`draw` samples it on (logarithmic
        between two positive ends, else linear), after :meth:`drawn` has undone the direction or
        instance; the position is the mean over those numbers, each clipped to [0, 1]. None when the
        ends differ in no number.

        Raises:
            KeyError: ``entry`` is not one of the effect's suite entries."""
        weak, strong = cls.suite[entry]
        table = cls.drawn(entry, table)
        positions = [_position(v, a, b) for key, a_value in weak.items()
                     for v, a, b in zip(_numbers(table.get(key)), _numbers(a_value),
                                        _numbers(strong.get(key, a_value))) if a != b]
        return float(np.mean(positions)) if positions else None

    # -- hooks -------------------------------------------------------------------------------
    def configure(self, plan: BuildPlan, description) -> None:
        """Change the rigid bodies before the URDF is generated."""

    def attach(self, plant: Plant) -> None:
        """Set up on the loaded body (before settling)."""

    def drive_torque(self, applied: np.ndarray) -> np.ndarray:
        """Motor-side torque the motors apply this step, from what the drives apply and report."""
        return applied

    def before_step(self, plant: Plant) -> None:
        """Set friction limits, joint torques and external forces for the coming physics step."""

    def reported_torque(self, reported: np.ndarray) -> np.ndarray:
        """(4,) N m motor side: the torque actual (0x6077) the drives report at a SYNC, from the set-point
        they apply from that instant."""
        return reported

    # Which hooks an effect uses: the emulator calls only those every step.
    @classmethod
    def steps(cls) -> bool:
        return cls.before_step is not Effect.before_step

    @classmethod
    def shapes_torque(cls) -> bool:
        return cls.drive_torque is not Effect.drive_torque

    @classmethod
    def shapes_report(cls) -> bool:
        return cls.reported_torque is not Effect.reported_torque


def _between(a, b, rng: np.random.Generator):
    """A value drawn between a and b: log-uniform for two positive numbers, uniform otherwise; lists
    element by element; anything else (a choice) as a."""
    if isinstance(a, (list, tuple)):
        return [_between(x, y, rng) for x, y in zip(a, b)]
    if isinstance(a, bool) or not isinstance(a, (int, float)) or a == b:
        return a
    if a > 0 and b > 0:
        return float(math.exp(rng.uniform(math.log(min(a, b)), math.log(max(a, b)))))
    return float(rng.uniform(min(a, b), max(a, b)))


def mirrored(value: float, nominal: float) -> float:
    """``value`` reflected about ``nominal``: the same deviation on the other side (a torque-constant factor
    above 1, a wheel larger than the data sheet's), as ``instance`` draws it and ``drawn`` undoes it."""
    return 2 * nominal - value


def _numbers(value) -> list[float]:
    """The numbers of a table value (a list element by element); [] for anything else (a choice)."""
    if isinstance(value, (list, tuple)):
        return [x for v in value for x in _numbers(v)]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return []
    return [float(value)]


def _position(value: float, weak: float, strong: float) -> float:
    """``value``'s place between ``weak`` (0) and ``strong`` (1) on :func:`_between`'s scale, clipped."""
    if weak > 0 and strong > 0 and value > 0:
        t = math.log(value / weak) / math.log(strong / weak)
    else:
        t = (value - weak) / (strong - weak)
    return min(max(t, 0.0), 1.0)
