"""The campaign at both ends of every effect's realistic range: does it complete inside its limits?

For each suite entry and each table of ``Effect.range_ends`` (the weak and strong ends, the strong one in
every direction that bounds it), a campaign on the ideal vehicle plus that effect, run in this process
on the embedded vehicle (the same bus and client as ``qomni campaign``; no identification). A row
completes when the campaign's status is ``complete`` (no steering angle near the stops, no bus error), no
commanded torque reached the controller's clip (``torque_margin`` × max torque) and the straight step
kept inside the length the campaign planned for it (|x_ch| ≤ ``x_max``, the occupied rectangle of
section 6.2), by odometry of the recording, within ``SPACE_TOLERANCE``.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from qomni.emulator.effects.effect_set import REGISTRY

from .cases import MAGNITUDES, effect_name

#: Tracking tolerance on the straight step's planned excursion (share of x_max).
SPACE_TOLERANCE = 0.1


@dataclass
class RangeEnd:
    """One campaign at one end of one effect's realistic range.

    Attributes:
        effects: the effects-file tables; status: the campaign's metadata status;
        peak_torque_ratio: max |commanded motor torque| / max torque; clipped: share of cycles at the clip;
        excursion: the straight step's max |x_ch − x_ch(0)| by odometry, m; room: its planned x_max, m;
        probe: the dead-time probe's result.
    """

    effects: dict
    status: str
    peak_torque_ratio: float
    clipped: float
    excursion: float
    room: float
    probe: dict

    @property
    def completed(self) -> bool:
        """Complete, never at the torque clip, inside the planned space."""
        return (self.status == "complete" and self.clipped == 0.0
                and self.excursion <= (1 + SPACE_TOLERANCE) * self.room)


def campaign_margins(effects: dict, out: Path, *, seed: int = 1, quick: bool = True, probe: bool = True) -> RangeEnd:
    """Run a campaign on the ideal vehicle with ``effects`` into ``out`` (with the dead-time probe unless
    ``probe`` is false) and measure its margins."""
    from qomni.embedded import embedded_vehicle
    from qomni.emulator.description import VehicleDescription
    from qomni.emulator.effects import EffectSet
    from qomni.ident.campaign import LIMIT_CYCLE_STEP, Campaign, CampaignAborted, CampaignSettings
    from qomni.ident.controller import ControllerSettings
    from qomni.ident.odometry import odometry
    from qomni.ident.recording import read_signals

    description = VehicleDescription.load()
    sheet = description.datasheet
    settings = CampaignSettings.quick(seed=seed) if quick else CampaignSettings(seed=seed)
    campaign = Campaign(sheet, out, settings, ControllerSettings(probe=probe), source="range ends")
    try:
        with embedded_vehicle(description, seed=seed, effects=EffectSet.from_dict(effects)) as link:
            campaign.run(link)
    except CampaignAborted:
        pass
    meta = json.loads((Path(out) / "metadata.json").read_text())
    s = read_signals(Path(out) / "signals.csv")
    limit = sheet.drive.max_torque
    clip = ControllerSettings().torque_margin * limit
    # the campaign's own steps: not a limit cycle it stopped and started again after
    peak = np.abs(s.motor_torque_cmd[s.step != LIMIT_CYCLE_STEP]).max(axis=1)
    excursion = np.inf
    if "straight" in s.steps():
        st = s.of_step("straight")
        pose, _ = odometry(st.time, st.alpha, st.motor_position / sheet.drive.i_G, sheet.geometry)
        excursion = float(np.abs(pose[:, 0] - pose[0, 0]).max())
    return RangeEnd(effects, meta["status"], float(peak.max() / limit), float(np.mean(peak >= clip - 1e-9)),
                    excursion, settings.x_max, meta.get("probe", {}))


def range_end_cases(entries=None) -> list[tuple[str, dict]]:
    """(suite entry, effects-file tables) of every range end of every entry (or of ``entries``)."""
    return [(entry, {effect_name(entry): table}) for entry in (entries or MAGNITUDES)
            for table in REGISTRY[effect_name(entry)].range_ends(entry)]
