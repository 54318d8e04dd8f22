"""``qomni diagnose``: the sim-to-real gap report of a run against an identified model."""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.table import Table
from rich.text import Text

from .app import app
from .console import console, fail, guarded, run_with_progress


@app.command()
def diagnose(
    model: Path = typer.Option(..., "--model", help="identification.json (or its run directory)."),
    data: Path = typer.Option(..., "--data", help="Run directory whose data are diagnosed."),
    holdout: Optional[Path] = typer.Option(None, "--holdout", help="Second run used only as held-out "
                                           "data (default: alternate 1 s windows of --data)."),
    out: Path = typer.Option(..., "--out", help="Directory for gap.json and report.html."),
    simulate: bool = typer.Option(True, help="Also compare 1 s forward simulations."),
    reference: Optional[Path] = typer.Option(
        None, "--reference", help="Reference run the hypotheses are tested beyond (e.g. the run the model "
                                  "was identified on). Default: the model's digital twin, run with the "
                                  "data's campaign settings and kept in OUT/twin_reference."),
    datasheet: Optional[Path] = typer.Option(None, help="Data sheet of the twin (default: the data's)."),
    other_vehicle: bool = typer.Option(False, "--other-vehicle", help="Diagnose against a model identified on "
                                       "another vehicle (another data sheet name, geometry or drive): the gap "
                                       "then holds the two vehicles' difference, which no effect describes."),
    twin_runs: int = typer.Option(1, "--twin-runs", min=1, help="Runs of the twin's campaign on independent "
                                  "noise draws, kept in OUT/twin_reference, OUT/twin_reference_1, …; the data "
                                  "are diagnosed beyond their mean residual, whose noise shrinks by √runs."),
):
    """Diagnose the sim-to-real gap: where model and data differ, which unmodelled effect explains it,
    how far the held-out residual shrinks once it is added (gap.json, report.html)."""
    from qomni.diagnosis.diagnose import check_model_vehicle, diagnose_paths, identified_on
    from qomni.diagnosis.paired import PairingError
    from qomni.diagnosis.report import reference_parameters, unnamed_further, write_report

    if out.exists() and not out.is_dir():
        fail(f"--out {out} is a file, not a directory")
    from_data = guarded(lambda: identified_on(model, data))
    if not other_vehicle and not from_data:
        guarded(lambda: check_model_vehicle(model, data))          # before the twin's campaign runs
    repeats: list[Path] = []
    if reference is None:
        reference, *repeats = _twin_references(model, data, out / "twin_reference", datasheet, twin_runs)
    elif twin_runs != 1:
        fail("--twin-runs repeats the twin's campaign; with --reference RUN there is no twin to repeat")
    elif not reference.is_dir():
        fail(f"--reference {reference} is not a run directory")
    try:
        d = guarded(lambda: diagnose_paths(model, data, holdout, reference_dir=reference,
                                           other_vehicle=other_vehicle, model_from_data=from_data,
                                           reference_repeats=repeats, simulate=simulate))
    except PairingError as exc:      # repeats of a twin whose campaign does not pair with the data's
        fail(str(exc))
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
    console.print(Text.assemble(("verdict:", "bold"), f" {d.verdict}"))
    for effect, p, level, failed in unnamed_further(d.selection):
        console.print(Text(f"not named beside it: {effect} (p = {p:.2g}, level {level:.2g}): "
                           + "; ".join(failed)))
    json_path, html_path = write_report(d, out)
    if other_vehicle and not from_data:
        _vehicle_difference(model, data, out)
    console.print(Text(f"reference run: {d.reference}" + (f" and {len(d.reference_repeats)} repeat(s) of it"
                                                          if d.reference_repeats else "")))
    twin_parameters = reference_parameters(d.reference)
    if twin_parameters:
        console.print(Text(f"twin made from: {twin_parameters}"))
    console.print(f"written {json_path} and {html_path}")


#: |z| from which two vehicles' identified parameters are printed as differing (two-sided 0.3 %).
DIFFERENCE_Z = 3.0


def _vehicle_difference(model: Path, data: Path, out: Path) -> None:
    """With --other-vehicle: the two vehicles' identified parameters side by side (data − model, σ, z),
    written to OUT/vehicle_difference.json, where the data's run holds its own identification."""
    from qomni.ident.result import parameter_differences
    from qomni.ident.rundir import IDENTIFICATION_JSON, load_identification, write_json

    if not (data / IDENTIFICATION_JSON).is_file():
        console.print(Text(f"the gap holds the two vehicles' difference; identify the data's run (qomni identify "
                           f"{data}) to compare their parameters"))
        return
    rows = guarded(lambda: parameter_differences(load_identification(model), load_identification(data)))
    table = Table(title="The two vehicles' identified parameters (data − model)")
    for col in ("Name", "Model", "Data", "Difference", "Relative", "σ", "z"):
        table.add_column(col, justify="left" if col == "Name" else "right")
    for name, row in rows.items():
        z = row["z"]
        table.add_row(name, f"{row['model']:.4g}", f"{row['other']:.4g}", f"{row['difference']:+.4g}",
                      "-" if row["relative"] is None else f"{100 * row['relative']:+.1f} %",
                      "fixed" if row["std"] is None else f"{row['std']:.3g}",
                      "-" if z is None else f"{z:+.1f}" + (" *" if abs(z) >= DIFFERENCE_Z else ""))
    console.print(table)
    differ = [name for name, row in rows.items() if row["z"] is not None and abs(row["z"]) >= DIFFERENCE_Z]
    console.print(Text(f"the vehicles differ (|z| ≥ {DIFFERENCE_Z:g}) in {', '.join(differ) or 'no parameter'}"))
    write_json(out / "vehicle_difference.json", {"model": str(model), "data": str(data),
                                                 "z_threshold": DIFFERENCE_Z, "parameters": rows})
    console.print(Text(f"written {out / 'vehicle_difference.json'}"))


def _twin_references(model: Path, data: Path, cache: Path, datasheet: Optional[Path], runs: int) -> list[Path]:
    """The model's digital twin's campaign (qomni.twin), run ``runs`` times and kept in ``cache`` and its
    siblings."""
    from qomni.datasheet import DataSheetError
    from qomni.ident.campaign import CampaignAborted
    from qomni.twin import TwinError, twin_references

    try:
        return guarded(lambda: run_with_progress(
            "twin campaign", lambda cb: twin_references(model, data, cache, runs, datasheet, on_progress=cb)))
    except (TwinError, DataSheetError, CampaignAborted, TypeError) as exc:
        fail(f"cannot run the model's digital twin: {exc}")


@app.command()
def twin(
    identification: Path = typer.Argument(..., help="identification.json (or its run directory)."),
    out: Path = typer.Option(..., "--out", help="Vehicle description TOML to write."),
    datasheet: Optional[Path] = typer.Option(None, help="Data sheet (default: the run's metadata.json)."),
):
    """Write the digital twin of an identified vehicle: an emulator vehicle description whose truth is the
    identified parameters; run it with
    'qomni campaign --vehicle OUT --effects emulator/data/effects/ideal.toml'."""
    from qomni.datasheet import DataSheetError
    from qomni.twin import TwinError, write_twin

    if out.is_dir():
        fail(f"--out {out} is a directory; give the vehicle description file to write")
    if out.suffix != ".toml":
        fail(f"--out {out}: a vehicle description is a .toml file")
    if not out.parent.is_dir():
        fail(f"--out {out}: its folder {out.parent} does not exist")
    try:
        path = guarded(lambda: write_twin(identification, out, datasheet))
    except (TwinError, DataSheetError, OSError) as exc:
        fail(str(exc))
    console.print(f"written {path}")

