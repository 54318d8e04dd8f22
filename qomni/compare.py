"""Truth comparison: identified parameters against the emulated vehicle's true ones.

A separate, explicit step after identification; nothing here feeds back into estimation.
"""
from __future__ import annotations

from pathlib import Path

from qomni.emulator.description import VehicleDescription
from qomni.ident.rundir import COMPARISON_JSON, check_identification_vehicle, load_identification, write_json



def compare_with_truth(run_dir: str | Path, description: VehicleDescription) -> dict:
    """Identified vs. true per parameter: relative error and error in standard deviations.

    Writes ``comparison.json`` into ``run_dir`` and returns its content.

    Raises:
        RunDirectoryError: no identification.json in ``run_dir``, or one identified on another vehicle than
        ``description``'s (:func:`qomni.ident.rundir.check_identification_vehicle`).
    """
    run_dir = Path(run_dir)
    result = load_identification(run_dir)
    check_identification_vehicle(run_dir, description.datasheet, description.name,
                                 f"the described vehicle {description.source}",
                                 "compare with the description of the vehicle the run drove (--vehicle)")
    truth = description.truth
    rows = {}
    for name, value in result.values.items():
        true = getattr(truth, name)
        std = result.std[name]
        rows[name] = {"identified": value, "std": std, "true": true,
                      "relative_error": (value - true) / true,
                      "error_in_std": (value - true) / std if std > 0 else float("inf")}
    report = {"vehicle": description.name, "source": description.source, "parameters": rows,
              "B_w": {"fixed": result.B_w, "true": truth.B_w}}
    write_json(run_dir / COMPARISON_JSON, report)
    return report
