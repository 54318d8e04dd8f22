"""``qomni export-fmu``: the identified model as a native C Co-Simulation FMU."""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from .app import app
from .console import console, fail, guarded
from .loaders import load_datasheet


@app.command("export-fmu")
def export_fmu(
    source: Path = typer.Argument(..., help="Run directory or identification.json."),
    out: Path = typer.Option(..., "--out", help="FMU file to write (NAME.fmu)."),
    fmi: int = typer.Option(2, "--fmi", help="FMI version: 2 or 3."),
    kind: str = typer.Option("feedforward", help="Model: 'feedforward' (law (21): motor torques from the "
                                                 "desired motion), 'plant' (the vehicle: motor torques in, "
                                                 "pose, steering, encoders and mode k out) or 'plant-can' (the "
                                                 "plant behind its CAN bus: CAN frames in and out through an "
                                                 "FMI-LS-BUS CAN terminal; FMI 3 only)."),
    vehicle: Optional[Path] = typer.Option(None, help="Data sheet (geometry, i_G); default: the run's."),
    platform: Optional[list[str]] = typer.Option(
        None, "--platform", help="Cross-compile for this FMI 3 platform tuple with zig cc (repeatable): "
                                 "x86_64-linux (glibc 2.17), aarch64-linux, x86_64-windows. Default: the "
                                 "native linux x86-64 binary (gcc)."),
    parameter_sets: int = typer.Option(0, "--parameter-sets", min=0,
                                       help="Also write OUT.ssp: the FMU with this many parameter sets (SSV) "
                                            "sampled from the identified covariance (0: none)."),
    seed: int = typer.Option(0, "--seed", min=0, help="Seed of the parameter-set sampling."),
):
    """Export the identified model as a native C Co-Simulation FMU (no Python needed to import it)."""
    from qomni.fmu.export import MODELS, FmuExportError, export_fmu
    from qomni.ident.rundir import (METADATA, check_identification_vehicle, datasheet_from_metadata,
                                    load_identification, read_json)

    if kind not in MODELS:
        fail(f"--kind must be one of {', '.join(sorted(MODELS))}, got {kind!r}")
    if fmi not in (2, 3):
        fail(f"--fmi must be 2 or 3, got {fmi}")
    run_dir = source if source.is_dir() else source.parent
    name = None
    if vehicle is not None:
        sheet = load_datasheet(vehicle, None)
        other = f"--vehicle {vehicle}"
    else:
        meta = run_dir / METADATA
        if not meta.exists():
            fail(f"{meta} not found: pass --vehicle with the data sheet")
        recorded = guarded(lambda: read_json(meta))
        sheet, name = guarded(lambda: datasheet_from_metadata(recorded, str(meta))), recorded.get("vehicle")
        other = f"the run {run_dir}"
    result = guarded(lambda: load_identification(source))
    guarded(lambda: check_identification_vehicle(source, sheet, name, other, "export a model with the data sheet "
                                                 "of the vehicle it was identified on"))
    try:
        path = export_fmu(MODELS[kind], result, sheet, out, fmi_version=fmi, platforms=platform or None)
    except (FmuExportError, ValueError) as exc:
        fail(str(exc))
    where = ", ".join(platform) if platform else "x86_64-linux"
    console.print(f"written {path} (FMI {fmi}.0 Co-Simulation, {MODELS[kind].summary}; binaries: {where})")
    if parameter_sets:
        from qomni.fmu.parameter_sets import ParameterSetError, write_parameter_sets

        try:
            ssp = write_parameter_sets(result, path, path.with_suffix(".ssp"), parameter_sets, seed)
        except ParameterSetError as exc:
            fail(str(exc))
        console.print(f"written {ssp} (SSP: the FMU, the nominal set and {parameter_sets} sampled parameter sets)")

