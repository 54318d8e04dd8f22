"""From a recorded campaign to identified parameters and their validation (paper sections 6.3 and 7).

Reads the run directory (:mod:`.rundir`), builds the rows of (19) per step (:mod:`.regressor_rows`),
stacks them into (22) and estimates with B_w fixed (24), (25); the lane change (mode 2) is never used
for fitting and validates the result (Fig. 6). Both write their result into the run directory.
"""
from __future__ import annotations

from pathlib import Path

from . import filtering
from .campaign import IDENTIFICATION_STEPS, VALIDATION_STEP
from .result import IdentificationResult
from .estimation import estimate
from .regressor_rows import (COULOMB_VELOCITY_CUTOFF, VELOCITY_THRESHOLD, correlation_lag,
                             identification_blocks, validation_blocks)
from .rundir import (IDENTIFICATION_JSON, METADATA, VALIDATION_JSON, b_w_source, load_identification, load_run,
                     require_complete, write_json)
from .validation import ValidationResult, compare_generalized_torques


def identify_run(run_dir: str | Path) -> IdentificationResult:
    """Identify from a run directory and write ``identification.json`` into it."""
    run_dir = Path(run_dir)
    signals, sheet, meta = load_run(run_dir)
    require_complete(meta, IDENTIFICATION_STEPS, str(run_dir / METADATA))
    B_w, source = b_w_source(run_dir, sheet)
    lag = correlation_lag(sheet.drive.cycle_time)
    result = estimate(identification_blocks(signals, sheet), B_w,
                      velocity_threshold=VELOCITY_THRESHOLD, correlation_lag=lag)
    data = result.to_json_dict()
    data["parameters"]["B_w"]["source"] = source
    data["filter"] = {"omega_g": filtering.OMEGA_G, "unit": "rad/s", "zero_phase": True}
    data["velocity_threshold"] = VELOCITY_THRESHOLD
    data["coulomb_velocity_cutoff"] = {"value": COULOMB_VELOCITY_CUTOFF, "unit": "rad/s"}
    data["std_method"] = f"Newey-West, Bartlett kernel, {lag} lags (filtered rows are correlated)"
    data["run"] = {"status": meta.get("status", "not recorded"), "steps_used": list(IDENTIFICATION_STEPS)}
    write_json(run_dir / IDENTIFICATION_JSON, data)
    return result


def validate_run(run_dir: str | Path) -> ValidationResult:
    """Validate ``identification.json`` on the lane change and write ``validation.json``."""
    run_dir = Path(run_dir)
    signals, sheet, meta = load_run(run_dir)
    require_complete(meta, (VALIDATION_STEP,), str(run_dir / METADATA))
    result = load_identification(run_dir)
    blocks = validation_blocks(signals, sheet)
    validation = compare_generalized_torques(blocks, result)
    data = validation.to_json_dict()
    data["step"] = VALIDATION_STEP
    # As the paper's Fig. 6, all rows count above. Rows in stiction carry static friction that no
    # tanh(v/ε) model predicts; the same comparison over moving rows only separates that effect.
    moving = {}
    for block in blocks:
        try:
            one = compare_generalized_torques([block], result, velocity_threshold=VELOCITY_THRESHOLD)
            moving.update({c: {"nrmse": v, "n_rows": one.channels[c].n_rows}
                           for c, v in one.nrmse.items()})
        except ValueError:  # no row of this channel moves faster than its stiction threshold
            moving[str(block.channel[0])] = {"nrmse": None, "n_rows": 0}
    data["moving_rows"] = {"velocity_threshold": VELOCITY_THRESHOLD, "channels": moving}
    validation.moving = moving
    write_json(run_dir / VALIDATION_JSON, data)
    return validation
