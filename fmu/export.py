"""Export the identified model as a native C Co-Simulation FMU (FMI 2.0 or FMI 3.0) that runs without Python.

One generic path (:func:`export_fmu`) builds any model spec (:mod:`.spec`): the feed-forward law (21)
(:data:`qomni.fmu.feedforward_spec.FEEDFORWARD`) and the plant (:data:`qomni.fmu.plant_spec.PLANT`). The
variables come from the spec, the XML from :mod:`.description`, the binary and the zip from :mod:`.build`.
"""
from __future__ import annotations

import os
import re
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from .build import FmuExportError, package
from .feedforward_spec import DEFAULT_EPS, FEEDFORWARD
from .plant_can_spec import PLANT_CAN
from .plant_spec import PLANT
from .spec import ModelSpec

if TYPE_CHECKING:  # pragma: no cover
    from qomni.datasheet import DataSheet
    from qomni.ident.result import IdentificationResult

#: The exportable models by the CLI's ``--kind``.
MODELS: dict[str, ModelSpec] = {spec.kind: spec for spec in (FEEDFORWARD, PLANT, PLANT_CAN)}


def _identification_values(identification) -> tuple[dict[str, float], dict[str, float]]:
    if isinstance(identification, (str, os.PathLike)):
        from qomni.ident.rundir import load_identification
        identification = load_identification(identification)
    try:
        values = identification.as_dict()
    except AttributeError as exc:
        raise TypeError("identification must be a qomni.ident.result.IdentificationResult or the path of "
                        f"identification.json, got {type(identification).__name__}") from exc
    wrong = identification.not_physical() if hasattr(identification, "not_physical") else []
    if wrong:
        raise ValueError(f"the identified model is not physical ({', '.join(wrong)}): an FMU of it would "
                         f"simulate no vehicle; {identification.not_physical_remedy()}")
    return values, dict(getattr(identification, "std", {}) or {})


def _check_identifier(identifier: str) -> str:
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", identifier or ""):
        raise ValueError(f"model_identifier must be a C identifier, got {identifier!r}")
    return identifier


def export_fmu(spec: ModelSpec, identification: "IdentificationResult | str | os.PathLike",
               datasheet: "DataSheet", out: str | os.PathLike, fmi_version: int = 2, *,
               model_identifier: str | None = None, eps: float = DEFAULT_EPS, compiler: str | None = None,
               platforms: "tuple[str, ...] | list[str] | None" = None) -> Path:
    """Build a Co-Simulation FMU of ``spec`` with the identified parameters.

    Args:
        spec: the model (:data:`MODELS`).
        identification: :class:`qomni.ident.result.IdentificationResult`, or the path of
            ``identification.json`` (or of the run directory holding it, see
            :func:`qomni.ident.rundir.load_identification`). Its 11 parameters (B_w included) become the
            start values of the tunable parameters.
        datasheet: :class:`qomni.datasheet.DataSheet`: geometry l, b, a, r (m), gear ratio i_G and
            the cycle time T_s (DefaultExperiment stepSize).
        out: path of the ``.fmu`` file to write (parent directories are created); an existing directory
            gets ``<model_identifier>.fmu``.
        fmi_version: 2 (FMI 2.0) or 3 (FMI 3.0).
        model_identifier: C identifier of the model and binary; default the file stem of ``out`` if it
            is a C identifier, else ``spec.default_identifier``.
        eps: tanh smoothing of Coulomb friction, rad/s (start value of parameter ``eps``).
        compiler: C compiler command of the native build (default ``$CC`` or ``gcc``).
        platforms: None for the native linux x86-64 binary; else FMI 3 platform tuples of
            :data:`qomni.fmu.platforms.PLATFORMS` (``x86_64-linux`` against glibc 2.17, ``aarch64-linux``,
            ``x86_64-windows``), each cross-compiled from the same sources with ``zig cc`` (package
            ``ziglang``) into its FMI 2 / FMI 3 binaries directory.
    Returns:
        Path of the written FMU. Its content: ``modelDescription.xml``, ``binaries/linux64/<id>.so``
        (FMI 2) or ``binaries/x86_64-linux/<id>.so`` (FMI 3) (with ``platforms``: one binary per platform,
        ``<id>.so`` / ``<id>.dll`` in :meth:`Platform.directory`), ``sources/`` (all C sources; FMI 3 also
        ``sources/buildDescription.xml``). The GUID / instantiationToken is a UUID derived from the
        content (same inputs, same token), checked by fmi2Instantiate / fmi3InstantiateCoSimulation.
    Raises:
        ValueError: fmi_version not 2 or 3 (or not one of ``spec.fmi_versions``: the plant-can model is
            FMI 3.0 only), ``out`` without the ``.fmu`` suffix, bad identifier,
            non-finite parameters, a model that is not physical
            (:meth:`~qomni.ident.result.IdentificationResult.not_physical`), i_G or eps <= 0.
        TypeError: ``identification`` of a wrong type.
        qomni.ident.rundir.RunDirectoryError: no identification.json at the given path.
        FmuExportError: compilation failed, an unknown platform, or ziglang missing for ``platforms``.
    """
    out, identifier = _resolve_out(out, fmi_version, model_identifier, spec.default_identifier)
    if fmi_version not in spec.fmi_versions:
        raise ValueError(f"the {spec.kind} model is exported as FMI {' or '.join(map(str, spec.fmi_versions))}.0 "
                         f"only, not FMI {fmi_version}.0")
    values, std = _identification_values(identification)
    variables = spec.with_datasheet(spec.variables(values, datasheet.geometry, datasheet.drive.i_G, eps, std),
                                    datasheet)
    variables = _with_limits(variables, spec.input_limits(datasheet))
    return package(spec, out, identifier, fmi_version, variables, spec.description.format(name=datasheet.name),
                   datasheet.drive.cycle_time, compiler,
                   None if platforms is None else tuple(platforms))


def export_feedforward_fmu(identification, datasheet, out, fmi_version: int = 2, **kwargs) -> Path:
    """:func:`export_fmu` of the feed-forward law (21) (default identifier ``qomni_feedforward``)."""
    return export_fmu(FEEDFORWARD, identification, datasheet, out, fmi_version, **kwargs)


def export_plant_fmu(identification, datasheet, out, fmi_version: int = 2, **kwargs) -> Path:
    """:func:`export_fmu` of the plant (default identifier ``qomni_plant``). The FMU has an internal state
    (FMU state get/set/serialize includes it), outputs do not depend directly on the inputs
    (ModelStructure: ``dependencies=""``), any communication step size > 0 is accepted (internal sub-steps,
    see parameter ``max_step``)."""
    return export_fmu(PLANT, identification, datasheet, out, fmi_version, **kwargs)


def export_plant_can_fmu(identification, datasheet, out, **kwargs) -> Path:
    """:func:`export_fmu` of the plant behind its CAN bus (FMI 3.0, default identifier ``qomni_plant_can``,
    :mod:`qomni.fmu.plant_can_spec`): CAN frames in and out through the FMI-LS-BUS terminal ``CAN``, the
    drives' and encoders' data from the data sheet."""
    return export_fmu(PLANT_CAN, identification, datasheet, out, 3, **kwargs)


def _with_limits(variables: list, limits: dict[str, tuple[float, float]]) -> list:
    """The variables with the declared min/max of the bounded inputs; ValueError for an unknown name or an
    empty range."""
    inputs = {v.name for v in variables if v.causality == "input"}
    for name, (low, high) in limits.items():
        if name not in inputs or not low < high:
            raise ValueError(f"input limit {name}: ({low}, {high}) names no input or is empty")
    return [replace(v, min=limits[v.name][0], max=limits[v.name][1]) if v.name in limits else v
            for v in variables]


def _resolve_out(out, fmi_version: int, model_identifier: str | None, default: str) -> tuple[Path, str]:
    """The .fmu path and the model identifier (see the ``out``/``model_identifier`` arguments)."""
    if fmi_version not in (2, 3):
        raise ValueError(f"fmi_version must be 2 or 3, got {fmi_version!r}")
    out = Path(out)
    if out.is_dir():
        identifier = _check_identifier(model_identifier or default)
        return out / f"{identifier}.fmu", identifier
    if out.suffix != ".fmu":
        raise ValueError(f"out must end with .fmu, got {str(out)!r}")
    stem_ok = re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", out.stem) is not None
    return out, _check_identifier(model_identifier or (out.stem if stem_ok else default))


__all__ = ["MODELS", "FmuExportError", "export_fmu", "export_feedforward_fmu", "export_plant_fmu",
           "export_plant_can_fmu"]
