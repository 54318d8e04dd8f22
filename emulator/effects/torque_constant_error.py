"""Torque-constant error of one drive: its motor applies ``factor`` × the torque the drive reports.

The drive computes torque actual (0x6077) from its current with a nominal torque constant; the real
constant differs (magnet temperature, tolerance), so the applied torque is scaled and the report is not."""
from __future__ import annotations

import numpy as np

from .base import WHEELS, Effect, Param, mirrored


class TorqueConstantError(Effect):
    name = "torque_constant_error"
    stage = 110
    #: Blind-suite entries: the (weak, strong) ends of the realistic range (docs/effects.md).
    suite = {"torque_constant_error": ({"drive": "fl", "factor": 0.95}, {"drive": "fl", "factor": 0.85})}
    summary = "one drive applies factor × its reported torque"
    params = {
        "drive": Param("-", kind="choice", choices=WHEELS, doc="the drive: fl, rl, fr or rr"),
        "factor": Param("-", 0.5, 1.5, doc="applied / reported torque"),
    }

    def __init__(self, **values):
        super().__init__(**values)
        self._scale = np.ones(4)
        if self.values["drive"] in WHEELS:
            self._scale[WHEELS.index(self.values["drive"])] = self.values["factor"]

    def drive_torque(self, applied: np.ndarray) -> np.ndarray:
        return applied * self._scale

    @classmethod
    def instance(cls, entry: str, table: dict, rng) -> dict:
        """Any drive, the factor below or above 1 by the drawn deviation."""
        factor = table["factor"] if rng.random() < 0.5 else mirrored(table["factor"], 1.0)
        return {**table, "drive": str(rng.choice(WHEELS)), "factor": float(factor)}

    @classmethod
    def drawn(cls, entry: str, table: dict) -> dict:
        """A factor above 1 mirrored below it (the drawn deviation)."""
        factor = float(table["factor"])
        return {**table, "factor": factor if factor <= 1.0 else mirrored(factor, 1.0)}

    @classmethod
    def range_ends(cls, entry: str) -> list[dict]:
        """The deviations' ends below and above 1."""
        weak, strong = cls.suite[entry]
        return [dict(t, factor=f) for t in (weak, strong) for f in (t["factor"], mirrored(t["factor"], 1.0))]
