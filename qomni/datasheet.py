"""The vehicle data sheet: what an engineer knows about the real vehicle before identification.

A leaf module (numpy only), the one place the data sheet is defined: the identification, the CANopen client
(drive data), the FMU export and the emulator's vehicle description (which embeds it) all read it.

A data-sheet TOML file has the sections ``[vehicle]`` (optional ``name``), ``[geometry]``,
``[drive]`` and ``[nominal]``; see ``qomni/data/prototype_datasheet.toml`` (the default prototype).
Any other section (an emulator description's ``[truth]``, ``[body]``, ``[noise]``) is ignored and never
read, so the emulator's vehicle description files can be loaded as data sheets too.

Units are SI (m, rad, s, N m, kg, kg m²); torques in ``[drive]`` are motor side, friction and inertia
parameters in ``[nominal]`` follow ``docs/conventions.md`` (steering per side, wheel per wheel on the
wheel side of the gear).
"""
from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import astuple, dataclass, fields
from importlib import resources
from pathlib import Path

import numpy as np

DEFAULT_DATASHEET = "data/prototype_datasheet.toml"
"""Resource path (inside the ``qomni`` package) of the default prototype data sheet."""


#: s, the SYNC periods a data sheet may give. Below 0.2 ms a CAN bus at 1 Mbit/s cannot carry the SYNC
#: and one 8-byte PDO (≈ 0.05 + 0.13 ms with stuffing); above 50 ms the identification's zero-phase
#: filter at ω_g = 40 rad/s is no longer well sampled (Nyquist π/T_s ≥ 63 rad/s).
CYCLE_TIME_RANGE = (2e-4, 5e-2)


class DataSheetError(ValueError):
    """A data-sheet file is missing a section or key, has a wrong type or an impossible value.
    The message names the file, the section and the key."""


@dataclass(frozen=True)
class Geometry:
    """Kinematic geometry (docs/conventions.md).

    Attributes:
        l: longitudinal distance between the steering axes, m.
        b: lateral distance between the steering axes, m.
        a: lateral offset of the wheel centre from its steering axis (outward along the axle), m.
        r: wheel radius, m.
        steering_limit: mechanical stop |alpha| <= steering_limit, rad (default pi/2).
    """

    l: float
    b: float
    a: float
    r: float
    steering_limit: float = math.pi / 2


@dataclass(frozen=True)
class Drive:
    """Drive data: gear ratio ``i_G`` (wheel torque = i_G · motor torque), motor-side ``rated_torque``
    and ``max_torque`` (N m), motor ``encoder_increments`` per motor revolution,
    ``steering_sensor_bits`` of the absolute single-turn steering sensors, ``cycle_time`` T_s (s)."""

    i_G: float
    rated_torque: float
    max_torque: float
    encoder_increments: int
    steering_sensor_bits: int
    cycle_time: float

    @property
    def steering_lsb(self) -> float:
        """One step of the steering sensor, rad: 2π / 2^steering_sensor_bits."""
        return 2 * math.pi / 2**self.steering_sensor_bits


@dataclass(frozen=True)
class Nominal:
    """Prior (design) values of the dynamic parameters p (18), in the order of p; B_w is the
    data-sheet drive inertia used as the known p_2 of (24)."""

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

    @property
    def p(self) -> np.ndarray:
        """The parameter vector p (18), shape (11,), float."""
        return np.array(astuple(self), dtype=float)


@dataclass(frozen=True)
class DataSheet:
    """A vehicle data sheet: ``name``, ``geometry``, ``drive``, ``nominal`` and the ``source`` it was
    read from."""

    name: str
    geometry: Geometry
    drive: Drive
    nominal: Nominal
    source: str

    @classmethod
    def load(cls, path: str | Path | None = None) -> "DataSheet":
        """Read a data-sheet TOML file; ``None`` reads the packaged default prototype
        (``qomni/data/prototype_datasheet.toml``). Only [vehicle], [geometry], [drive] and [nominal]
        are read; other sections are ignored.

        Raises:
            FileNotFoundError: ``path`` does not exist.
            DataSheetError: invalid TOML, a missing section or key, an unknown key in a read section,
                a non-numeric value or an impossible value; the message names file, section and key.
        """
        if path is None:
            text = resources.files("qomni").joinpath(DEFAULT_DATASHEET).read_text(encoding="utf-8")
            source = "qomni/" + DEFAULT_DATASHEET
        else:
            text = Path(path).read_text(encoding="utf-8")
            source = str(path)
        return cls.loads(text, source=source)

    @classmethod
    def loads(cls, text: str, source: str = "<string>") -> "DataSheet":
        """Parse data-sheet TOML ``text``; ``source`` names it in error messages. See :meth:`load`."""
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise DataSheetError(f"{source}: not valid TOML: {exc}") from exc
        vehicle = data.get("vehicle", {})
        if not isinstance(vehicle, dict):
            raise DataSheetError(f"{source}: [vehicle] must be a table")
        name = vehicle.get("name", Path(source).stem)
        if not isinstance(name, str):
            raise DataSheetError(f"{source}: [vehicle] key 'name' must be a string, got {name!r}")
        return cls.from_tables(data, name, source)

    @classmethod
    def from_tables(cls, data: Mapping, name: str, source: str) -> "DataSheet":
        """The data sheet of the tables ``geometry``, ``drive`` and ``nominal`` of ``data`` (a parsed TOML
        file, or the ``datasheet`` entry a run's metadata.json stores). Raises DataSheetError as
        :meth:`load`."""
        sheet = cls(
            name=name,
            geometry=read_table(data, "geometry", Geometry, source),
            drive=read_table(data, "drive", Drive, source),
            nominal=read_table(data, "nominal", Nominal, source),
            source=source,
        )
        sheet._check()
        return sheet

    def _check(self) -> None:
        g, d, n = self.geometry, self.drive, self.nominal

        def fail(section: str, key: str, message: str, value) -> None:
            raise DataSheetError(f"{self.source}: [{section}] key '{key}' {message}, got {value!r}")

        for key in ("l", "b", "r"):
            if not getattr(g, key) > 0:
                fail("geometry", key, "must be > 0", getattr(g, key))
        if not 0 < g.a < g.b / 2:      # the wheels' forces steer the passive units through a
            fail("geometry", "a", "must be in (0, b/2): the wheels steer their passive units through the "
                 "offset a, with no lever at a = 0", g.a)
        if not 0 < g.steering_limit <= math.pi / 2 + 1e-9:
            fail("geometry", "steering_limit", "must be in (0, pi/2]", g.steering_limit)
        for key in ("i_G", "rated_torque", "cycle_time"):
            if not getattr(d, key) > 0:
                fail("drive", key, "must be > 0", getattr(d, key))
        if not CYCLE_TIME_RANGE[0] <= d.cycle_time <= CYCLE_TIME_RANGE[1]:
            fail("drive", "cycle_time", f"must be within {CYCLE_TIME_RANGE[0]:g}–{CYCLE_TIME_RANGE[1]:g} s "
                 "(a CAN cycle holds at least the SYNC and one PDO; the 40 rad/s filter needs the sampling "
                 "well above its band)", d.cycle_time)
        if d.max_torque < d.rated_torque:
            fail("drive", "max_torque", "must be >= rated_torque", d.max_torque)
        if d.encoder_increments < 1:
            fail("drive", "encoder_increments", "must be >= 1", d.encoder_increments)
        if not 1 <= d.steering_sensor_bits <= 32:
            fail("drive", "steering_sensor_bits", "must be in 1..32", d.steering_sensor_bits)
        for key in ("C_l", "C_r", "m_ch", "C_ch", "B_w"):
            if not getattr(n, key) > 0:
                fail("nominal", key, "must be > 0", getattr(n, key))
        for key in ("d_vl", "d_cl", "d_vr", "d_cr", "d_vw", "d_cw"):
            if not getattr(n, key) >= 0:
                fail("nominal", key, "must be >= 0", getattr(n, key))


def vehicle_differences(a: DataSheet, b: DataSheet) -> list[str]:
    """The ``geometry.key`` and ``drive.key`` entries in which two data sheets differ: what makes them two
    vehicles (their nominal parameters are a starting point, not the vehicle). Empty for the same vehicle."""
    return [f"{part}.{f.name}" for part in ("geometry", "drive") for f in fields(getattr(a, part))
            if getattr(getattr(a, part), f.name) != getattr(getattr(b, part), f.name)]


def read_table(data: Mapping, name: str, kind: type, source: str, error: type[Exception] | None = None):
    """The table ``[name]`` of a parsed TOML document as the dataclass ``kind``, whose fields are numbers:
    every field present, each a number (not a boolean or a string), finite, an integer where the field is
    one, and no other key.

    Raises:
        ``error`` (default :class:`DataSheetError`) naming ``source``, the table and the key."""
    error = DataSheetError if error is None else error
    if name not in data:
        raise error(f"{source}: missing section [{name}]")
    table = data[name]
    if not isinstance(table, dict):
        raise error(f"{source}: [{name}] must be a table")
    values = {}
    for f in fields(kind):
        if f.name not in table:
            raise error(f"{source}: [{name}] is missing key '{f.name}'")
        value = table[f.name]
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise error(f"{source}: [{name}] key '{f.name}' must be a number, got {value!r}")
        if f.type in ("int", int):
            if isinstance(value, float) and not value.is_integer():
                raise error(f"{source}: [{name}] key '{f.name}' must be an integer, got {value!r}")
            values[f.name] = int(value)
        else:
            if not math.isfinite(value):
                raise error(f"{source}: [{name}] key '{f.name}' must be finite, got {value!r}")
            values[f.name] = float(value)
    unknown = set(table) - {f.name for f in fields(kind)}
    if unknown:
        raise error(f"{source}: [{name}] has unknown keys {sorted(unknown)}")
    return kind(**values)


__all__ = ["DataSheet", "DataSheetError", "Drive", "Geometry", "Nominal", "DEFAULT_DATASHEET", "read_table",
           "vehicle_differences"]
