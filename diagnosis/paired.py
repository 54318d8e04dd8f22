"""A paired reference run: the data's own campaign, run on the model's digital twin, sample for sample.

The model's structure is not the vehicle's even when nothing is missing (tanh friction where real joints
stick, the filter's smear of the stick-slip transients, the solver's contacts, and in the lane change the
steering's transients the paper's rigid model does not hold). The twin runs the data's campaign with the
data's settings, excitation seed and segments, and the same model leaves nearly the same residual in both
runs at the same instants: on the full campaign's lane change 12–18 N RMS in the data and in the twin,
correlated at 0.98–0.99, 1.7–2.1 N apart on clean vehicles. Subtracting the twin's residual at the same
instant leaves the gap itself: what the vehicle does that the twin does not (a 163 kg payload: 7.0 N of
the lane change's 15.6).

A torque channel of the data is *paired* where the reference run is paired (:func:`paired_runs`) and the
twin has the same channel: its residual is then the data's minus the twin's at the same sample of the
campaign (the same time, or shifted by a limit-cycle recovery only the data's run went through,
:func:`pairing_shift`; ``ChannelData.paired``), and rows the twin does not have are not fitted. The
reference run's own paired channels then hold no residual: every hypothesis' reference level there is
zero, and the reference level of a hypothesis that also acts in unpaired channels comes from those alone,
weighted as in the data.
Kinematic and rolling channels stay unpaired: they are positions measured to within the sensors' LSB, and
a twin's differently drawn noise would add to them more than its structure removes.

The subtracted residual carries the twin's noise (torque ripple, sensor noise) as well as its structure,
so a paired channel's floor is the data's noise and the twin's together. Repeats of the reference run on
independent noise draws (``repeats``) leave the same structure at the same instants and noise that
averages out: the data are then paired with the runs' mean residual, whose noise is one run's over √K for
K runs in all (the full campaign's clean vehicles, K = 3 against 1: straight driving 1.20–1.47 → 1.08–1.32 N,
rotation 1.05–1.12 → 0.78–0.89 N m, arcs 1.89–2.22 → 1.61–1.71 N).
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from qomni.ident.campaign import LIMIT_CYCLE_STEP, recorded_settings

from .channels import ChannelData

class PairingError(ValueError):
    """Runs given as repeats of a paired reference do not pair with the data (names the run)."""


#: Segment boundaries of the two runs may differ by this fraction of a cycle (text round-off).
SEGMENT_TOLERANCE = 0.5


def pairing_shift(data_meta: dict, reference_meta: dict, cycle_time: float) -> int | None:
    """Cycles to add to a data sample's index for the reference's sample at the same point of the same
    campaign, or None where the reference run is not the data's campaign run again.

    It is when both record the same campaign ``settings`` (steps, excitation design, seed, durations; a
    setting one run does not record taken as what runs drove before it was added,
    :func:`qomni.ident.campaign.recorded_settings`), the same planned cond(Θ̂₁ᵀΘ̂₁) where both record it
    (a design procedure that changed since gives other trajectories for the same settings), and the same
    ``segments`` (step names, modes and durations within half a cycle) starting at the same times but for
    one shift common to all. Segments of the campaign's limit-cycle recovery
    (:data:`qomni.ident.campaign.LIMIT_CYCLE_STEP`: the rows held when a steering loop cycled at the
    torque limit, before the campaign started again) are not part of the campaign: a run that recovered
    from one pairs with a twin that did not, its steps shifted by the recovery's duration. A data run cut
    short (stopped, aborted) records the segments it completed, the first of the campaign's: it pairs with
    a reference that went on, over the steps both completed.

    Args:
        data_meta, reference_meta: the two runs' ``metadata.json`` contents.
        cycle_time: the drives' cycle time T_s [s].
    """
    if not data_meta.get("settings") or not reference_meta.get("settings"):
        return None
    try:
        if recorded_settings(data_meta["settings"]) != recorded_settings(reference_meta["settings"]):
            return None
    except (TypeError, ValueError):
        return None
    planned = [m.get("planned_condition_number") for m in (data_meta, reference_meta)]
    if None not in planned and not math.isclose(float(planned[0]), float(planned[1]), rel_tol=1e-6):
        return None
    a, b = (_campaign_segments(m) for m in (data_meta, reference_meta))
    if not a or len(a) > len(b):
        return None
    tol = SEGMENT_TOLERANCE * cycle_time
    shift = float(b[0]["t_start"]) - float(a[0]["t_start"])
    same = all(x.get("name") == y.get("name") and x.get("k") == y.get("k")
               and math.isclose(float(x["t_start"]) + shift, float(y["t_start"]), abs_tol=tol)
               and math.isclose(float(x["t_end"]) + shift, float(y["t_end"]), abs_tol=tol) for x, y in zip(a, b))
    return int(round(shift / cycle_time)) if same else None


def paired_runs(data_meta: dict, reference_meta: dict, cycle_time: float) -> bool:
    """Whether the reference run is the data's campaign run again (:func:`pairing_shift`)."""
    return pairing_shift(data_meta, reference_meta, cycle_time) is not None


def _campaign_segments(meta: dict) -> list[dict]:
    """The run's ``segments`` without those of a limit-cycle recovery."""
    return [seg for seg in meta.get("segments") or [] if seg.get("name") != LIMIT_CYCLE_STEP]


def pair_channels(data: list[ChannelData], reference: list[ChannelData], cycle_time: float,
                  repeats: tuple[list[ChannelData], ...] = (),
                  shifts: tuple[int, ...] = ()) -> tuple[list[ChannelData], list[ChannelData]]:
    """The torque channels of both runs paired sample for sample (see the module).

    Args:
        data, reference: the channels of the data run and of its paired reference run
            (:func:`paired_runs`), under the same model.
        cycle_time: T_s [s]; rows are matched by their sample index round(t/T_s).
        repeats: the channels of further runs of the reference's campaign on independent noise draws,
            each paired with the data (:func:`paired_runs`), under the same model.
        shifts: per reference run (the reference first, then each repeat), the cycles its samples lie
            after the data's same sample (:func:`pairing_shift`); default 0 for every run.
    Returns:
        (data channels, reference channels): each torque channel that the data and every reference run
        have with ``paired`` set (on the data: the mean of the reference runs' residuals at the same
        samples; on the reference: its own residual, so that it holds none), every other channel as it
        was. A data row without a sample in every reference run is not fitted.
    """
    runs = [{c.name: c for c in run if c.kind == "torque"} for run in (reference, *repeats)]
    shifts = tuple(shifts) or (0,) * len(runs)
    if len(shifts) != len(runs):
        raise ValueError(f"{len(shifts)} shifts for {len(runs)} reference runs")
    out_data, paired_names = [], set()
    for ch in data:
        refs = [run.get(ch.name) for run in runs]
        if ch.kind != "torque" or any(ref is None for ref in refs):
            out_data.append(ch)
            continue
        k_data = np.rint(ch.time / cycle_time).astype(np.int64)
        found = np.ones(len(k_data), dtype=bool)
        total = np.zeros(len(k_data))
        for ref, shift in zip(refs, shifts):
            at_ref, in_ref = _same_samples(k_data + shift, np.rint(ref.time / cycle_time).astype(np.int64))
            found &= in_ref
            total += np.where(in_ref, ref.residual[at_ref], 0.0)
        out_data.append(replace(ch, fitted=ch.fitted & found, paired=np.where(found, total / len(refs), 0.0)))
        paired_names.add(ch.name)
    out_ref = [replace(c, paired=c.residual.copy()) if c.name in paired_names else c for c in reference]
    return out_data, out_ref


def _same_samples(k_data: np.ndarray, k_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(index into the reference's rows of each data sample, whether the reference has that sample)."""
    order = np.argsort(k_ref)
    at = np.clip(np.searchsorted(k_ref[order], k_data), 0, len(k_ref) - 1)
    return order[at], k_ref[order][at] == k_data


__all__ = ["PairingError", "SEGMENT_TOLERANCE", "pair_channels", "paired_runs", "pairing_shift"]
