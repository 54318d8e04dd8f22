"""Torque report lag: the drives report torque actual (0x6077) late, e.g. sampled at the SYNC instant and
so one cycle behind the set-point they apply from it. The reported torque is the applied one ``lag``
seconds earlier; the motors act at once. A diagnosis sees it as a negative actuator delay."""
from __future__ import annotations

import numpy as np

from .base import Effect, EffectsError, Param, Plant


class TorqueReportLag(Effect):
    name = "torque_report_lag"
    stage = 95
    #: Blind-suite entries: the (weak, strong) ends of the realistic range (docs/effects.md).
    suite = {"torque_report_lag": ({"lag": 0.002}, {"lag": 0.006})}
    summary = "the drives' torque actual lags the torque they apply"
    params = {
        "lag": Param("s", 0.0, 0.1, doc="report delay, a multiple of the SYNC period T_s"),
    }

    def attach(self, plant: Plant) -> None:
        cycle = plant.description.drive.cycle_time
        cycles = self.values["lag"] / cycle
        if abs(cycles - round(cycles)) > 1e-6:
            raise EffectsError(f"[{self.name}] lag: {self.values['lag']} s is not a multiple of the SYNC "
                               f"period {cycle} s")
        self._fifo = np.zeros((round(cycles), 4))
        self._head = 0

    def reported_torque(self, reported: np.ndarray) -> np.ndarray:
        if not len(self._fifo):
            return reported
        out = self._fifo[self._head].copy()
        self._fifo[self._head] = reported
        self._head = (self._head + 1) % len(self._fifo)
        return out

    #: The SYNC period the lag is a multiple of, s (the data sheet's T_s).
    CYCLE = 0.002

    @classmethod
    def instance(cls, entry: str, table: dict, rng) -> dict:
        """The drawn lag on the SYNC period's grid, as the effect requires."""
        return {**table, "lag": round(round(table["lag"] / cls.CYCLE) * cls.CYCLE, 3)}
