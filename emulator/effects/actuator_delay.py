"""Actuator delay: the motor applies the torque the drive reported ``delay`` seconds earlier.

Current-loop and PWM latency plus the drive's set-point pipeline: torque actual (0x6077) equals the
commanded torque at once, the torque on the shaft follows later. A FIFO of physics steps."""
from __future__ import annotations

import numpy as np

from .base import Effect, EffectsError, Param, Plant


class ActuatorDelay(Effect):
    name = "actuator_delay"
    stage = 100
    #: Blind-suite entries: the (weak, strong) ends of the realistic range (docs/effects.md).
    suite = {"actuator_delay": ({"delay": 0.002}, {"delay": 0.02})}
    summary = "applied torque lags the reported torque by a dead time"
    params = {
        "delay": Param("s", 0.0, 0.1, doc="dead time, a multiple of the physics step (1 ms)"),
    }

    def attach(self, plant: Plant) -> None:
        steps = self.values["delay"] / plant.time_step
        if abs(steps - round(steps)) > 1e-6:
            raise EffectsError(f"[{self.name}] delay: {self.values['delay']} s is not a multiple of the "
                               f"physics step {plant.time_step} s")
        self._fifo = np.zeros((round(steps), 4))
        self._head = 0

    def drive_torque(self, applied: np.ndarray) -> np.ndarray:
        if not len(self._fifo):
            return applied
        out = self._fifo[self._head].copy()
        self._fifo[self._head] = applied
        self._head = (self._head + 1) % len(self._fifo)
        return out

    @classmethod
    def instance(cls, entry: str, table: dict, rng) -> dict:
        """The drawn delay on the physics step's grid (1 ms), as the effect requires."""
        return {**table, "delay": round(table["delay"], 3)}
