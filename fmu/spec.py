"""The FMU model spec: everything the generic build needs to know of one model (its variables, its C
sources and generated code, its direct dependencies, its internal state size), so that a model is one spec
module (:mod:`.feedforward_spec`, :mod:`.plant_spec`) plus its C code under ``fmu/c/<model_dir>``."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

from .codegen import GeneratedCode
from .variables import Variable


@dataclass(frozen=True)
class ModelSpec:
    """One FMU model.

    Attributes:
        kind: ``"feedforward"`` or ``"plant"`` (the CLI's ``--kind``).
        default_identifier: model identifier (C identifier of the model and binary) when none is given.
        model_dir: folder of the model's C sources under ``fmu/c``.
        model_sources: the model's C files in that folder.
        generate: ``() -> GeneratedCode``, the sympy-generated C of the model's equations.
        variables: ``(p {name: value}, geometry, i_G, eps [rad/s], std {name: σ}) -> [Variable]`` in value
            reference order (:func:`qomni.fmu.variables.number_variables` applied).
        dependencies: names of the inputs every output depends on directly (ModelStructure).
        config_prefix: prefix of the group macros in ``config.h`` (``<prefix>_<GROUP>``).
        n_states: doubles of internal state the FMU state (get/set/serialize) carries.
        description: modelDescription's description, ``{name}`` = the vehicle's name.
        summary: one line for the CLI.
        input_limits: ``(datasheet) -> {input name: (min, max)}``, the inputs the vehicle's physics bounds
            (declared min/max of the variable; the FMU refuses a value set outside it). Default none.
        shared_sources: C files of other models the model also compiles (paths under ``fmu/c``, packaged
            under their file names).
        bus: the model has an FMI-LS-BUS bus terminal (``FMU_BUS`` in ``config.h``: Event Mode, Clocks and
            Binary variables through its ``fmu_bus_*`` functions; FMI 3.0 only).
        fmi_versions: the FMI versions the model can be exported as.
        with_datasheet: ``(variables, datasheet) -> variables``, start values taken from the data sheet.
        extra_files: ``(variables) -> {path in the FMU: bytes}``, files beyond the model description,
            binaries and sources (FMI 3.0: ``terminalsAndIcons/``, ``extra/``).
    """

    kind: str
    default_identifier: str
    model_dir: str
    model_sources: tuple[str, ...]
    generate: Callable[[], GeneratedCode]
    variables: Callable[..., list[Variable]]
    dependencies: tuple[str, ...]
    config_prefix: str
    n_states: int
    description: str
    summary: str
    input_limits: Callable[[Any], dict[str, tuple[float, float]]] = field(default=lambda datasheet: {})
    shared_sources: tuple[str, ...] = ()
    bus: bool = False
    fmi_versions: tuple[int, ...] = (2, 3)
    with_datasheet: Callable[[list[Variable], Any], list[Variable]] = field(
        default=lambda variables, datasheet: variables)
    extra_files: Callable[[list[Variable]], dict[str, bytes]] = field(default=lambda variables: {})
