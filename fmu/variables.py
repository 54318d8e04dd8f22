"""FMU variables: one scalar variable of a model (:class:`Variable`), the SI units the descriptions may name,
and the numbering of a variable list into value references and storage indices (FMI 2.0 §2.2.7, FMI 3.0
§2.4.7)."""
from __future__ import annotations

from dataclasses import dataclass, replace

# unit name -> SI base-unit exponents (FMI 2.0 section 2.2.2, FMI 3.0 section 2.4.3)
UNITS = {
    "s": {"s": 1}, "m": {"m": 1}, "rad": {"rad": 1}, "kg": {"kg": 1}, "kg.m2": {"kg": 1, "m": 2},
    "N.m": {"kg": 1, "m": 2, "s": -2}, "N.m.s/rad": {"kg": 1, "m": 2, "s": -1, "rad": -1},
    "rad/s": {"rad": 1, "s": -1}, "m/s": {"m": 1, "s": -1},
}

@dataclass(frozen=True)
class Variable:
    """One scalar FMU variable.

    ``type`` is the FMI 3 type name (``Float64``, ``Int32``, ``Boolean``; FMI 2: Real, Integer,
    Boolean; FMI 3 only: ``Binary``, ``Clock``, whose storage index is their value reference). ``group``: name of the ``FF_<GROUP>`` (plant: ``PL_<GROUP>``) macro in ``config.h`` that holds the storage index
    of the group's first variable (groups are contiguous). ``vr`` is the value reference, ``index`` the
    position in the value array of its type (both assigned by :func:`number_variables`). ``min``/``max``: the
    declared range (FMI 2.0 §2.2.7, FMI 3.0 §2.4.7.4); the FMU refuses a Float64 input set outside it.
    ``attributes``: further XML attributes of the FMI 3 variable element as (name, value) pairs (a Binary's
    ``mimeType``, ``maxSize``, ``clocks``; a Clock's ``intervalVariability``).
    """

    name: str
    type: str
    causality: str
    variability: str
    description: str
    start: float | int | bool | None = None
    unit: str | None = None
    group: str | None = None
    min: float | int | None = None
    max: float | int | None = None
    vr: int = -1
    index: int = -1
    attributes: tuple[tuple[str, str], ...] = ()


def number_variables(variables: list[Variable]) -> list[Variable]:
    """Assign value references (list order) and storage indices (per type; Binary and Clock: the value
    reference); check finite start values."""
    counters = {"Float64": 0, "Int32": 0, "Boolean": 0}
    numbered = []
    for vr, v in enumerate(variables):
        if v.start is not None and v.type == "Float64" and not (abs(v.start) < float("inf")):
            raise ValueError(f"{v.name} must be finite, got {v.start!r}")
        if v.causality == "independent":
            numbered.append(replace(v, vr=vr, index=0))
            continue
        if v.type in ("Binary", "Clock"):          # handled by the model, addressed by value reference
            numbered.append(replace(v, vr=vr, index=vr))
            continue
        numbered.append(replace(v, vr=vr, index=counters[v.type]))
        counters[v.type] += 1
    return numbered
