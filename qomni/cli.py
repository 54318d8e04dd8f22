"""``qomni``: run the identification campaign against the embedded emulator or a real vehicle, identify,
validate and compare with the emulator's truth."""
from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Table

app = typer.Typer(add_completion=False, no_args_is_help=True,
                  help="Identification of the quasi-omnidirectional mobile platform (emulator, CANopen, "
                       "campaign, estimation).")
console = Console()

BUS_LOG = "bus.blf"


def _progress() -> Progress:
    return Progress(TextColumn("{task.description:<14}"), BarColumn(), TextColumn("{task.percentage:>5.1f} %"),
                    TimeElapsedColumn(), TimeRemainingColumn(), console=console, transient=False)


def _fail(message: str) -> None:
    console.print(f"[bold red]error:[/] {message}")
    raise typer.Exit(2)


def _datasheet(vehicle: Optional[Path], datasheet: Optional[Path]):
    from qomni.ident.datasheet import DataSheet, DataSheetError

    try:
        return DataSheet.load(datasheet or vehicle)
    except (DataSheetError, FileNotFoundError) as exc:
        _fail(str(exc))


def _description(vehicle: Optional[Path]):
    from qomni.emulator.description import DescriptionError, VehicleDescription

    try:
        return VehicleDescription.load(vehicle)
    except (DescriptionError, FileNotFoundError) as exc:
        _fail(str(exc))


def _effects(path: Optional[Path]):
    """The effects file's EffectSet, or None (the prototype as described)."""
    if path is None:
        return None
    from qomni.emulator.effects import EffectSet, EffectsError

    try:
        return EffectSet.load(path)
    except (EffectsError, FileNotFoundError) as exc:
        _fail(str(exc))


def _vehicle_link(bus: Optional[str], vehicle: Optional[Path], sheet, seed: int, lifted: bool,
                  gui: bool, record: Path, effects=None, faults=None):
    """Context manager yielding a connected client: embedded emulator or the vehicle on ``bus``."""
    record = [record, record.with_suffix(".log")]         # BLF and candump -L
    if bus is None:
        from qomni.embedded import embedded_vehicle

        return embedded_vehicle(_description(vehicle), seed=seed, lifted=lifted, gui=gui, record=record,
                                effects=effects,
                                faults=faults)
    from qomni.hil.client import VehicleClient

    return VehicleClient.from_drive(sheet.drive, bus, record=record)


def _run_with_progress(label: str, make_runner):
    with _progress() as progress:
        task = progress.add_task(label, total=None)

        def on_progress(done: int, total: int, name: str) -> None:
            if done % 25 == 0 or done == total:
                progress.update(task, completed=done, total=total, description=name)

        return make_runner(on_progress)


@app.command()
def campaign(
    out: Path = typer.Option(..., "--out", help="Run directory to create."),
    bus: Optional[str] = typer.Option(None, help="Bus of a real or external vehicle, e.g. "
                                      "'socketcan:can0'. Default: the embedded emulator."),
    vehicle: Optional[Path] = typer.Option(None, help="Vehicle description TOML (emulator) / data sheet."),
    datasheet: Optional[Path] = typer.Option(None, help="Data-sheet TOML if different from --vehicle."),
    seed: int = typer.Option(0, help="Seed of the embedded emulator's noise."),
    quick: bool = typer.Option(False, help="Short campaign (≈ 35 s emulated) for smoke tests."),
    single_axis: Optional[bool] = typer.Option(
        None, "--single-axis/--no-single-axis",
        help="Run the lifted single-axis identification of B_w first (default: yes with the embedded "
             "emulator; with --bus the vehicle must be lifted, so run 'qomni single-axis' instead)."),
    gui: bool = typer.Option(False, help="Show the PyBullet GUI (needs a display)."),
    faults: Optional[Path] = typer.Option(
        None, help="Fault plan (TOML, hil/faults.py) injected into the embedded emulator during the "
                   "campaign (not the single-axis run); for an external emulator use 'qomni emulate "
                   "--faults'."),
    effects: Optional[Path] = typer.Option(
        None, help="Effects file (TOML, docs/effects.md) for the embedded emulator: the ideal vehicle "
                   "plus the effects it lists. Default: the prototype as described."),
):
    """Run the four-step campaign and the lane change, then identify and validate."""
    from qomni.ident.campaign import Campaign, CampaignAborted, CampaignSettings

    sheet = _datasheet(vehicle, datasheet)
    if faults is not None and bus is not None:
        _fail("--faults applies to the embedded emulator; give the plan to 'qomni emulate --faults' "
              "serving the vehicle on --bus")
    from qomni.hil_commands import _load_or_fail

    fault_plan = _load_or_fail(faults, "faults")
    if (out / "signals.csv").exists():
        _fail(f"{out} already holds a campaign; choose a new --out")
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    if single_axis is None:
        single_axis = bus is None
    if effects is not None and bus is not None:
        _fail("--effects applies to the embedded emulator only (the vehicle on --bus has its own)")
    effect_set = _effects(effects)
    if single_axis:
        _single_axis(out, bus, vehicle, sheet, seed, gui, effect_set)
    settings = CampaignSettings.quick() if quick else CampaignSettings()
    source = bus or "embedded emulator (virtual CAN bus)"
    try:
        run = Campaign(sheet, out, settings, source=source)
    except ValueError as exc:
        _fail(f"cannot plan the campaign within the vehicle's limits: {exc}")
    try:
        with _vehicle_link(bus, vehicle, sheet, seed, False, gui, out / BUS_LOG, effect_set,
                           faults=fault_plan) as link:
            _run_with_progress("campaign", lambda cb: (setattr(run, "on_progress", cb), run.run(link)))
    except CampaignAborted as exc:
        _fail(f"campaign aborted, the wheels were stopped; recorded data kept in {out}: {exc}")
    from qomni.hil.dbc import write_dbc

    write_dbc(out / "bus.dbc")  # decodes bus.blf in CANoe, cantools, candump-based tools
    rect = json.loads((out / "metadata.json").read_text())["occupied_rectangle"]
    console.print(f"campaign recorded in {out} ({time.perf_counter() - started:.1f} s wall); occupied "
                  f"rectangle {rect['length']:.2f} m × {rect['width']:.2f} m")
    _identify_and_report(out)
    console.print(f"total wall time {time.perf_counter() - started:.1f} s")


def _single_axis(out: Path, bus, vehicle, sheet, seed: int, gui: bool, effects=None) -> None:
    from qomni.ident.campaign import CampaignAborted
    from qomni.ident.single_axis import (SINGLE_AXIS_DIR, identify_single_axis, plan_single_axis,
                                   run_single_axis)

    (out / SINGLE_AXIS_DIR).mkdir(parents=True, exist_ok=True)
    trajectories = plan_single_axis()
    try:
        with _vehicle_link(bus, vehicle, sheet, seed, True, gui,
                           out / SINGLE_AXIS_DIR / BUS_LOG, effects) as link:
            _run_with_progress("single axis",
                               lambda cb: run_single_axis(link, sheet, out, trajectories, on_progress=cb))
    except CampaignAborted as exc:
        _fail(f"single-axis run aborted; recorded data kept in {out / SINGLE_AXIS_DIR}: {exc}")
    result = identify_single_axis(out, sheet)
    pooled, std = result.pooled, result.pooled_std
    console.print("single-axis (lifted): " + ", ".join(
        f"{n} = {pooled[n]:.4g} ± {std[n]:.2g}" for n in ("B_w", "d_vw", "d_cw")))


@app.command("single-axis")
def single_axis_command(
    out: Path = typer.Option(..., "--out", help="Run directory (created or reused before 'campaign')."),
    bus: Optional[str] = typer.Option(None, help="Bus of the lifted vehicle; default: embedded emulator."),
    vehicle: Optional[Path] = typer.Option(None, help="Vehicle description / data sheet TOML."),
    datasheet: Optional[Path] = typer.Option(None, help="Data-sheet TOML if different from --vehicle."),
    seed: int = typer.Option(0, help="Seed of the embedded emulator's noise."),
    gui: bool = typer.Option(False, help="Show the PyBullet GUI."),
):
    """Identify B_w, d_vw, d_cw per wheel on the lifted vehicle (wheels free)."""
    sheet = _datasheet(vehicle, datasheet)
    out.mkdir(parents=True, exist_ok=True)
    _single_axis(out, bus, vehicle, sheet, seed, gui)


def _identify_and_report(run_dir: Path) -> None:
    from qomni.ident.identify import identify_run, validate_run

    result = _guarded(lambda: identify_run(run_dir))
    _print_parameters(result)
    validation = _guarded(lambda: validate_run(run_dir))
    _print_validation(validation)
    _plots(run_dir, result, validation)


def _guarded(fn):
    from qomni.ident.estimation import IdentifiabilityError
    from qomni.ident.identify import RunDirectoryError
    from qomni.ident.recording import RecordingError

    try:
        return fn()
    except (RunDirectoryError, RecordingError, IdentifiabilityError, FileNotFoundError) as exc:
        _fail(str(exc))


def _print_parameters(result) -> None:
    from qomni.ident.estimation import PARAMETER_UNITS

    table = Table(title="Identified parameters (paper Table 2)")
    for col in ("Name", "Value", "Std. deviation", "Unit"):
        table.add_column(col, justify="right" if col in ("Value", "Std. deviation") else "left")
    for name, value in result.values.items():
        table.add_row(name, f"{value:.4f}", f"{result.std[name]:.4f}", PARAMETER_UNITS[name])
    table.add_row("B_w", f"{result.B_w:.4f}", "fixed", PARAMETER_UNITS["B_w"])
    console.print(table)
    console.print(f"cond(Θ̂₁ᵀΘ̂₁) = {result.condition_number:.2f}  (paper: 11.56)")


def _print_validation(validation) -> None:
    table = Table(title="Validation on the lane change (mode 2, not used for fitting)")
    table.add_column("Channel")
    table.add_column("NRMSE", justify="right")
    table.add_column("RMS error", justify="right")
    table.add_column("NRMSE, moving rows", justify="right")
    moving = validation.moving
    for channel, value in validation.nrmse.items():
        m = moving.get(channel, {})
        cell = (f"{100 * m['nrmse']:.1f} % ({m['n_rows']} rows)" if m.get("nrmse") is not None
                else "no moving rows")
        table.add_row(channel, f"{100 * value:.1f} %", f"{validation.rms_error[channel]:.3g}", cell)
    console.print(table)


def _plots(run_dir: Path, result, validation) -> None:
    from qomni.ident.identify import identification_blocks, load_run, validation_blocks
    from qomni.ident.plots import torque_comparison

    signals, sheet, _ = load_run(run_dir)
    times = {name: signals.of_step(name).time for name in signals.steps()}
    torque_comparison(identification_blocks(signals, sheet), times, result,
                      run_dir / "fig5_identification.png",
                      "Identification experiment: generalized torques (cf. paper Fig. 5)")
    torque_comparison(validation_blocks(signals, sheet), times, result,
                      run_dir / "fig6_validation.png",
                      "Validation experiment (lane change): generalized torques (cf. paper Fig. 6)",
                      nrmse=validation.nrmse)


@app.command()
def identify(run_dir: Path = typer.Argument(..., help="Run directory of a campaign.")):
    """Identify the parameters from a recorded campaign (writes identification.json)."""
    from qomni.ident.identify import identify_run

    _print_parameters(_guarded(lambda: identify_run(run_dir)))
    console.print(f"written {run_dir / 'identification.json'}")


@app.command()
def validate(run_dir: Path = typer.Argument(..., help="Run directory with identification.json.")):
    """Validate identification.json on the recorded lane change (writes validation.json, plots)."""
    from qomni.ident.identify import load_identification, validate_run

    validation = _guarded(lambda: validate_run(run_dir))
    _print_validation(validation)
    _plots(run_dir, _guarded(lambda: load_identification(run_dir)), validation)
    console.print(f"written {run_dir / 'validation.json'}")


@app.command()
def compare(
    run_dir: Path = typer.Argument(..., help="Run directory with identification.json."),
    vehicle: Optional[Path] = typer.Option(None, help="The emulated vehicle's description (truth); "
                                           "default: the prototype."),
):
    """Compare identified parameters with the emulator's truth (a separate step, never an input)."""
    from qomni.compare import compare_with_truth

    report = _guarded(lambda: compare_with_truth(run_dir, _description(vehicle)))
    table = Table(title=f"Identified vs. true ({report['vehicle']})")
    for col in ("Name", "Identified", "Std", "True", "Rel. error", "Error / σ"):
        table.add_column(col, justify="left" if col == "Name" else "right")
    for name, row in report["parameters"].items():
        table.add_row(name, f"{row['identified']:.4f}", f"{row['std']:.4f}", f"{row['true']:.4f}",
                      f"{100 * row['relative_error']:+.2f} %", f"{row['error_in_std']:+.2f}")
    console.print(table)
    console.print(f"written {run_dir / 'comparison.json'}")


@app.command("export-fmu")
def export_fmu(
    source: Path = typer.Argument(..., help="Run directory or identification.json."),
    out: Path = typer.Option(..., "--out", help="FMU file to write (NAME.fmu)."),
    fmi: int = typer.Option(2, "--fmi", help="FMI version: 2 or 3."),
    kind: str = typer.Option("feedforward", help="Model: 'feedforward' (law (21): motor torques from the "
                                                 "desired motion) or 'plant' (the vehicle: motor torques in, "
                                                 "pose, steering, encoders and mode k out)."),
    vehicle: Optional[Path] = typer.Option(None, help="Data sheet (geometry, i_G); default: the run's."),
):
    """Export the identified model as a native C Co-Simulation FMU (no Python needed to import it)."""
    from qomni.fmu.export import FmuExportError, export_feedforward_fmu, export_plant_fmu
    from qomni.ident.identify import datasheet_from_metadata, load_identification

    exporters = {"feedforward": (export_feedforward_fmu, "feed-forward law (21)"),
                 "plant": (export_plant_fmu, "plant, reduced dynamics (19)/(20) per motion mode")}
    if kind not in exporters:
        _fail(f"--kind must be 'plant' or 'feedforward', got {kind!r}")
    if fmi not in (2, 3):
        _fail(f"--fmi must be 2 or 3, got {fmi}")
    run_dir = source if source.is_dir() else source.parent
    if vehicle is not None:
        sheet = _datasheet(vehicle, None)
    else:
        meta = run_dir / "metadata.json"
        if not meta.exists():
            _fail(f"{meta} not found: pass --vehicle with the data sheet")
        sheet = _guarded(lambda: datasheet_from_metadata(json.loads(meta.read_text()), str(meta)))
    result = _guarded(lambda: load_identification(source))
    try:
        path = exporters[kind][0](result, sheet, out, fmi_version=fmi)
    except (FmuExportError, ValueError) as exc:
        _fail(str(exc))
    console.print(f"written {path} (FMI {fmi}.0 Co-Simulation, {exporters[kind][1]})")


@app.command()
def diagnose(
    model: Path = typer.Option(..., "--model", help="identification.json (or its run directory)."),
    data: Path = typer.Option(..., "--data", help="Run directory whose data are diagnosed."),
    holdout: Optional[Path] = typer.Option(None, "--holdout", help="Second run used only as held-out "
                                           "data (default: alternate 1 s windows of --data)."),
    out: Path = typer.Option(..., "--out", help="Directory for gap.json and report.html."),
    simulate: bool = typer.Option(True, help="Also compare 1 s forward simulations."),
):
    """Diagnose the sim-to-real gap: where model and data differ, which unmodelled effect explains it,
    how far the held-out residual shrinks once it is added (gap.json, report.html)."""
    from qomni.diagnosis.diagnose import diagnose_paths
    from qomni.diagnosis.report import write_report

    d = _guarded(lambda: diagnose_paths(model, data, holdout, simulate=simulate))
    table = Table(title="Unmodelled-effect hypotheses (ranked by held-out residual removed)")
    for col in ("#", "Effect", "Magnitude", "95 % CI", "p", "Held-out shrink", "beyond base fit", "Channel",
                "Significant"):
        table.add_column(col, justify="left" if col in ("Effect", "Channel") else "right")
    for i, c in enumerate(d.candidates[:8]):
        m = c.magnitude
        table.add_row(str(i + 1), c.hypothesis.label, f"{m.value:.4g} {m.unit}",
                      f"[{m.ci[0]:.3g}, {m.ci[1]:.3g}]", f"{c.p_value:.1e}",
                      f"{100 * c.from_model.shrink_affected:.1f} %", f"{100 * c.shrink.shrink_affected:.1f} %",
                      c.shrink.affected,
                      "yes" if c.significant else "no")
    console.print(table)
    console.print(f"[bold]verdict:[/] {d.verdict}")
    json_path, html_path = write_report(d, out)
    console.print(f"written {json_path} and {html_path}")


@app.command()
def hub(port: int = typer.Option(29536, help="TCP port on 127.0.0.1 (0 picks a free one)."),
        max_clients: int = typer.Option(16, help="Most clients connected at once.")):
    """Share one CAN bus between processes where vcan does not exist: a socketcand hub on 127.0.0.1.

    Connect with --bus socketcand:127.0.0.1:PORT/can0 (python-can's socketcand interface).
    """
    from qomni.hil.hub import Hub, hub_bus_spec

    with Hub(port=port, max_clients=max_clients) as running:
        console.print(f"hub listening on 127.0.0.1:{running.port}; bus spec "
                      f"[bold]{hub_bus_spec(running.port)}[/]; Ctrl-C stops it")
        try:
            while True:
                time.sleep(1.0)
        except KeyboardInterrupt:
            console.print(f"hub stopped after {running.frames} frames ({running.dropped} dropped)")


from qomni import hil_commands as _hil_commands  # noqa: E402,F401 - registers emulate, decode, replay


def main() -> None:  # pragma: no cover
    app()


if __name__ == "__main__":  # pragma: no cover
    main()
