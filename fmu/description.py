"""The FMU's XML: ``modelDescription.xml`` for FMI 2.0 (§2.2) and FMI 3.0 (§2.4), the FMI 3
``buildDescription.xml`` (§2.5.1.2), from a model's variable list."""
from __future__ import annotations

from xml.etree import ElementTree as ET

from .variables import UNITS, Variable

_FMI2_TYPE = {"Float64": "Real", "Int32": "Integer", "Boolean": "Boolean"}


def _xml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    return repr(float(value))


def _dependencies(variables: list[Variable], names: tuple[str, ...]) -> list[Variable]:
    return [v for v in variables if v.name in set(names)]


def _unit_definitions(parent: ET.Element, variables: list[Variable]) -> None:
    used = sorted({v.unit for v in variables if v.unit})
    units = ET.SubElement(parent, "UnitDefinitions")
    for name in used:
        unit = ET.SubElement(units, "Unit", name=name)
        ET.SubElement(unit, "BaseUnit", {k: str(e) for k, e in UNITS[name].items()})


def _log_categories(parent: ET.Element) -> None:
    cats = ET.SubElement(parent, "LogCategories")
    for name, text in (("logStatusError", "errors (always logged)"),
                       ("logStatusWarning", "warnings (always logged)"),
                       ("logCalls", "FMI function calls (debug logging)")):
        ET.SubElement(cats, "Category", name=name, description=text)


def model_description_fmi2(variables, identifier, token, description, tool, step_size, source_files,
                           dependencies: tuple[str, ...]) -> ET.Element:
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": "2.0", "modelName": identifier, "guid": token, "description": description,
        "generationTool": tool, "variableNamingConvention": "structured", "numberOfEventIndicators": "0"})
    cs = ET.SubElement(root, "CoSimulation", {
        "modelIdentifier": identifier, "canHandleVariableCommunicationStepSize": "true",
        "canInterpolateInputs": "false", "maxOutputDerivativeOrder": "0", "canRunAsynchronuously": "false",
        "canBeInstantiatedOnlyOncePerProcess": "false", "canNotUseMemoryManagementFunctions": "false",
        "canGetAndSetFMUstate": "true", "canSerializeFMUstate": "true",
        "providesDirectionalDerivative": "true"})
    files = ET.SubElement(cs, "SourceFiles")
    for name in source_files:
        ET.SubElement(files, "File", name=name)
    _unit_definitions(root, variables)
    _log_categories(root)
    ET.SubElement(root, "DefaultExperiment", startTime="0.0", stopTime="1.0", stepSize=repr(float(step_size)))
    mv = ET.SubElement(root, "ModelVariables")
    for v in variables:  # FMI 2: value attributes on the type child element (FMI 2.0 §2.2.7)
        sv = ET.SubElement(mv, "ScalarVariable", _variable_attrs(v))
        ET.SubElement(sv, _FMI2_TYPE[v.type], _value_attrs(v))
    ms = ET.SubElement(root, "ModelStructure")
    outputs = ET.SubElement(ms, "Outputs")
    deps = " ".join(str(v.vr + 1) for v in _dependencies(variables, dependencies))
    for v in variables:
        if v.causality == "output":
            ET.SubElement(outputs, "Unknown", index=str(v.vr + 1), dependencies=deps)
    initial = ET.SubElement(ms, "InitialUnknowns")
    for v in variables:
        if v.causality == "output":
            ET.SubElement(initial, "Unknown", index=str(v.vr + 1))
    return root


def model_description_fmi3(variables, identifier, token, description, tool, step_size,
                           dependencies: tuple[str, ...], event_mode: bool = False) -> ET.Element:
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": "3.0", "modelName": identifier, "instantiationToken": token,
        "description": description, "generationTool": tool, "variableNamingConvention": "structured"})
    ET.SubElement(root, "CoSimulation", {
        "modelIdentifier": identifier, "canHandleVariableCommunicationStepSize": "true",
        "canGetAndSetFMUState": "true", "canSerializeFMUState": "true",
        "providesDirectionalDerivatives": "true", "providesAdjointDerivatives": "true",
        "hasEventMode": "true" if event_mode else "false", "providesIntermediateUpdate": "false",
        "canReturnEarlyAfterIntermediateUpdate": "false", "maxOutputDerivativeOrder": "0"})
    _unit_definitions(root, variables)
    _log_categories(root)
    ET.SubElement(root, "DefaultExperiment", startTime="0.0", stopTime="1.0", stepSize=repr(float(step_size)))
    mv = ET.SubElement(root, "ModelVariables")
    for v in variables:  # FMI 3: all attributes on the typed variable element (FMI 3.0 §2.4.7)
        if v.type == "Binary":  # start values of Binary are child elements (FMI 3.0 §2.4.7.6)
            element = ET.SubElement(mv, v.type, {**_variable_attrs(v), **dict(v.attributes)})
            if v.start is not None:
                ET.SubElement(element, "Start", value=str(v.start))
            continue
        ET.SubElement(mv, v.type, {**_variable_attrs(v), **_value_attrs(v), **dict(v.attributes)})
    ms = ET.SubElement(root, "ModelStructure")
    deps = " ".join(str(v.vr) for v in _dependencies(variables, dependencies))
    for v in variables:
        if v.causality == "output":
            ET.SubElement(ms, "Output", valueReference=str(v.vr), dependencies=deps)
    for v in variables:
        if v.causality == "output" and "clocks" not in dict(v.attributes):  # clocked: known at ticks only
            ET.SubElement(ms, "InitialUnknown", valueReference=str(v.vr))
    return root


def _variable_attrs(v) -> dict[str, str]:
    """Attributes every FMI version puts on the variable element itself."""
    attrs = {"name": v.name, "valueReference": str(v.vr), "description": v.description,
             "causality": v.causality, "variability": v.variability}
    if v.causality == "output" and v.type != "Clock":
        attrs["initial"] = "calculated"
    return attrs


def _value_attrs(v) -> dict[str, str]:
    """Unit, bounds and start value (FMI 2: on the type element; FMI 3: on the variable)."""
    attrs = {}
    if v.unit:
        attrs["unit"] = v.unit
    if v.min is not None:
        attrs["min"] = str(v.min)
    if v.max is not None:
        attrs["max"] = str(v.max)
    if v.start is not None:
        attrs["start"] = _xml_value(v.start)
    return attrs


def build_description_fmi3(identifier: str, source_files: list[str]) -> ET.Element:
    root = ET.Element("fmiBuildDescription", fmiVersion="3.0")
    bc = ET.SubElement(root, "BuildConfiguration", modelIdentifier=identifier,
                       description="gcc -std=c99 -shared -fPIC -O2 -fvisibility=hidden *.c -lm")
    sfs = ET.SubElement(bc, "SourceFileSet", language="C99")
    for name in source_files:
        ET.SubElement(sfs, "SourceFile", name=name)
    return root


def xml_bytes(root: ET.Element) -> bytes:
    ET.indent(root, space="  ")
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True) + b"\n"
