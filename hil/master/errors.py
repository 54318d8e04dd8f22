"""The client's errors: the vehicle did not answer as it should (:class:`CommunicationError`), or a drive
left OPERATION ENABLED (:class:`DriveFaultError`)."""
from __future__ import annotations

from qomni.vehicle_interface import Measurement


class CommunicationError(RuntimeError):
    """The vehicle did not answer (in time) or answered wrongly: missing boot-up, SDO abort/timeout,
    missing TPDO after a SYNC, or a PDO mapping the master cannot use."""


class DriveFaultError(CommunicationError):
    """A drive is no longer OPERATION ENABLED (fault, e.g. after a SYNC timeout, or quick stop).

    Attributes:
        measurement: the :class:`~qomni.vehicle_interface.Measurement` of the cycle that revealed it.
        states: {node id: CiA 402 state name} of the drives not in OPERATION ENABLED.
    """

    def __init__(self, message: str, measurement: Measurement, states: dict[int, str]):
        super().__init__(message)
        self.measurement = measurement
        self.states = states
