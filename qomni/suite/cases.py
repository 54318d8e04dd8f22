"""The blind suite's cases, drawn at random per run from one recorded master seed.

A case is a campaign on a vehicle with known effects. From the master seed (numpy ``default_rng``) the
suite draws, in this order:

* single effects: ``singles`` tables per suite entry, each drawn over the entry's whole realistic range
  and in any direction or instance (``Effect.draw``: log-uniform magnitudes, payload quadrant, faulty
  drive, torque constant above or below 1, smaller or larger wheel, incline heading, Stribeck joints);
* ``pairs`` two-effect and ``triples`` three-effect combinations of distinct effects, each effect drawn
  the same way;
* on every other vehicle (``VEHICLES``), a clean case and ``other_vehicle_singles`` single effects;
* ``clean`` clean cases of the ideal vehicle and of the prototype (whose heavy steering units are its
  own real effect: naming them is right, naming nothing is too).

Every case gets its own emulator seed from the same stream, so one master seed fixes the whole suite and
no table of fixed cases exists to be tuned to. Composition root: it knows the truth to score against.
"""
from __future__ import annotations

import itertools
import json
from dataclasses import dataclass, field
from importlib import resources

import numpy as np

from qomni.emulator.effects.effect_set import REGISTRY

#: Suite entry → (weak, strong) ends of its realistic range, as each effect declares them (``Effect.suite``).
MAGNITUDES: dict[str, tuple[dict, dict]] = {entry: tables for cls in REGISTRY.values()
                                            for entry, tables in cls.suite.items()}
#: Effect (effects-file table) name of each suite entry (the Stribeck variants share one effect).
TABLE = {entry: cls.name for cls in REGISTRY.values() for entry in cls.suite}
#: The vehicles besides the built-in prototype: name → description file (emulator/data).
VEHICLES = {"heavy_platform": str(resources.files("qomni.emulator").joinpath("data/heavy_platform.toml"))}
#: Effects the prototype has of its own: naming them on a prototype case is no false positive.
PROTOTYPE_OWN = ("heavy_steering_units",)


def effect_name(entry: str) -> str:
    """The effect name the diagnosis should report for a suite entry."""
    return TABLE.get(entry, entry)


def variant(entry: str, table: dict) -> str | None:
    """The hypothesis variant the diagnosis should name for an entry's table (None: any)."""
    if effect_name(entry) == "stribeck":
        return f"joints={table['joints']}"
    if entry == "torque_constant_error":
        return f"drive {table['drive']}"
    return None


def range_position(entry: str, table: dict) -> float | None:
    """Where an entry's effects-file table lies in its realistic range: 0 at the weak end, 1 at the strong
    end (``Effect.range_position``)."""
    return REGISTRY[effect_name(entry)].range_position(entry, table)


def effects_toml(tables: dict[str, dict]) -> str:
    """An effects file (TOML) holding ``tables`` (effect name → parameters)."""
    lines = []
    for name, table in tables.items():
        lines.append(f"[{name}]")
        lines += [f"{k} = {json.dumps(v)}" for k, v in table.items()]
        lines.append("")
    return "\n".join(lines)


def draw(entry: str, rng: np.random.Generator) -> dict:
    """An effects-file table for ``entry`` drawn over its realistic range (``Effect.draw``)."""
    return REGISTRY[effect_name(entry)].draw(entry, rng)


@dataclass
class Case:
    """One campaign of the suite and the truth it is scored against.

    Attributes:
        name: unique in the suite; effects: effects-file tables (empty: the clean vehicle);
        truth: effect names the diagnosis should report; seed: the emulator's (and excitation's) seed;
        magnitude: how the tables were chosen; entry: the suite entry of a one-effect case;
        variants: effect name → the instance to name; vehicle: "" for the built-in vehicle, else a
        ``VEHICLES`` key; prototype: the vehicle as built (its own steering units), not the ideal one;
        tolerated: effects that may be named without being a false positive (the prototype's own).
    """

    name: str
    effects: dict[str, dict]
    truth: list[str]
    seed: int
    magnitude: str = ""
    entry: str = ""
    variants: dict[str, str] = field(default_factory=dict)
    vehicle: str = ""
    prototype: bool = False
    tolerated: list[str] = field(default_factory=list)


def _case(name: str, entries: dict[str, dict], seed: int, **kw) -> Case:
    variants = {effect_name(e): v for e, t in entries.items() if (v := variant(e, t)) is not None}
    return Case(name, {effect_name(e): t for e, t in entries.items()}, [effect_name(e) for e in entries], seed,
                variants=variants, **kw)


def draw_cases(master_seed: int, *, singles: int = 5, pairs: int = 10, triples: int = 3, clean: int = 2,
               other_vehicle_singles: int = 3, entries=None) -> list[Case]:
    """The suite drawn from ``master_seed`` (module docstring); ``entries`` restricts the single-effect
    cases (and the combinations) to those suite entries."""
    rng = np.random.default_rng(master_seed)
    names = list(entries or MAGNITUDES)

    def seed() -> int:
        return int(rng.integers(1, 2**31 - 1))

    out = []
    for entry in names:
        for i in range(singles):
            s = seed()
            out.append(_case(f"{entry}_{i}_s{s}", {entry: draw(entry, rng)}, s, magnitude="drawn", entry=entry))
    combos = {n: [c for c in itertools.combinations(names, n)
                  if len({effect_name(e) for e in c}) == n] for n in (2, 3)}
    for n, count in ((2, pairs), (3, triples)):
        pool = combos[n]
        for k in rng.choice(len(pool), size=min(count, len(pool)), replace=False) if pool else []:
            combo = pool[int(k)]
            s = seed()
            out.append(_case("+".join(combo) + f"_s{s}", {e: draw(e, rng) for e in combo}, s, magnitude="drawn"))
    for vehicle in VEHICLES:
        s = seed()
        out.append(Case(f"{vehicle}_clean_s{s}", {}, [], s, "clean", vehicle=vehicle))
        for entry in rng.choice(names, size=min(other_vehicle_singles, len(names)), replace=False):
            s = seed()
            out.append(_case(f"{vehicle}_{entry}_s{s}", {str(entry): draw(str(entry), rng)}, s, magnitude="drawn",
                             entry=str(entry), vehicle=vehicle))
    for i in range(clean):
        s = seed()
        out.append(Case(f"ideal_s{s}", {}, [], s, "clean"))
        s = seed()
        out.append(Case(f"prototype_s{s}", {}, [], s, "clean", prototype=True, tolerated=list(PROTOTYPE_OWN)))
    return out
