"""``qomni campaign``, ``single-axis``, ``identify``, ``validate`` and ``compare``."""
from __future__ import annotations

import math
import time
from dataclasses import replace
from pathlib import Path
from typing import Optional

import typer
from rich.table import Table

from .app import app
from .console import console, fail, guarded, run_with_progress
from qomni.ident.rundir import (BUS_BLF, BUS_DBC, CAMPAIGN_FILES, FIG_IDENTIFICATION, FIG_VALIDATION,
                                IDENTIFICATION_JSON, METADATA, SINGLE_AXIS_DIR, SINGLE_AXIS_FILES, SINGLE_AXIS_JSON,
                                VALIDATION_JSON, check_lifted_vehicle, read_json, read_lifted)

from .loaders import (check_bus_spec, check_effects, load_datasheet, load_description, load_effects, load_faults,
                      prepare_out, PLANT_PROCESS_HELP, vehicle_link)

ESTIMATOR_HELP = ("wls: channel-weighted least squares; irls: robust (Huber then Tukey bisquare) against "
                  "outlier rows; iv: instrumental variables from a model-simulated trajectory; consistent: all inertias, "
                  "masses and friction coefficients >= 0 (equals wls when wls is admissible).")
SPIKES_HELP = ("Repair isolated glitches (a sample far from both neighbours: a corrupted frame, a zeroed row) "
               "in the drives' signals before filtering; --keep-spikes fits the samples as recorded. Either way "
               "identification.json reports what was found.")
TORQUE_LAG_HELP = ("Lag of the reported torque actual (0x6077) behind the applied torque that the fit corrects "
                   "for: 'auto' the campaign's own estimate, a number a known lag in seconds; 0 (default): "
                   "0x6077 as docs/conventions.md defines it. The estimate is reported in every case.")


@app.command()
def campaign(
    out: Path = typer.Option(..., "--out", help="Run directory to create."),
    bus: Optional[str] = typer.Option(None, help="Bus of a real or external vehicle, e.g. "
                                      "'socketcan:can0'. Default: the embedded emulator."),
    vehicle: Optional[Path] = typer.Option(None, help="Vehicle description TOML (emulator) / data sheet."),
    datasheet: Optional[Path] = typer.Option(None, help="Data-sheet TOML if different from --vehicle."),
    seed: int = typer.Option(0, min=0, help="Seed of the embedded emulator's noise."),
    quick: bool = typer.Option(False, help="Short campaign (≈ 46 s emulated) for smoke tests."),
    excitation: Optional[str] = typer.Option(
        None, help="Design criterion of the identification steps: 'richness' (the default) or 'min_cond' "
                   "(the viscous/Coulomb pairs' condition number: cond about 4.5 on a full campaign and "
                   "better steering parameters, but less chassis acceleration for the gap diagnosis); "
                   "docs/identification.md, Optimised excitation."),
    single_axis: Optional[bool] = typer.Option(
        None, "--single-axis/--no-single-axis",
        help="Run the lifted single-axis identification of B_w first (default: yes with the embedded "
             "emulator; with --bus the vehicle must be lifted, so run 'qomni single-axis' instead)."),
    gui: bool = typer.Option(False, help="Show the PyBullet GUI (needs a display)."),
    plant_process: bool = typer.Option(False, help=PLANT_PROCESS_HELP),
    faults: Optional[Path] = typer.Option(
        None, help="Fault plan (TOML, hil/device/faults.py) injected into the embedded emulator during the "
                   "campaign (not the single-axis run); for an external emulator use 'qomni emulate "
                   "--faults'."),
    effects: Optional[Path] = typer.Option(
        None, help="Effects file (TOML, docs/effects.md) for the embedded emulator: the ideal vehicle "
                   "plus the effects it lists. Default: the prototype as described."),
    force: bool = typer.Option(False, help="Replace the campaign (and single-axis run) already in --out."),
    estimator: str = typer.Option("wls", help=ESTIMATOR_HELP),
    torque_lag: str = typer.Option("0", "--torque-lag", help=TORQUE_LAG_HELP),
    dead_time_probe: bool = typer.Option(
        False, "--dead-time-probe/--no-dead-time-probe",
        help="First measure the actuator dead time with a short steering pulse at rest and lower the "
             "steering bandwidth to keep a 30° phase margin with it (needed above about 6 ms of delay)."),
    limit_cycle_probe: bool = typer.Option(
        True, "--limit-cycle-probe/--no-limit-cycle-probe",
        help="Where the steering falls into a limit cycle at the torque limit before the first "
             "identification step has ended, stop, probe the dead time and start the campaign again at the "
             "bandwidth it gives (a vehicle that never reaches the limit records the same either way)."),
):
    """Run the four-step campaign, the lane change and the two arcs, then identify and validate."""
    from qomni.hil.master.client import CommunicationError
    from qomni.ident.campaign import Campaign, CampaignAborted, CampaignSettings
    from qomni.ident.controller import ControllerSettings

    sheet = load_datasheet(vehicle, datasheet)
    lag = _identify_options(estimator, torque_lag)
    if faults is not None and bus is not None:
        fail("--faults applies to the embedded emulator; give the plan to 'qomni emulate --faults' "
              "serving the vehicle on --bus")
    fault_plan = load_faults(faults)
    check_bus_spec(bus)
    if single_axis is None:
        single_axis = bus is None
    if plant_process and bus is not None:
        fail("--plant-process applies to the embedded emulator; a vehicle on --bus runs its own physics")
    if effects is not None and bus is not None:
        fail("--effects applies to the embedded emulator only (the vehicle on --bus has its own)")
    effect_set = load_effects(effects)
    if bus is None:                        # the embedded emulator's vehicle, checked before --force removes a run
        check_effects(load_description(vehicle), effect_set)
    settings = CampaignSettings.quick() if quick else CampaignSettings()
    if excitation is not None:
        try:
            settings = replace(settings, excitation=excitation)
        except ValueError as exc:
            fail(str(exc))
    kept = out / SINGLE_AXIS_JSON
    if not single_axis and kept.is_file():     # kept beside the new campaign: it must be this vehicle's wheels
        guarded(lambda: check_lifted_vehicle(kept, read_json(kept), sheet))
    prepare_out(out, CAMPAIGN_FILES + (SINGLE_AXIS_FILES if single_axis else ()), force)
    started = time.perf_counter()
    if single_axis:
        _single_axis(out, bus, vehicle, sheet, seed, gui, effect_set)
    source = bus or "embedded emulator (virtual CAN bus)"
    try:
        controller = ControllerSettings(probe=dead_time_probe, probe_on_limit_cycle=limit_cycle_probe)
        run = Campaign(sheet, out, settings, controller, source=source)
    except ValueError as exc:
        fail(f"cannot plan the campaign within the vehicle's limits: {exc}")
    console.print(f"planned cond(Θ̂₁ᵀΘ̂₁) = {run.planned_condition:.2f} ({settings.excitation} design)",
                  markup=False)
    try:
        with vehicle_link(bus, vehicle, sheet, seed, False, gui, out / BUS_BLF, effect_set,
                           faults=fault_plan, plant_process=plant_process) as link:
            run_with_progress("campaign", lambda cb: (setattr(run, "on_progress", cb), run.run(link)))
    except CampaignAborted as exc:
        fail(f"campaign aborted, the wheels were stopped; recorded data kept in {out}: {exc}")
    except CommunicationError as exc:                  # while connecting, before the campaign began
        fail(f"cannot bring the vehicle up: {exc}")
    from qomni.hil.tools.dbc import write_dbc

    write_dbc(out / BUS_DBC)  # decodes bus.blf in CANoe, cantools, candump-based tools
    meta = read_json(out / METADATA)
    rect = meta["occupied_rectangle"]
    if meta.get("missed_samples"):
        console.print("TPDOs missed and held from the cycle before: " + ", ".join(
            f"{cob} {n}×" for cob, n in meta["missed_samples"].items()))
    console.print(f"campaign recorded in {out} ({time.perf_counter() - started:.1f} s wall); occupied "
                  f"rectangle {rect['length']:.2f} m × {rect['width']:.2f} m")
    _identify_and_report(out, estimator, lag)
    console.print(f"total wall time {time.perf_counter() - started:.1f} s")


def _single_axis(out: Path, bus, vehicle, sheet, seed: int, gui: bool, effects=None) -> None:
    from qomni.hil.master.client import CommunicationError
    from qomni.ident.campaign import CampaignAborted
    from qomni.ident.single_axis import identify_single_axis, plan_single_axis, run_single_axis

    (out / SINGLE_AXIS_DIR).mkdir(parents=True, exist_ok=True)
    trajectories = plan_single_axis()
    try:
        with vehicle_link(bus, vehicle, sheet, seed, True, gui,
                           out / SINGLE_AXIS_DIR / BUS_BLF, effects) as link:
            run_with_progress("single axis",
                               lambda cb: run_single_axis(link, sheet, out, trajectories, on_progress=cb))
    except CampaignAborted as exc:
        fail(f"single-axis run aborted; recorded data kept in {out / SINGLE_AXIS_DIR}: {exc}")
    except CommunicationError as exc:
        fail(f"cannot bring the vehicle up: {exc}")
    result = identify_single_axis(out, sheet)
    pooled, std = result.pooled, result.pooled_std
    console.print("single-axis (lifted): " + ", ".join(
        f"{n} = {pooled[n]:.4g} ± {std[n]:.2g}" for n in ("B_w", "d_vw", "d_cw")))
    breakaway = read_lifted(out).breakaway
    if breakaway is not None:
        console.print(f"breakaway (lifted): {1 + breakaway[0]:.3f} ± {breakaway[1]:.2g} × d_cw")


@app.command("single-axis")
def single_axis_command(
    out: Path = typer.Option(..., "--out", help="Run directory (created or reused before 'campaign')."),
    bus: Optional[str] = typer.Option(None, help="Bus of the lifted vehicle; default: embedded emulator."),
    vehicle: Optional[Path] = typer.Option(None, help="Vehicle description / data sheet TOML."),
    datasheet: Optional[Path] = typer.Option(None, help="Data-sheet TOML if different from --vehicle."),
    seed: int = typer.Option(0, min=0, help="Seed of the embedded emulator's noise."),
    gui: bool = typer.Option(False, help="Show the PyBullet GUI."),
    force: bool = typer.Option(False, help="Replace the single-axis run already in --out."),
):
    """Identify B_w, d_vw, d_cw per wheel on the lifted vehicle (wheels free)."""
    sheet = load_datasheet(vehicle, datasheet)
    check_bus_spec(bus)
    prepare_out(out, SINGLE_AXIS_FILES, force)
    _single_axis(out, bus, vehicle, sheet, seed, gui)


def _identify_and_report(run_dir: Path, estimator: str, torque_lag) -> None:
    from qomni.ident.identify import identify_run, validate_run

    result = guarded(lambda: _identification_errors(lambda: identify_run(run_dir, torque_lag=torque_lag, estimator=estimator)))
    _print_parameters(result)
    if result.not_physical():
        # the recording and identification.json stand; a forward simulation of this model would not
        from qomni.ident.result import BOUND_REMEDY

        remedy = result.not_physical_remedy()
        if remedy == BOUND_REMEDY:
            remedy = f"run 'qomni identify {run_dir} --estimator consistent', then 'qomni validate {run_dir}'"
        console.print(f"validation skipped: the model is not physical ({', '.join(result.not_physical())}); "
                      + remedy)
        _plots(run_dir, result, None)
        return
    validation = guarded(lambda: _identification_errors(lambda: validate_run(run_dir)))
    _print_validation(validation)
    _plots(run_dir, result, validation)


def _print_parameters(result) -> None:
    from qomni.conventions import PARAMETER_UNITS

    table = Table(title=f"Identified parameters (paper Table 2), estimator {result.estimator}")
    for col in ("Name", "Value", "Std. deviation", "Unit", "Rel. std", "Std (bootstrap)", "Determined by",
                "Strongest correlation"):
        table.add_column(col, justify="right" if col in ("Value", "Std. deviation", "Rel. std",
                                                         "Std (bootstrap)") else "left")
    for name, value in result.values.items():
        table.add_row(name, f"{value:.4f}", f"{result.std[name]:.4f}", PARAMETER_UNITS[name],
                      *result.report_row(name))
    table.add_row("B_w", f"{result.B_w:.4f}", "fixed", PARAMETER_UNITS["B_w"], "", "", "", "")
    console.print(table)
    console.print(f"cond(Θ̂₁ᵀΘ̂₁) = {result.condition_number:.2f}  (paper: 11.56)")
    if result.estimator_info.get("converged") is False:
        console.print(f"warning: the {result.estimator} iterations did not converge "
                      f"({result.estimator_info.get('iterations')} iterations); the values are the last iterate")
    if result.estimator_info.get("active_bounds"):
        console.print("held at their physical bound (σ = 0): " + ", ".join(result.estimator_info["active_bounds"]))
    if result.not_physical():
        console.print(f"warning: the estimate is not physical ({', '.join(result.not_physical())}); validation, "
                      f"FMU export and the twin refuse it: {result.not_physical_remedy()}")
    spikes = result.spikes
    if spikes.get("total_corrupt"):
        columns = ", ".join(f"{k} {v}" for k, v in spikes["corrupt_samples"].items() if v)
        console.print(f"warning: {spikes['total_corrupt']} samples stand apart from their neighbours "
                      f"({columns}); {'repaired before filtering' if spikes['repaired'] else 'kept as recorded'}")
    lag = result.torque_lag
    if lag:
        console.print(f"torque lag (0x6077 behind the applied torque) corrected for: {1e3 * lag['value']:.3f} ms "
                      f"= {lag['cycles']:.2f} cycles ({lag['source']})")
        if lag.get("estimate") is not None:
            console.print(f"torque lag estimated from the campaign: {1e3 * lag['estimate']:.3f} ± "
                          f"{1e3 * lag['estimate_std']:.3f} ms" +
                          ("" if lag["source"] == "estimated" else " (--torque-lag auto corrects for it)"))
            z = abs(lag["value"] - lag["estimate"]) / lag["estimate_std"] if lag["estimate_std"] else 0.0
            if lag["source"] != "estimated" and z > LAG_CONTRADICTION_Z:
                console.print(f"warning: the configured torque lag is {z:.0f} σ from the campaign's own "
                              "estimate; the parameters are corrected for a lag the data do not show")


#: Distance (in the estimate's σ) beyond which a configured torque lag contradicts the campaign's estimate:
#: p ≈ 6·10⁻⁷ for a normal estimate, so a lag the drive maker states is not flagged for noise.
LAG_CONTRADICTION_Z = 5.0


def _print_validation(validation) -> None:
    table = Table(title="Validation on the lane change (mode 2, not used for fitting)")
    table.add_column("Channel")
    table.add_column("NRMSE", justify="right")
    table.add_column("RMS error", justify="right")
    table.add_column("NRMSE, moving rows", justify="right")
    table.add_column("NRMSE, sticking rows (stick-slip)", justify="right")
    moving, sticking = validation.moving, validation.sticking
    for channel, value in validation.nrmse.items():
        m, s = moving.get(channel, {}), sticking.get(channel, {})
        cell = (f"{100 * m['nrmse']:.1f} % ({m['n_rows']} rows)" if m.get("nrmse") is not None
                else "no moving rows")
        stuck = (f"{100 * s['nrmse']:.1f} % ({s['n_rows']} rows)" if s.get("nrmse") is not None
                 else "no sticking rows")
        table.add_row(channel, f"{100 * value:.1f} %", f"{validation.rms_error[channel]:.3g}", cell, stuck)
    console.print(table)


def _plots(run_dir: Path, result, validation) -> None:
    from qomni.ident.identify import load_corrected_run
    from qomni.ident.plots import torque_comparison
    from qomni.ident.regressor_rows import identification_blocks, validation_blocks

    signals, sheet, _ = guarded(lambda: load_corrected_run(run_dir, result))
    times = {name: signals.of_step(name).time for name in signals.steps()}
    torque_comparison(identification_blocks(signals, sheet), times, result,
                      run_dir / FIG_IDENTIFICATION,
                      "Identification experiment: generalized torques (cf. paper Fig. 5)")
    if validation is None:
        return
    torque_comparison(validation_blocks(signals, sheet), times, result,
                      run_dir / FIG_VALIDATION,
                      "Validation experiment (lane change): generalized torques (cf. paper Fig. 6)",
                      nrmse=validation.nrmse)



def _identification_errors(fn):
    """``fn()``, or a plain error for a torque lag that cannot be estimated or applied or a model that
    cannot simulate the instruments of the iv estimator."""
    from qomni.ident.instruments import InstrumentError
    from qomni.ident.torque_timing import TorqueTimingError

    try:
        return fn()
    except (TorqueTimingError, InstrumentError) as exc:
        fail(str(exc))


def _identify_options(estimator: str, torque_lag: str) -> str | float:
    """Check --estimator; --torque-lag as ``"auto"`` or seconds. Anything else ends the command with a
    plain error."""
    from qomni.ident.estimators import ESTIMATORS

    if estimator not in ESTIMATORS:
        fail(f"--estimator must be one of {', '.join(ESTIMATORS)}, got {estimator!r}")
    if torque_lag == "auto":
        return torque_lag
    try:
        lag = float(torque_lag)
    except ValueError:
        lag = math.nan
    if not math.isfinite(lag):
        fail(f"--torque-lag must be 'auto' or a finite number of seconds, got {torque_lag!r}")
    return lag


@app.command()
def identify(
    run_dir: Path = typer.Argument(..., help="Run directory of a campaign."),
    estimator: str = typer.Option("wls", help=ESTIMATOR_HELP),
    torque_lag: str = typer.Option("0", "--torque-lag", help=TORQUE_LAG_HELP),
    repair_spikes: bool = typer.Option(True, "--repair-spikes/--keep-spikes", help=SPIKES_HELP),
):
    """Identify the parameters from a recorded campaign (writes identification.json)."""
    from qomni.ident.identify import identify_run

    lag = _identify_options(estimator, torque_lag)
    _print_parameters(guarded(lambda: _identification_errors(
        lambda: identify_run(run_dir, torque_lag=lag, estimator=estimator, repair_spikes=repair_spikes))))
    console.print(f"written {run_dir / IDENTIFICATION_JSON}")


@app.command()
def validate(run_dir: Path = typer.Argument(..., help="Run directory with identification.json.")):
    """Validate identification.json on the recorded lane change (writes validation.json, plots)."""
    from qomni.ident.rundir import load_identification
    from qomni.ident.identify import validate_run

    validation = guarded(lambda: _identification_errors(lambda: validate_run(run_dir)))
    _print_validation(validation)
    _plots(run_dir, guarded(lambda: load_identification(run_dir)), validation)
    console.print(f"written {run_dir / VALIDATION_JSON}")


@app.command()
def compare(
    run_dir: Path = typer.Argument(..., help="Run directory with identification.json."),
    vehicle: Optional[Path] = typer.Option(None, help="The emulated vehicle's description (truth); "
                                           "default: the prototype."),
):
    """Compare identified parameters with the emulator's truth (a separate step, never an input)."""
    from qomni.compare import compare_with_truth

    report = guarded(lambda: compare_with_truth(run_dir, load_description(vehicle)))
    table = Table(title=f"Identified vs. true ({report['vehicle']})")
    for col in ("Name", "Identified", "Std", "True", "Rel. error", "Error / σ"):
        table.add_column(col, justify="left" if col == "Name" else "right")
    for name, row in report["parameters"].items():
        table.add_row(name, f"{row['identified']:.4f}", f"{row['std']:.4f}", f"{row['true']:.4f}",
                      f"{100 * row['relative_error']:+.2f} %", f"{row['error_in_std']:+.2f}")
    console.print(table)
    console.print(f"written {run_dir / 'comparison.json'}")


