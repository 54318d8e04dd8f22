"""Vehicle description: the TOML file the emulator is built from.

A description embeds the data sheet ([vehicle], [geometry], [drive], [nominal]; read by
:class:`qomni.datasheet.DataSheet`, the one definition of those sections) and adds the emulator-only
physics ([truth], [body], [noise]). See ``emulator/data/prototype.toml`` for the default vehicle and
``docs/conventions.md`` for frames and units.
"""
from __future__ import annotations

import tomllib
from dataclasses import dataclass
from importlib import resources
from pathlib import Path


from qomni.datasheet import DataSheet, DataSheetError, Drive, Geometry, read_table


class DescriptionError(ValueError):
    """A vehicle description file is missing a key, has a wrong type or an impossible value."""


@dataclass(frozen=True)
class Truth:
    """True dynamic parameters p (18) plus B_w; per-side steering, per-wheel wheel parameters."""

    C_l: float
    d_vl: float
    d_cl: float
    C_r: float
    d_vr: float
    d_cr: float
    m_ch: float
    C_ch: float
    d_vw: float
    d_cw: float
    B_w: float


@dataclass(frozen=True)
class Body:
    steering_unit_mass: float
    wheel_mass: float
    wheel_transverse_inertia: float
    chassis_height: float
    tire_friction: float
    contact_stiffness: float
    contact_damping: float


@dataclass(frozen=True)
class Noise:
    motor_torque_ripple: float
    torque_measurement: float
    steering_sensor_lsb: float


@dataclass(frozen=True)
class VehicleDescription:
    """An emulated vehicle: its data sheet (what an engineer knows) and its truth, body and noise (what
    only the emulator knows)."""

    datasheet: DataSheet
    truth: Truth
    body: Body
    noise: Noise
    source: str

    @property
    def name(self) -> str:
        return self.datasheet.name

    @property
    def geometry(self) -> Geometry:
        return self.datasheet.geometry

    @property
    def drive(self) -> Drive:
        return self.datasheet.drive

    @classmethod
    def load(cls, path: str | Path | None = None) -> "VehicleDescription":
        """Read a description TOML file; ``None`` gives the default prototype.

        Raises:
            DescriptionError: naming the file, section and key that is missing or invalid.
            FileNotFoundError: if ``path`` does not exist.
        """
        if path is None:
            text = resources.files("qomni.emulator").joinpath("data/prototype.toml").read_text()
            source = "prototype (built in)"
        else:
            text = Path(path).read_text()
            source = str(path)
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise DescriptionError(f"{source}: not valid TOML: {exc}") from exc
        try:
            datasheet = DataSheet.loads(text, source=source)
        except DataSheetError as exc:
            raise DescriptionError(str(exc)) from exc
        desc = cls(
            datasheet=datasheet,
            truth=read_table(data, "truth", Truth, source, DescriptionError),
            body=read_table(data, "body", Body, source, DescriptionError),
            noise=read_table(data, "noise", Noise, source, DescriptionError),
            source=source,
        )
        desc._check()
        return desc

    def _check(self) -> None:
        t, bd = self.truth, self.body
        positive = {
            "truth.m_ch": t.m_ch, "truth.C_ch": t.C_ch, "truth.C_l": t.C_l, "truth.C_r": t.C_r,
            "truth.B_w": t.B_w, "body.wheel_mass": bd.wheel_mass,
        }
        for key, value in positive.items():
            if not value > 0:
                raise DescriptionError(f"{self.source}: {key} must be > 0, got {value}")
        for key in ("d_vl", "d_cl", "d_vr", "d_cr", "d_vw", "d_cw"):
            if getattr(t, key) < 0:
                raise DescriptionError(f"{self.source}: truth.{key} must be >= 0")
        # The body and the contact: masses are not negative, the solver needs a stiff, damped, frictional
        # contact, and noise is a standard deviation (>= 0).
        for key in ("steering_unit_mass", "wheel_transverse_inertia"):
            if getattr(bd, key) < 0:
                raise DescriptionError(f"{self.source}: body.{key} must be >= 0, got {getattr(bd, key)}")
        for key in ("chassis_height", "tire_friction", "contact_stiffness", "contact_damping"):
            if not getattr(bd, key) > 0:
                raise DescriptionError(f"{self.source}: body.{key} must be > 0, got {getattr(bd, key)}")
        for key in ("motor_torque_ripple", "torque_measurement", "steering_sensor_lsb"):
            if getattr(self.noise, key) < 0:
                raise DescriptionError(f"{self.source}: noise.{key} must be >= 0 (a standard deviation), "
                                       f"got {getattr(self.noise, key)}")
        unit_mass = 4 * (bd.steering_unit_mass + bd.wheel_mass)
        if unit_mass >= t.m_ch:
            raise DescriptionError(
                f"{self.source}: body: 4·(steering_unit_mass + wheel_mass) = {unit_mass} kg "
                f"must be below truth.m_ch = {t.m_ch} kg")
        if not 2 * bd.wheel_transverse_inertia > t.B_w:      # at B_w/2 (a disc of no width) PyBullet
            raise DescriptionError(                           # takes the tensor for bad and zeroes it
                f"{self.source}: body.wheel_transverse_inertia must be > B_w/2 (triangle inequality; a wheel "
                f"of no width is refused by the physics engine), got {bd.wheel_transverse_inertia} with "
                f"B_w = {t.B_w}")
        from .urdf import body_inertias     # the bodies [body] describes hold the truth: no negative inertia

        body_inertias(self)
