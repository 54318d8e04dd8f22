"""From a recorded campaign to identified parameters and their validation (paper sections 6.3 and 7).

Reads the run directory (:mod:`.rundir`), builds the rows of (19) per step (:mod:`.regressor_rows`),
stacks them into (22) and estimates with B_w fixed (24), (25); the lane change (mode 2) is never used
for fitting and validates the result (Fig. 6). Both write their result into the run directory.
"""
from __future__ import annotations

import math
from pathlib import Path

from qomni.datasheet import DataSheet

from . import filtering
from .campaign import IDENTIFICATION_STEPS, VALIDATION_STEP
from .result import IdentificationResult
from .estimation import estimate
from .regressor_rows import (VELOCITY_THRESHOLD, correlation_lag, coulomb_steering_cutoff,
                             coulomb_velocity_cutoff, identification_blocks, validation_blocks)
from .recording import Signals
from .rundir import (IDENTIFICATION_JSON, METADATA, SIGNALS, SINGLE_AXIS_DIR, SINGLE_AXIS_JSON, VALIDATION_JSON,
                     RunDirectoryError, b_w_source, check_identification_vehicle, file_sha256,
                     load_identification, load_repaired_run, read_json, require_complete, write_json)
from .instruments import simulated_instruments
from .single_axis import identify_single_axis
from .least_squares import IdentifiabilityError
from .torque_timing import TorqueLag, TorqueTimingError, check_lag, estimate_torque_lag, model_lag, shift_torque
from .validation import ValidationResult, compare_generalized_torques, stick_slip_comparison


#: Instrument refinements of the ``iv`` estimator: WLS → instruments → IV → instruments → IV.
IV_ITERATIONS = 2


def identify_run(run_dir: str | Path, *, torque_lag: str | float = 0.0,
                 estimator: str = "wls", repair_spikes: bool = True) -> IdentificationResult:
    """Identify from a run directory and write ``identification.json`` into it (:func:`identify`).

    Raises: as :func:`identify`.
    """
    run_dir = Path(run_dir)
    result, data = identify(run_dir, torque_lag=torque_lag, estimator=estimator, repair_spikes=repair_spikes)
    write_json(run_dir / IDENTIFICATION_JSON, data)
    return result


def identify(run_dir: str | Path, *, torque_lag: str | float = 0.0,
             estimator: str = "wls", repair_spikes: bool = True) -> tuple[IdentificationResult, dict]:
    """Identify from a run directory: the result and the content of its ``identification.json``, not
    written (a single-axis recording made with another torque lag is re-identified in place).

    Args:
        run_dir: a campaign's run directory.
        torque_lag: the lag of the reported torque behind the applied one the fit corrects for:
            ``"auto"`` the campaign's own estimate (:mod:`.torque_timing`), a number (s) a known lag
            (default 0: 0x6077 as docs/conventions.md defines it). The torque is corrected before the
            fit, the single-axis B_w too when the run has a single-axis recording. The estimate is
            made and reported in every case.
        estimator: one of :data:`.estimators.ESTIMATORS`.
        repair_spikes: repair isolated glitches of the drives' signals before filtering (:mod:`.spikes`;
            reported as ``spikes`` in identification.json either way).
    Raises:
        RunDirectoryError, RecordingError, DataSheetError: the run directory (RecordingError also for a
        signal column more than 5 % corrupt); IdentifiabilityError: the
        campaign does not determine p₁; TorqueTimingError: the lag; ValueError: an unknown estimator.
    """
    run_dir = Path(run_dir)
    signals, sheet, meta, spikes = load_repaired_run(run_dir, repair=repair_spikes)
    require_complete(meta, IDENTIFICATION_STEPS, str(run_dir / METADATA))
    B_w, source = b_w_source(run_dir, sheet)
    ts = sheet.drive.cycle_time
    lag = correlation_lag(ts)
    blocks_of = lambda s: identification_blocks(s, sheet)  # noqa: E731
    if torque_lag == "auto":
        timing = estimate_torque_lag(signals, blocks_of, B_w, ts, VELOCITY_THRESHOLD, lag)
    else:
        value = check_lag(torque_lag)
        try:
            found = estimate_torque_lag(signals, blocks_of, B_w, ts, VELOCITY_THRESHOLD, lag)
        except (TorqueTimingError, IdentifiabilityError):
            found = TorqueLag(math.nan, "estimated", ts)   # reported as null: not estimable here
        timing = TorqueLag(value, "configured", ts, estimate=None if math.isnan(found.value) else found.value,
                           estimate_std=found.std)
    if (run_dir / SINGLE_AXIS_DIR / SIGNALS).exists() and single_axis_lag(run_dir) != timing.value:
        identify_single_axis(run_dir, sheet, torque_lag=timing.value)
        B_w, source = b_w_source(run_dir, sheet)
    corrected = shift_torque(signals, timing.value)
    blocks = blocks_of(corrected)
    fit = lambda name, z=None: estimate(blocks, B_w, velocity_threshold=VELOCITY_THRESHOLD,  # noqa: E731
                                        correlation_lag=lag, estimator=name, instruments=z)
    if estimator == "iv":
        result = fit("wls")
        for _ in range(IV_ITERATIONS):     # instruments from the model of the previous estimate
            result = fit("iv", simulated_instruments(corrected, sheet, result.p))
    else:
        result = fit(estimator)
    result.torque_lag = timing.to_json_dict()
    result.spikes = spikes.to_json_dict()
    data = result.to_json_dict()
    data["parameters"]["B_w"]["source"] = source
    data["filter"] = {"omega_g": filtering.OMEGA_G, "unit": "rad/s", "zero_phase": True}
    data["velocity_threshold"] = VELOCITY_THRESHOLD
    data["coulomb_velocity_cutoff"] = {"value": coulomb_velocity_cutoff(sheet.drive),
                                       "steering": coulomb_steering_cutoff(sheet.drive), "unit": "rad/s"}
    data["std_method"] = f"Newey-West, Bartlett kernel, {lag} lags (filtered rows are correlated)"
    data["run"] = {"status": meta.get("status", "not recorded"), "steps_used": list(IDENTIFICATION_STEPS),
                   "signals_sha256": file_sha256(run_dir / SIGNALS)}
    if "vehicle" in meta and "datasheet" in meta:      # the vehicle the model belongs to (diagnosis)
        data["run"].update(vehicle=meta["vehicle"], datasheet=meta["datasheet"])
    return result, data


def single_axis_lag(run_dir: Path) -> float:
    """The torque lag (s) the run's ``single_axis.json`` was identified with (0 when it says none)."""
    path = run_dir / SINGLE_AXIS_JSON
    if not path.exists():
        return math.nan
    return float(read_json(path).get("torque_lag", {}).get("value", 0.0))


def load_corrected_run(run_dir: str | Path, model: IdentificationResult | None = None
                       ) -> tuple[Signals, DataSheet, dict]:
    """:func:`load_repaired_run` (glitches repaired unless the identification kept them) with the torque
    corrected by the lag of ``model`` (default: the run's ``identification.json``)."""
    run_dir = Path(run_dir)
    model = load_identification(run_dir) if model is None else model
    signals, sheet, meta, _ = load_repaired_run(run_dir, repair=model.spikes.get("repaired", True))
    return shift_torque(signals, model_lag(model)), sheet, meta


def validate_run(run_dir: str | Path) -> ValidationResult:
    """Validate ``identification.json`` on the lane change and write ``validation.json``.

    Raises: RunDirectoryError: a file missing or invalid, the lane change not completed, a model that is
    not physical, or one identified on another vehicle (:func:`.rundir.check_identification_vehicle`)."""
    run_dir = Path(run_dir)
    result = load_identification(run_dir)
    signals, sheet, meta = load_corrected_run(run_dir, result)
    check_identification_vehicle(run_dir / IDENTIFICATION_JSON, sheet, meta.get("vehicle"), f"the run {run_dir}",
                                 "validate a model on a run of its own vehicle")
    require_complete(meta, (VALIDATION_STEP,), str(run_dir / METADATA))
    if result.not_physical():
        raise RunDirectoryError(f"{run_dir / IDENTIFICATION_JSON}: the model is not physical "
                                f"({', '.join(result.not_physical())}); its forward simulation would not be "
                                f"a vehicle's: {result.not_physical_remedy()}")
    blocks = validation_blocks(signals, sheet)
    validation = compare_generalized_torques(blocks, result)
    data = validation.to_json_dict()
    data["step"] = VALIDATION_STEP
    # As the paper's Fig. 6, all rows count above. Rows in stiction carry static friction that no
    # tanh(v/ε) model predicts: moving rows are compared with the model, sticking rows with the model
    # made able to stick (a stick-slip switch), each on its own.
    split = stick_slip_comparison(blocks, result, VELOCITY_THRESHOLD)
    moving = {c: (v["moving"] if v["moving"]["n_rows"] else {"nrmse": None, "n_rows": 0})
              for c, v in split.items()}
    data["moving_rows"] = {"velocity_threshold": VELOCITY_THRESHOLD, "channels": moving}
    data["sticking_rows"] = {"model": "stick-slip switch: friction balances the torque within the static "
                                      "friction band F_s (the Coulomb level)",
                             "channels": {c: dict(v["sticking"], moving_share=v["moving_share"])
                                          for c, v in split.items()}}
    validation.moving = moving
    validation.sticking = data["sticking_rows"]["channels"]
    write_json(run_dir / VALIDATION_JSON, data)
    return validation
