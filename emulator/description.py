"""Vehicle description: the TOML file the emulator is built from.

A description holds the data sheet ([geometry], [drive], [nominal]) and the emulator-only physics
([truth], [body], [noise]). See ``emulator/data/prototype.toml`` for the default vehicle and
``docs/conventions.md`` for frames and units.
"""
from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, fields
from importlib import resources
from pathlib import Path



class DescriptionError(ValueError):
    """A vehicle description file is missing a key, has a wrong type or an impossible value."""


@dataclass(frozen=True)
class Geometry:
    l: float
    b: float
    a: float
    r: float
    steering_limit: float


@dataclass(frozen=True)
class Drive:
    i_G: float
    rated_torque: float
    max_torque: float
    encoder_increments: int
    steering_sensor_bits: int
    cycle_time: float


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
    name: str
    geometry: Geometry
    drive: Drive
    truth: Truth
    body: Body
    noise: Noise
    source: str

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
        desc = cls(
            name=str(data.get("vehicle", {}).get("name", Path(source).stem)),
            geometry=_section(data, "geometry", Geometry, source),
            drive=_section(data, "drive", Drive, source),
            truth=_section(data, "truth", Truth, source),
            body=_section(data, "body", Body, source),
            noise=_section(data, "noise", Noise, source),
            source=source,
        )
        desc._check()
        return desc

    def _check(self) -> None:
        g, t, bd = self.geometry, self.truth, self.body
        positive = {
            "geometry.l": g.l, "geometry.b": g.b, "geometry.r": g.r, "drive.i_G": self.drive.i_G,
            "drive.rated_torque": self.drive.rated_torque, "drive.cycle_time": self.drive.cycle_time,
            "truth.m_ch": t.m_ch, "truth.C_ch": t.C_ch, "truth.C_l": t.C_l, "truth.C_r": t.C_r,
            "truth.B_w": t.B_w, "body.wheel_mass": bd.wheel_mass,
        }
        for key, value in positive.items():
            if not value > 0:
                raise DescriptionError(f"{self.source}: {key} must be > 0, got {value}")
        for key in ("d_vl", "d_cl", "d_vr", "d_cr", "d_vw", "d_cw"):
            if getattr(t, key) < 0:
                raise DescriptionError(f"{self.source}: truth.{key} must be >= 0")
        if not 0 <= g.a < g.b / 2:
            raise DescriptionError(f"{self.source}: geometry.a must be in [0, b/2), got {g.a}")
        if not 0 < g.steering_limit <= math.pi / 2 + 1e-9:
            raise DescriptionError(f"{self.source}: geometry.steering_limit must be in (0, π/2]")
        if self.drive.max_torque < self.drive.rated_torque:
            raise DescriptionError(f"{self.source}: drive.max_torque must be >= drive.rated_torque")
        unit_mass = 4 * (bd.steering_unit_mass + bd.wheel_mass)
        if unit_mass >= t.m_ch:
            raise DescriptionError(
                f"{self.source}: body: 4·(steering_unit_mass + wheel_mass) = {unit_mass} kg "
                f"must be below truth.m_ch = {t.m_ch} kg")
        if 2 * bd.wheel_transverse_inertia < t.B_w:
            raise DescriptionError(
                f"{self.source}: body.wheel_transverse_inertia must be >= B_w/2 (triangle inequality)")


def _section(data: dict, name: str, kind: type, source: str):
    if name not in data:
        raise DescriptionError(f"{source}: missing section [{name}]")
    table = data[name]
    values = {}
    for f in fields(kind):
        if f.name not in table:
            raise DescriptionError(f"{source}: [{name}] is missing key '{f.name}'")
        value = table[f.name]
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise DescriptionError(f"{source}: [{name}] {f.name} must be a number, got {value!r}")
        values[f.name] = int(value) if f.type in ("int", int) else float(value)
    unknown = set(table) - {f.name for f in fields(kind)}
    if unknown:
        raise DescriptionError(f"{source}: [{name}] has unknown keys {sorted(unknown)}")
    return kind(**values)
