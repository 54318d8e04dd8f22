"""The emulated vehicle: PyBullet physics of the prototype behind its drives' and sensors' interface.

What a drive can do to it (apply a motor torque) and what its sensors report (``SensorReading``) are the
whole interface the HIL layer uses. ``true_state`` and ``effects`` exist for tests and the truth
comparison only; they are never put on the bus.

The vehicle is the ideal vehicle (the paper's assumptions hold) plus the unmodelled effects of an
``EffectSet`` (emulator/effects, docs/effects.md); the default is the prototype, whose only effect is its
heavy steering units.
"""
from __future__ import annotations

import math
import tempfile
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .description import VehicleDescription
from .effects import EffectSet, Plant
from .effects.base import ideal_plan
from .sensors import SensorReading
from .urdf import WHEELS, vehicle_urdf

from qomni.conventions import GRAVITY
from .bullet import bullet_client, pybullet
SETTLE_TIME = 0.3  # s of physics run at construction so the soft contacts reach equilibrium
LIFT_HEIGHT = 0.3  # m the lifted vehicle's wheels hang above the floor


@dataclass(frozen=True)
class TrueState:
    """Ground truth of the emulated vehicle (tests and truth comparison only).

    Attributes:
        time: s.
        pose: (3,) world x [m], y [m], yaw γ_ch [rad].
        velocity: (3,) chassis-frame ẋ_ch, ẏ_ch [m/s] and γ̇_ch [rad/s].
        alpha: (2,) α_l, α_r [rad] (front steering joints).
        alpha_rear: (2,) rear steering joints, −α when the coupling holds [rad].
        alpha_dot: (2,) [rad/s].
        beta: (4,) wheel rolling angles fl, rl, fr, rr [rad] (wheel side of the gear).
        beta_dot: (4,) [rad/s].
        applied_motor_torque: (4,) N m, motor side, as applied (ripple included).
    """

    time: float
    pose: np.ndarray
    velocity: np.ndarray
    alpha: np.ndarray
    alpha_rear: np.ndarray
    alpha_dot: np.ndarray
    beta: np.ndarray
    beta_dot: np.ndarray
    applied_motor_torque: np.ndarray


class Emulator:
    """PyBullet model of the vehicle, stepped by its drives.

    Args:
        description: the vehicle; ``None`` is the prototype (``VehicleDescription.load()``).
        seed: seeds torque ripple and sensor noise; the same seed and commands give bit-identical runs.
        lifted: chassis held fixed above the floor, wheels free (single-axis identification set-up).
        gui: open PyBullet's GUI window instead of DIRECT mode (needs a display).
        time_step: physics step in s, at most 1 ms; the drives' cycle time must be a multiple of it (default:
            1 ms, or the longest step below it that divides the cycle time).
        initial_alpha: (α_l, α_r) in rad the vehicle was parked with (wheels aligned for a mode).
        effects: the unmodelled effects on top of the ideal vehicle (``EffectSet.ideal()``: none);
            ``None`` is the prototype (``EffectSet.prototype``: heavy steering units with the
            description's ``[body]`` masses).

    Attributes:
        effects: the active ``EffectSet`` (tests and truth comparison only, never on the bus).

    Raises:
        ValueError: bad time step; ``EffectsError`` (a ValueError) for an effect that does not fit.
    """

    def __init__(self, description: VehicleDescription | None = None, *, seed: int = 0,
                 lifted: bool = False, gui: bool = False, time_step: float | None = None,
                 initial_alpha: tuple[float, float] = (0.0, 0.0), effects: EffectSet | None = None):
        self.description = description or VehicleDescription.load()
        d = self.description
        self.effects = effects if effects is not None else EffectSet.prototype(d)
        self._effects = [e.fresh() for e in self.effects]  # run-time state is per vehicle
        if time_step is None:            # 1 ms, or the longest step below it that divides the SYNC period
            time_step = d.drive.cycle_time / math.ceil(d.drive.cycle_time / 0.001 - 1e-9)
        if not 0 < time_step <= 0.001 + 1e-12:
            raise ValueError(f"time_step must be in (0, 1 ms], got {time_step}")
        cycle_steps = d.drive.cycle_time / time_step
        if abs(cycle_steps - round(cycle_steps)) > 1e-9:
            raise ValueError(f"cycle time {d.drive.cycle_time} s is not a multiple of {time_step} s")
        self.time_step = time_step
        self.lifted = lifted
        self._rng = np.random.default_rng(seed)
        self._i_G, self._increments = d.drive.i_G, d.drive.encoder_increments
        self._ripple_sigma = d.noise.motor_torque_ripple
        self._steps = 0
        self._commanded = np.zeros(4)
        self._applied = np.zeros(4)
        self._pb = bullet_client(gui)
        self._build()
        limit = d.geometry.steering_limit
        if any(abs(a) > limit for a in initial_alpha):
            raise ValueError(f"initial_alpha {initial_alpha} outside the stops ±{limit}")
        alpha_l, alpha_r = initial_alpha
        for joint, angle in zip(self._steer, (alpha_l, -alpha_l, alpha_r, -alpha_r)):
            self._pb.resetJointState(self.body, joint, angle, 0.0)
        velocity_window = max(1, round(0.002 / time_step))
        # the encoders' wheel angles over the velocity window; turned into counts only when read
        self._position_history: deque[np.ndarray] = deque(maxlen=velocity_window + 1)
        for _ in range(round(SETTLE_TIME / time_step)):
            self._physics_step()
        self._steps = 0
        self._sensed_joints = [*self._plant.encoder_joints, self._steer[0], self._steer[2]]
        self._n_encoders = len(self._plant.encoder_joints)
        self._angles_now = self._angles_before = self._sensed_angles()
        self._sampled = self._sampled_angles()
        self._counts_of: tuple[np.ndarray | None, np.ndarray | None] = (None, None)
        self._position_history.clear()
        self._position_history.append(self._wheel_angles())

    # -- construction -----------------------------------------------------------------------
    def _build(self) -> None:
        pb, d = self._pb, self.description
        t, bd = d.truth, d.body
        # Box friction (rolling and axle directions clamped at μN each) instead of PyBullet's implicit
        # cone: with the cone a wheel sliding sideways also slips along its rolling direction, 15–40 mm/s
        # at 0.8 m/s for a 10–20 mrad toe, where Coulomb's cone gives ≈ 1 mm/s (docs/effects.md).
        pb.setPhysicsEngineParameter(fixedTimeStep=self.time_step, numSubSteps=0,
                                     deterministicOverlappingPairs=1, enableConeFriction=0)
        pb.setTimeStep(self.time_step)  # before any motor or constraint (DESIGN.md)
        pb.setGravity(0, 0, -GRAVITY)
        plane = pb.createMultiBody(0, pb.createCollisionShape(pybullet.GEOM_PLANE))
        pb.changeDynamics(plane, -1, lateralFriction=1.0, spinningFriction=0, rollingFriction=0)
        plan = ideal_plan(d)
        for effect in self._effects:
            effect.configure(plan, d)
        self.plan = plan
        pb.setPhysicsEngineParameter(numSolverIterations=plan.solver_iterations)
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "vehicle.urdf"
            path.write_text(vehicle_urdf(d, plan))
            height = plan.wheel_radius + (LIFT_HEIGHT if self.lifted else 0.0)
            self.body = pb.loadURDF(str(path), [0, 0, height], useFixedBase=self.lifted,
                                    flags=pybullet.URDF_USE_INERTIA_FROM_FILE)
        names = {pb.getJointInfo(self.body, j)[1].decode(): j for j in range(pb.getNumJoints(self.body))}
        self._steer = [names[f"steer_{w}"] for w in WHEELS]
        self._wheel = [names[f"wheel_{w}"] for w in WHEELS]
        rotor = [names[f"motor_{w}"] for w in WHEELS] if plan.rotor_fraction > 0 else []
        pb.changeDynamics(self.body, -1, linearDamping=0, angularDamping=0)
        for j in range(pb.getNumJoints(self.body)):
            pb.changeDynamics(self.body, j, linearDamping=0, angularDamping=0)
        for j, w in zip(self._wheel, WHEELS):
            pb.changeDynamics(self.body, j, lateralFriction=bd.tire_friction, spinningFriction=0,
                              rollingFriction=0, contactStiffness=bd.contact_stiffness,
                              contactDamping=bd.contact_damping, jointDamping=t.d_vw)
        for j, w in zip(self._steer, WHEELS):
            d_v = t.d_vl if w[1] == "l" else t.d_vr
            pb.changeDynamics(self.body, j, jointDamping=d_v / 2)  # front + rear share the side's d_v
        # Mirror coupling of front and rear steering on each side: q_rear = -q_front.
        self._couplings = []
        for front, rear in ((0, 1), (2, 3)):
            c = pb.createConstraint(self.body, self._steer[front], self.body, self._steer[rear],
                                    pybullet.JOINT_GEAR, [0, 0, 1], [0, 0, 0], [0, 0, 0])
            pb.changeConstraint(c, gearRatio=1, maxForce=1e5, erp=0.2)
            self._couplings.append(c)
        joints = self._steer + self._wheel
        pb.setJointMotorControlArray(self.body, joints + rotor, pybullet.VELOCITY_CONTROL,
                                     forces=[0.0] * len(joints + rotor))
        # Coulomb friction with true stiction: a velocity motor holding 0 up to d_c.
        coulomb = [(t.d_cl if w[1] == "l" else t.d_cr) / 2 for w in WHEELS] + [t.d_cw] * 4
        pb.setJointMotorControlArray(self.body, joints, pybullet.VELOCITY_CONTROL,
                                     targetVelocities=[0.0] * len(joints), forces=coulomb)
        self._plant = Plant(pb, self.body, plane, self.time_step, d, plan, self._steer, self._wheel,
                            rotor, self._couplings, np.array(coulomb))
        for effect in self._effects:
            effect.attach(self._plant)
        self._shapers = [e for e in self._effects if e.shapes_torque()]
        self._steppers = [e for e in self._effects if e.steps()]
        self._reporters = [e for e in self._effects if e.shapes_report()]

    # -- drive interface ---------------------------------------------------------------------
    @property
    def time(self) -> float:
        """Emulated time in s since the vehicle was set up."""
        return self._steps * self.time_step

    def set_motor_torques(self, motor_torque) -> None:
        """Command the four wheel motors; held until the next call.

        Args:
            motor_torque: (4,) N m on the motor side, order fl, rl, fr, rr. Clipped to ±max_torque;
                the drive adds zero-mean torque ripple at every physics step.

        Raises:
            ValueError: wrong shape or a non-finite value.
        """
        u = np.asarray(motor_torque, dtype=float)
        if u.shape != (4,) or not np.isfinite(u).all():
            raise ValueError(f"motor_torque must be 4 finite values, got {motor_torque!r}")
        limit = self.description.drive.max_torque
        self._commanded = np.minimum(np.maximum(u, -limit), limit)

    def step(self, duration: float) -> None:
        """Advance the physics by ``duration`` s (rounded to whole physics steps)."""
        history = self._position_history
        for _ in range(round(duration / self.time_step)):
            self._physics_step()
            self._read_sensed_joints()
            history.append(self._wheel_angles())

    def _physics_step(self) -> None:
        # Torque ripple: zero-mean, fresh every physics step, only while the drive produces torque.
        ripple = self._rng.normal(0.0, self._ripple_sigma, 4)
        applied = self._commanded + ripple * (self._commanded != 0)
        for effect in self._shapers:
            applied = effect.drive_torque(applied)
        self._applied = applied
        wheel_torque = self._i_G * applied
        plant = self._plant
        if self._steppers:
            plant.torque[:] = 0.0
            plant.torque[:4] = wheel_torque
            if plant.friction_dynamic:
                plant.coulomb[:] = plant.coulomb_base
            for effect in self._steppers:
                effect.before_step(plant)
            if plant.friction_dynamic:
                self._pb.setJointMotorControlArray(
                    self.body, plant.coulomb_joints, pybullet.VELOCITY_CONTROL,
                    targetVelocities=[0.0] * len(plant.coulomb_joints), forces=plant.coulomb.tolist())
            wheel_torque = plant.torque
        self._pb.setJointMotorControlArray(self.body, plant.torque_joints, pybullet.TORQUE_CONTROL,
                                           forces=wheel_torque.tolist())
        self._pb.stepSimulation()
        self._steps += 1

    def _sensed_angles(self) -> np.ndarray:
        """The sensed joints' angles now (encoder joints, then the fl and fr steering joints), rad."""
        return np.array([s[0] for s in self._pb.getJointStates(self.body, self._sensed_joints)])

    def _read_sensed_joints(self) -> None:
        """Advance the sensed joints' angles by the physics step just taken."""
        self._angles_before, self._angles_now = self._angles_now, self._sensed_angles()
        self._sampled = self._sampled_angles()

    def _sampled_angles(self) -> np.ndarray:
        """The sensed joints' angles at the sampling instant of the continuous motion, rad.

        PyBullet integrates semi-implicitly (v ← v + h a, then q ← q + h v): over steps of constant
        acceleration its q_n runs (h/2)(v_n − v_0) ahead of the continuous motion its step-wise forces
        produce, and the mean of the last two steps' angles, (q_n + q_{n−1})/2 = q_n − (h/2) v_n, is that
        motion at t_n up to a constant. A sensor of a real vehicle samples the motion at t_n; reading q_n
        would make the torque appear to act h/2 early (a torque lag of +0.5 ms at h = 1 ms,
        docs/conventions.md, Torque timing).
        """
        return 0.5 * (self._angles_now + self._angles_before)

    def _wheel_angles(self) -> np.ndarray:
        """Angles the motor encoders see, wheel side (the wheels, or the motor rotors behind a gear)."""
        return self._sampled[:self._n_encoders]

    def _encoder_counts(self, wheel_angles: np.ndarray) -> np.ndarray:
        """Motor encoder positions (increments, int64) of wheel-side angles (rad)."""
        source, counts = self._counts_of
        if wheel_angles is source:                  # the last read's newest sample (T_s = the window)
            return counts
        counts = np.floor(wheel_angles * self._i_G / (2 * math.pi) * self._increments).astype(np.int64)
        self._counts_of = (wheel_angles, counts)
        return counts

    def read_sensors(self) -> SensorReading:
        """Sample every sensor now, at data-sheet resolution (see ``SensorReading``)."""
        drive, noise = self.description.drive, self.description.noise
        history = self._position_history
        oldest = self._encoder_counts(history[0])
        position = self._encoder_counts(history[-1])
        span = (len(history) - 1) * self.time_step
        if span > 0:
            velocity = ((position - oldest) / span).round().astype(np.int64)
        else:
            velocity = np.zeros(4, dtype=np.int64)
        torque = self._commanded.copy()
        for effect in self._reporters:
            torque = effect.reported_torque(torque)
        torque = torque + self._rng.normal(0.0, noise.torque_measurement, 4)
        full = 2 ** drive.steering_sensor_bits
        alpha = self._sampled[-2:]
        counts = np.round(alpha / (2 * math.pi) * full
                          + self._rng.normal(0.0, noise.steering_sensor_lsb, 2))
        return SensorReading(time=self.time, motor_position=position.copy(), motor_velocity=velocity,
                             motor_torque=torque, steering_position=counts.astype(np.int64) % full)

    # -- truth (never on the bus) --------------------------------------------------------------
    def true_state(self) -> TrueState:
        """The physical state (tests and truth comparison only)."""
        pb = self._pb
        pos, orn = pb.getBasePositionAndOrientation(self.body)
        lin, ang = pb.getBaseVelocity(self.body)
        yaw = pb.getEulerFromQuaternion(orn)[2]
        c, s = math.cos(yaw), math.sin(yaw)
        steer = pb.getJointStates(self.body, self._steer)
        wheel = pb.getJointStates(self.body, self._wheel)
        return TrueState(
            time=self.time,
            pose=np.array([pos[0], pos[1], yaw]),
            velocity=np.array([c * lin[0] + s * lin[1], -s * lin[0] + c * lin[1], ang[2]]),
            alpha=np.array([steer[0][0], steer[2][0]]),
            alpha_rear=np.array([steer[1][0], steer[3][0]]),
            alpha_dot=np.array([steer[0][1], steer[2][1]]),
            beta=np.array([w[0] for w in wheel]),
            beta_dot=np.array([w[1] for w in wheel]),
            applied_motor_torque=self._applied.copy(),
        )

    def close(self) -> None:
        """Disconnect the physics client; the emulator is unusable afterwards."""
        if self._pb is not None:
            self._pb.disconnect()
            self._pb = None

    def __enter__(self) -> "Emulator":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
