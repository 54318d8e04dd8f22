"""A set of active effects, read from an effects file (TOML): one table per effect, named as the effect,
holding its parameters. ``docs/effects.md`` lists every effect with units and realistic ranges."""
from __future__ import annotations

import importlib
import math
import pkgutil
import tomllib
from importlib import resources
from pathlib import Path
from typing import Iterator

from .base import Effect, EffectsError, Param
from .heavy_steering_units import HeavySteeringUnits


def _discover() -> dict[str, type[Effect]]:
    """Every :class:`Effect` subclass defined in a module of this package, by name, in stage order."""
    package = __name__.rpartition(".")[0]
    found: dict[str, type[Effect]] = {}
    for info in pkgutil.iter_modules([str(Path(__file__).parent)]):
        module = importlib.import_module(f"{package}.{info.name}")
        for obj in vars(module).values():
            if isinstance(obj, type) and issubclass(obj, Effect) and obj.name and obj.__module__ == module.__name__:
                if obj.name in found:
                    raise EffectsError(f"two effects are named {obj.name!r}: {found[obj.name]} and {obj}")
                found[obj.name] = obj
    return dict(sorted(found.items(), key=lambda item: (item[1].stage, item[0])))


#: Every effect, in the order the emulator applies them (``Effect.stage``; the order of a file does not
#: matter). A new effect module in this package is found here by itself.
REGISTRY: dict[str, type[Effect]] = _discover()


class EffectSet:
    """The unmodelled effects an emulator runs with, on top of the ideal vehicle.

    ``names`` lists the active effects; iterating gives them (``Effect`` instances with ``values``).
    An ``EffectSet`` is a description: each emulator builds its own run-time copies, so one set can
    serve many emulators.
    """

    def __init__(self, effects: list[Effect] | tuple[Effect, ...] = (), source: str = "(in memory)"):
        order = list(REGISTRY)
        self._effects = tuple(sorted(effects, key=lambda e: order.index(e.name)))
        self.source = source

    @classmethod
    def ideal(cls) -> "EffectSet":
        """No effect: the ideal vehicle on which the paper's assumptions hold."""
        return cls((), "ideal")

    @classmethod
    def prototype(cls, description=None) -> "EffectSet":
        """The default prototype: heavy steering units with the description's ``[body]`` masses."""
        if description is None:
            return cls.example("prototype")
        bd = description.body
        return cls([HeavySteeringUnits(steering_unit_mass=bd.steering_unit_mass,
                                       wheel_mass=bd.wheel_mass)], "prototype")

    @classmethod
    def example(cls, name: str) -> "EffectSet":
        """The shipped example file ``emulator/data/effects/<name>.toml``: one effect at a realistic high
        magnitude (``<effect name>``, or ``stribeck_wheels``/``stribeck_steering``), ``ideal`` or
        ``prototype``."""
        path = resources.files("qomni.emulator").joinpath(f"data/effects/{name}.toml")
        if not path.is_file():
            raise EffectsError(f"no shipped effects file {name}.toml")
        return cls.load(path)

    @classmethod
    def combine(cls, *sets: "EffectSet") -> "EffectSet":
        """All effects of ``sets`` together (an effect named twice: the later set's parameters)."""
        data: dict[str, dict] = {}
        for effect_set in sets:
            data.update(effect_set.to_dict())
        return cls.from_dict(data, " + ".join(s.source for s in sets))

    @classmethod
    def load(cls, path) -> "EffectSet":
        """Read an effects file.

        Raises:
            EffectsError: naming the file, table and key of an unknown effect or parameter, a missing
                parameter, a wrong type or a value outside the physically allowed range.
            FileNotFoundError: if ``path`` does not exist.
        """
        source = str(path)
        text = path.read_text() if hasattr(path, "read_text") else Path(path).read_text()
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise EffectsError(f"{source}: not valid TOML: {exc}") from exc
        return cls.from_dict(data, source)

    @classmethod
    def from_dict(cls, data: dict, source: str = "(in memory)") -> "EffectSet":
        """An effect set from ``{effect name: {parameter: value}}`` (what an effects file holds)."""
        effects = []
        for name, table in data.items():
            if name not in REGISTRY:
                raise EffectsError(f"{source}: [{name}]: unknown effect; known: {', '.join(REGISTRY)}")
            if not isinstance(table, dict):
                raise EffectsError(f"{source}: {name} must be a table [{name}] of parameters")
            kind = REGISTRY[name]
            unknown = sorted(set(table) - set(kind.params))
            if unknown:
                raise EffectsError(f"{source}: [{name}] {unknown[0]}: unknown parameter; "
                                   f"known: {', '.join(kind.params)}")
            values = {}
            for key, spec in kind.params.items():
                where = f"{source}: [{name}] {key}"
                if key not in table:
                    if spec.default is None:
                        raise EffectsError(f"{where}: missing ({spec.unit})")
                    values[key] = spec.default
                else:
                    values[key] = _value(table[key], spec, where)
            effects.append(kind(**values))
        return cls(effects, source)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(e.name for e in self._effects)

    def __iter__(self) -> Iterator[Effect]:
        return iter(self._effects)

    def __len__(self) -> int:
        return len(self._effects)

    def __contains__(self, name: str) -> bool:
        return name in self.names

    def __getitem__(self, name: str) -> Effect:
        for e in self._effects:
            if e.name == name:
                return e
        raise KeyError(name)

    def to_dict(self) -> dict[str, dict]:
        """``{effect name: {parameter: value}}``, what an effects file would hold (truth comparison)."""
        return {e.name: dict(e.values) for e in self._effects}

    def __repr__(self) -> str:
        return f"EffectSet({self.to_dict()!r}, source={self.source!r})"


def _number(value, where: str, spec: Param) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise EffectsError(f"{where}: must be a number ({spec.unit}), got {value!r}")
    if not spec.low <= value <= spec.high:
        raise EffectsError(f"{where}: {value} {spec.unit} is outside the allowed range "
                           f"[{spec.low}, {spec.high}]")
    return float(value)


def _value(value, spec: Param, where: str):
    if spec.kind == "choice":
        if value not in spec.choices:
            raise EffectsError(f"{where}: must be one of {', '.join(map(repr, spec.choices))}, "
                               f"got {value!r}")
        return value
    if spec.kind == "vector2":
        if not isinstance(value, (list, tuple)) or len(value) != 2:
            raise EffectsError(f"{where}: must be two numbers [x, y] ({spec.unit}), got {value!r}")
        return tuple(_number(v, where, spec) for v in value)
    return _number(value, where, spec)
