"""Co-simulating the plant FMU from Python with fmpy (FMI 2.0 or 3.0): a version-neutral slave wrapper and
an adapter that makes the plant look like the vehicle (:class:`qomni.vehicle_interface.VehicleInterface`), so the
campaign controller (:class:`ident.controller.StepController`) drives the FMU exactly as it drives the
vehicle over CAN.

``fmpy`` is imported on first use (it is a test / optional dependency of qomni).
"""
from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from qomni.vehicle_interface import Measurement
from qomni.conventions import WHEELS

from .plant_spec import OUTPUTS

MOTOR_TORQUE = tuple(f"motor_torque.{w}" for w in WHEELS)
REAL_OUTPUTS = tuple(name for name, *_ in OUTPUTS)
"""The plant FMU's Float64 outputs, in this order (:data:`qomni.fmu.plant_spec.OUTPUTS`)."""
MOTOR_POSITION = tuple(n for n in REAL_OUTPUTS if n.startswith("motor_position."))
MOTOR_VELOCITY = tuple(n for n in REAL_OUTPUTS if n.startswith("motor_velocity."))
POSE, VELOCITY = REAL_OUTPUTS[0:3], REAL_OUTPUTS[3:6]
ALPHA, ALPHA_DOT = REAL_OUTPUTS[6:8], REAL_OUTPUTS[8:10]


class FmuSlave:
    """One instance of a Co-Simulation FMU (FMI 2.0 or 3.0) through fmpy, in Step Mode after construction
    (Event Mode with ``event_mode``).

    Args:
        path: the ``.fmu`` file (or an extracted FMU directory).
        start_values: {variable name: value} set before initialization (parameters, inputs).
        start_time: s.
        instance_name: the FMI instance name.
        event_mode: FMI 3.0 only: instantiate with eventModeUsed (a model with a bus terminal); the instance
            is then in Event Mode after construction.
    Raises:
        ValueError: an unknown variable name. fmpy.fmi1.FMICallException: an FMI call failed (message
            logged by the FMU on stdout).
    """

    def __init__(self, path: str | os.PathLike, start_values: dict | None = None, start_time: float = 0.0,
                 instance_name: str = "plant", event_mode: bool = False):
        self._tmp = None
        self.fmu = None
        try:
            self._start(Path(path), start_values, start_time, instance_name, event_mode)
        except BaseException:
            self._discard()         # an instance refused at initialisation leaves neither it nor its files
            raise

    def _discard(self) -> None:
        """Free an instance that failed to start (no terminate: it never ran) and remove its files."""
        fmu, self.fmu = self.fmu, None
        if fmu is not None:
            try:
                fmu.freeInstance()
            except Exception:  # noqa: BLE001 - the start's own error is the one to report
                pass
        if self._tmp:
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None

    def _start(self, path: Path, start_values: dict | None, start_time: float, instance_name: str,
               event_mode: bool) -> None:
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import FMU2Slave
        from fmpy.fmi3 import FMU3Slave

        if path.is_dir():
            directory = str(path)
        else:
            self._tmp = tempfile.mkdtemp(prefix="qomni_fmu_")
            directory = extract(str(path), self._tmp)
        self.model_description = md = read_model_description(directory)
        self.version = int(md.fmiVersion[0])
        self.variables = {v.name: v for v in md.modelVariables}
        cls = FMU2Slave if self.version == 2 else FMU3Slave
        fmu = cls(guid=md.guid, unzipDirectory=directory, modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName=instance_name)
        if event_mode:
            fmu.instantiate(eventModeUsed=True)
        else:
            fmu.instantiate()
        self.fmu = fmu
        if self.version == 2:
            self.fmu.setupExperiment(startTime=start_time)
            self.fmu.enterInitializationMode()
        else:
            self.fmu.enterInitializationMode(startTime=start_time)
        self.set(start_values or {})
        self.fmu.exitInitializationMode()
        self.time = float(start_time)
        self._get_real = self.fmu.getReal if self.version == 2 else self.fmu.getFloat64
        self._set_real = self.fmu.setReal if self.version == 2 else self.fmu.setFloat64
        self._get_int = self.fmu.getInteger if self.version == 2 else self.fmu.getInt32

    def refs(self, names) -> list[int]:
        """Value references of ``names``. Raises ValueError for an unknown name."""
        try:
            return [self.variables[n].valueReference for n in names]
        except KeyError as exc:
            raise ValueError(f"the FMU has no variable {exc.args[0]!r}") from None

    def set(self, values: dict) -> None:
        """Set variables by name (Float64 / Real, Int32 / Integer, Boolean)."""
        by_type: dict[str, list] = {}
        for name, value in values.items():
            by_type.setdefault(self.variables[name].type if name in self.variables else "?", []).append(
                (name, value))
        for typ, pairs in by_type.items():
            refs = self.refs([n for n, _ in pairs])
            vals = [v for _, v in pairs]
            if typ in ("Real", "Float64"):
                (self.fmu.setReal if self.version == 2 else self.fmu.setFloat64)(refs, [float(v) for v in vals])
            elif typ in ("Integer", "Int32"):
                (self.fmu.setInteger if self.version == 2 else self.fmu.setInt32)(refs, [int(v) for v in vals])
            else:
                self.fmu.setBoolean(refs, [bool(v) for v in vals])

    def get_real(self, refs: list[int]) -> np.ndarray:
        return np.array(self._get_real(refs))

    def set_real(self, refs: list[int], values) -> None:
        self._set_real(refs, [float(v) for v in values])

    def get_int(self, refs: list[int]) -> list[int]:
        return list(self._get_int(refs))

    def step(self, h: float) -> None:
        """One communication step of h > 0 s from the current time."""
        self.fmu.doStep(currentCommunicationPoint=self.time, communicationStepSize=h)
        self.time += h

    def close(self) -> None:
        """Terminate and free the instance; remove the extracted files."""
        if self.fmu is not None:
            fmu, self.fmu = self.fmu, None
            try:
                fmu.terminate()
            finally:
                fmu.freeInstance()
        if self._tmp:
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class PlantVehicle:
    """The plant FMU as a :class:`qomni.vehicle_interface.VehicleInterface`: ``exchange(u)`` returns the sample at
    the start of the cycle (motor positions and velocities, steering angles, the torque u applied from
    this instant) and advances the FMU by ``cycle_time``. Sensors are ideal (no quantization or noise).

    Args:
        path: the plant ``.fmu``; cycle_time: T_s, s; start_values: FMU start values (e.g. ``x0``,
            ``alpha_l0``, parameters).
    """

    def __init__(self, path: str | os.PathLike, cycle_time: float, start_values: dict | None = None):
        if not cycle_time > 0:
            raise ValueError(f"cycle_time must be > 0 s, got {cycle_time!r}")
        self.cycle_time = float(cycle_time)
        self.slave = FmuSlave(path, start_values)
        self._u_refs = self.slave.refs(MOTOR_TORQUE)
        self._y_refs = self.slave.refs(REAL_OUTPUTS)
        self._k_refs = self.slave.refs(("k", "k_configuration"))
        self.cycles = 0
        self.last: dict[str, np.ndarray] = {}

    def outputs(self) -> dict[str, np.ndarray]:
        """All outputs now: pose (3,), velocity (3,), alpha, alpha_dot (2,), motor_position,
        motor_velocity (4,), k and k_configuration (ints)."""
        y = self.slave.get_real(self._y_refs)
        k = self.slave.get_int(self._k_refs)
        return {"pose": y[0:3], "velocity": y[3:6], "alpha": y[6:8], "alpha_dot": y[8:10],
                "motor_position": y[10:14], "motor_velocity": y[14:18], "k": k[0], "k_configuration": k[1]}

    def exchange(self, motor_torque: np.ndarray) -> Measurement:
        u = np.asarray(motor_torque, dtype=float)
        if u.shape != (4,):
            raise ValueError(f"motor_torque must have shape (4,), got {u.shape}")
        self.last = self.outputs()
        m = Measurement(time=self.cycles * self.cycle_time, motor_position=self.last["motor_position"].copy(),
                        motor_velocity=self.last["motor_velocity"].copy(), motor_torque=u.copy(),
                        alpha=self.last["alpha"].copy())
        self.slave.set_real(self._u_refs, u)
        self.slave.step(self.cycle_time)
        self.cycles += 1
        return m

    def stop(self) -> None:
        """Zero torque (the FMU keeps running until :meth:`close`)."""
        if self.slave.fmu is not None:
            self.slave.set_real(self._u_refs, np.zeros(4))

    def close(self) -> None:
        self.slave.close()


def run_campaign_closed_loop(path: str | os.PathLike, sheet, settings=None, steps: tuple[str, ...] | None = None,
                             run_dir: str | os.PathLike | None = None,
                             start_values: dict | None = None) -> dict[str, dict[str, float]]:
    """Closed-loop co-simulation: the campaign controller (:class:`ident.controller.StepController`,
    segments of :class:`ident.campaign.Campaign`: alignments, rests, the four identification steps, the
    lane change and the arcs) drives the plant FMU through :class:`PlantVehicle`.

    Args:
        path: the plant ``.fmu``; sheet: the data sheet the controller uses (nominal parameters);
        settings: :class:`ident.campaign.CampaignSettings` (default ``quick()``);
        steps: names of the segments to run (default all); alignment and rest segments always run;
        run_dir: where :class:`ident.campaign.Campaign` may create its directory (nothing is recorded;
            default a temporary directory).
        start_values: the plant's start values (e.g. ``mode_tol``, docs/fmu.md).
    Returns:
        {segment name (``steer_left``, ..., ``arc_right``): tracking errors}: ``alpha_rms``, ``alpha_max``
        (rad, steering angles against the reference; mode 2 with alpha_v: alpha = f_ICR(alpha_v_ref)),
        and for chassis steps ``chassis_rms``, ``chassis_max`` (m or rad: x_ch for straight, lane
        change and the arcs, as the integral of the plant's x_ch_dot; gamma_ch for rotation), ``cycles`` and
        ``mode_fraction`` (share of the cycles in which the plant's engaged mode k was the step's mode).
    """
    from qomni.ident import kinematics
    from qomni.ident.campaign import Campaign, CampaignSettings

    settings = settings or CampaignSettings.quick()
    tmp = None
    if run_dir is None:
        tmp = tempfile.mkdtemp(prefix="qomni_closed_loop_")
        run_dir = tmp
    try:
        campaign = Campaign(sheet, Path(run_dir) / "campaign", settings)
        vehicle = PlantVehicle(path, sheet.drive.cycle_time, start_values)
        ts = sheet.drive.cycle_time
        results: dict[str, dict[str, float]] = {}
        measurement = vehicle.exchange(np.zeros(4))
        for seg, ctrl in zip(campaign.segments, campaign.controllers):
            if steps is not None and seg.name not in steps and seg.name not in ("align", "rest"):
                continue
            n = ctrl.cycles
            t = np.arange(n) * ts
            ref = seg.evaluate(t)
            if "alpha_v" in ref:
                alpha_ref = kinematics.f_icr(ref["alpha_v"][0], sheet.geometry)
            elif "alpha_l" in ref:
                alpha_ref = np.stack([ref["alpha_l"][0], ref["alpha_r"][0]], axis=1)
            else:
                alpha_ref = np.tile(vehicle.last["alpha"] if vehicle.last else np.zeros(2), (n, 1))
            # the chassis coordinate by the step's mode (mode 2's path, mode 4's yaw), not by its name
            chassis_name = {2: "x_ch", 4: "gamma_ch"}.get(seg.mode) if seg.name not in ("align", "rest") else None
            alpha, chassis, k = np.zeros((n, 2)), np.zeros(n), np.zeros(n, dtype=int)
            s, start_gamma = 0.0, None
            for j in range(n):
                u = ctrl.command(j * ts, measurement)
                measurement = vehicle.exchange(u)
                out = vehicle.last
                alpha[j], k[j] = out["alpha"], out["k"]
                if start_gamma is None:
                    start_gamma = out["pose"][2]
                chassis[j] = out["pose"][2] - start_gamma if chassis_name == "gamma_ch" else s
                s += out["velocity"][0] * ts
            if seg.name in ("align", "rest"):
                continue
            e_alpha = alpha - alpha_ref
            r = {"alpha_rms": float(np.sqrt(np.mean(e_alpha**2))), "alpha_max": float(np.max(np.abs(e_alpha))),
                 "cycles": n, "mode_fraction": float(np.mean(k == seg.mode))}
            if chassis_name:
                e = chassis - ref[chassis_name][0]
                r.update(chassis_rms=float(np.sqrt(np.mean(e**2))), chassis_max=float(np.max(np.abs(e))))
            results[seg.name] = r
        vehicle.stop()
        vehicle.close()
        return results
    finally:
        if tmp:
            shutil.rmtree(tmp, ignore_errors=True)


__all__ = ["MOTOR_TORQUE", "MOTOR_POSITION", "MOTOR_VELOCITY", "POSE", "VELOCITY", "ALPHA", "ALPHA_DOT",
           "REAL_OUTPUTS", "FmuSlave", "PlantVehicle", "run_campaign_closed_loop"]
