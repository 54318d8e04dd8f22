"""CANopen master for the vehicle: the same code drives the emulator (``qomni.hil.device.server``) and the real vehicle.

Built on canopen (:class:`canopen.profiles.p402.BaseNode402` for the drives, :class:`canopen.RemoteNode`
for the encoders, both from the EDS files) and python-can; nothing here knows about the emulator, only
the bus spec differs (``"virtual"`` vs ``"socketcan:can0"``).

Start-up (:meth:`VehicleClient.connect`), CiA 301 §7.2.8 / CiA 402 §6:

1. NMT reset communication of nodes 1…6, wait for their boot-up messages;
2. configure by SDO (PRE-OPERATIONAL): 0x1019 (the SYNC's counter), 0x1006 = T_s; PDO communication and
   mapping written from the EDS defaults (or, like 0x1019, read from the devices); drives: read 0x6076
   rated torque and 0x6072 max torque, check 0x6502, target torque 0x6071 = 0, 0x6060 = 10 (CST)
   confirmed by reading 0x6061;
3. walk every drive's power state machine to OPERATION ENABLED by SDO (fault reset if needed);
4. NMT start.

Cycle (:meth:`VehicleClient.exchange`): the RPDOs (controlword 0x000F, target torque per mille), then
SYNC (with its counter where 0x1019 sets one), then wait for every synchronous TPDO of this SYNC.
Everything the master sends and receives can be recorded to a BLF file.

Supervision while operational: a boot-up message of a node (it lost power or was reset) makes the next
:meth:`VehicleClient.exchange` raise :class:`CommunicationError` at once; every EMCY (CiA 301 §7.2.7) is
kept in :attr:`VehicleClient.emcy` and the recent ones are named in the error of a missed cycle.
"""
from __future__ import annotations

import logging
import math
import threading
import time
from pathlib import Path

import can
import canopen
import numpy as np
from canopen.profiles.p402 import BaseNode402, State402
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from qomni.vehicle_interface import Measurement

from ..cia import (CW_FAULT_RESET as _CW_FAULT_RESET, CW_SHUTDOWN as _CW_SHUTDOWN,
                   SW_OPERATION_ENABLED as _SW_OPERATION_ENABLED, SW_STATE_MASK as _SW_STATE_MASK)
from ..layout import DRIVE_EDS, DRIVE_NODE_IDS, ENCODER_EDS, SYNC_COB_ID, WHEELS
from ..tools.recorder import BusRecorder
from ..units import device_measurement, unwrap32
from . import dcf
from .configure import ClientConfiguration, RecordingNetwork
from .errors import CommunicationError, DriveFaultError
from .supervision import ClientSupervision

logger = logging.getLogger(__name__)


def state_of(statusword: int) -> str:
    """CiA 402 state name of a statusword (canopen's State402 coding), 'UNKNOWN' if none matches."""
    for state, (mask, bits) in State402.SW_MASK.items():
        if statusword & mask == bits:
            return state
    return "UNKNOWN"


class VehicleClient(ClientConfiguration, ClientSupervision):
    """Master of the vehicle's CANopen network (drives 1…4 = fl, rl, fr, rr; encoders 5, 6 = left, right).

    Args:
        bus: bus spec string (:func:`qomni.hil.bus.open_bus`, closed on :meth:`stop`) or an open python-can
            bus (left open).
        encoder_increments: motor encoder increments per motor revolution (data sheet).
        steering_sensor_bits: resolution of the steering angle sensors (data sheet).
        cycle_time: s, SYNC period T_s (data sheet); written to 0x1006 of every node.
        record: path of a bus log, or a list of them (``.blf``; ``.log`` = candump ``-L`` format; see
            :mod:`qomni.hil.tools.recorder`): every frame in both directions, flushed by :meth:`stop`.
        drive_eds, encoder_eds: EDS files; their PDO mapping is written to the devices.
        configure_pdos: True: write the EDS PDO configuration by SDO; False: read the devices'.
        timeout: s, how long :meth:`exchange` waits for the TPDOs of one SYNC when none has come.
        max_missed: consecutive cycles with a TPDO missing that :meth:`exchange` rides through, holding
            the missing TPDO's last sample (a real master's behaviour on a lossy bus); one more aborts.
        tpdo_grace: s a SYNC's other TPDOs get once its first has come (default ten cycles, at most
            ``timeout``); a lock-step host that never loses frames passes ``timeout``, so a loaded machine
            cannot turn a late frame into a held sample.
        boot_timeout: s, how long :meth:`connect` waits for boot-up messages.
        enable_timeout: s, per drive, for the walk to OPERATION ENABLED.
        concise_dcf: {node-ID: concise DCF} (:mod:`qomni.hil.master.dcf`, the CiA 302 0x1F22 content)
            written to that node by SDO after boot-up, before the client's own configuration.
    Attributes:
        rated_torque: (4,) N m motor side, from 0x6076 (read at connect).
        max_torque: (4,) N m motor side, from 0x6072.
        cycle: SYNCs sent since connect.
        sync_counter_overflow: 0x1019 of every node (set at connect): the SYNC carries a counter 1…this
            value (the counter of SYNC k since NMT start is k mod it + 1), or no data where it is 0.
        missed: {COB-ID: cycles} whose TPDO did not arrive and was held from the cycle before.
    Raises:
        ValueError: non-positive data-sheet numbers; ConciseDcfError (a ValueError): a malformed concise DCF.

    The drives supervise the master: if SYNCs stop for longer than their SYNC timeout (0.1 s for the
    emulator) while they are enabled, they fault and the next :meth:`exchange` raises
    :class:`DriveFaultError`; call :meth:`enable` to continue. Keep cycling (zero torque) or call
    :meth:`stop` during long pauses.
    """

    def __init__(self, bus: str | can.BusABC = "virtual", *, encoder_increments: int,
                 steering_sensor_bits: int, cycle_time: float,
                 record: str | Path | list[str | Path] | None = None,
                 drive_eds: str | Path = DRIVE_EDS, encoder_eds: str | Path = ENCODER_EDS,
                 configure_pdos: bool = True, timeout: float = 0.5, boot_timeout: float = 2.0,
                 enable_timeout: float = 1.0, max_missed: int = 5, tpdo_grace: float | None = None,
                 concise_dcf: dict[int, bytes] | None = None):
        if encoder_increments <= 0 or steering_sensor_bits <= 0 or not cycle_time > 0:
            raise ValueError("encoder_increments, steering_sensor_bits and cycle_time must be > 0")
        self.encoder_increments = int(encoder_increments)
        self.steering_sensor_bits = int(steering_sensor_bits)
        self.cycle_time = float(cycle_time)
        self.record = None if record is None else (
            Path(record) if isinstance(record, (str, Path)) else [Path(p) for p in record])
        self.timeout = timeout
        self.max_missed = int(max_missed)
        self.tpdo_grace = min(10 * cycle_time, timeout) if tpdo_grace is None else float(tpdo_grace)
        self.missed: dict[int, int] = {}
        self._consecutive_missed = 0
        self._last_rx: dict[int, bytes] = {}
        self._last_good = time.time()
        self.boot_timeout = boot_timeout
        self.enable_timeout = enable_timeout
        self._bus_arg = bus
        self._drive_eds, self._encoder_eds = str(drive_eds), str(encoder_eds)
        self._configure_pdos = configure_pdos
        self._concise_dcf = {int(k): bytes(v) for k, v in (concise_dcf or {}).items()}
        for data in self._concise_dcf.values():
            dcf.parse(data)                              # a malformed one fails here, not at connect
        self.rated_torque = np.full(4, np.nan)
        self.max_torque = np.full(4, np.nan)
        self.cycle = 0
        self.sync_counter_overflow = 0
        self._sync_data = [b""]
        self._network: RecordingNetwork | None = None
        self._bus: can.BusABC | None = None
        self._recorder: BusRecorder | None = None
        self.drives: list[BaseNode402] = []
        self.encoders: list[canopen.RemoteNode] = []
        self._operational = False
        self._rx: dict[int, bytes] = {}
        self._rx_done = threading.Event()
        self._expected = 0
        self._booted = False
        self._unwrap: tuple[np.ndarray, np.ndarray] | None = None
        self.emcy: list[tuple[int, int, int, float]] = []      # (node id, error code, register, time)
        self._rebooted: list[int] = []

    @classmethod
    def from_drive(cls, drive, bus: str | can.BusABC = "virtual", **kwargs) -> "VehicleClient":
        """Client from a data-sheet object with ``encoder_increments``, ``steering_sensor_bits`` and
        ``cycle_time`` attributes (e.g. a vehicle description's ``drive`` section)."""
        return cls(bus, encoder_increments=drive.encoder_increments,
                   steering_sensor_bits=drive.steering_sensor_bits, cycle_time=drive.cycle_time, **kwargs)

    # --------------------------------------------------------- lifecycle
    def connect(self) -> "VehicleClient":
        """Boot, configure and enable the vehicle, then NMT start (module docstring).

        Raises:
            CommunicationError: a node did not boot, an SDO failed, a drive could not be enabled, or the
                PDO mapping lacks an object the cycle needs.
            ValueError, can.CanError: the bus spec is bad or the bus cannot be opened.
        """
        if self._network is not None:
            raise RuntimeError("client already connected")
        try:
            self._open()
            self._boot()
            self._configure()
            self.enable()
            self._start()
        except BaseException:
            self.stop()
            raise
        return self

    def __enter__(self) -> "VehicleClient":
        return self.connect()

    def __exit__(self, *exc) -> None:
        self.stop()

    def stop(self) -> None:
        """Make the vehicle safe and disconnect; always safe to call (also after errors, twice, or
        without connect).

        Sends target torque 0 and controlword SHUTDOWN (torque off) to every drive by SDO, NMT
        PRE-OPERATIONAL to every node, then stops receiving, flushes the bus log and closes the bus if
        it was opened here. Communication errors on the way are logged, not raised.
        """
        network, self._network = self._network, None
        try:
            if network is not None and network.bus is not None and self._booted:
                for node in self.drives:                   # every drive, even after one stayed silent
                    try:
                        node.sdo[0x6071].raw = 0
                        node.sdo[0x6040].raw = _CW_SHUTDOWN
                    except SdoCommunicationError as exc:   # no answer: the others get a short wait
                        logger.warning("stop: drive %d does not answer (%s)", node.id, exc)
                        for other in self.drives:
                            other.sdo.RESPONSE_TIMEOUT = min(other.sdo.RESPONSE_TIMEOUT, 0.05)
                    except Exception as exc:               # noqa: BLE001 - keep making things safe
                        logger.warning("stop: drive %d: shutdown by SDO failed: %s", node.id, exc)
                for node in self.drives + self.encoders:
                    try:
                        node.nmt.send_command(0x80)        # PRE-OPERATIONAL
                    except Exception as exc:               # noqa: BLE001
                        logger.warning("stop: NMT to node %d failed: %s", node.id, exc)
        finally:
            self._operational = self._booted = False
            try:
                if network is not None and network.notifier is not None:
                    network.notifier.stop(1.0)
            finally:
                if self._recorder is not None:
                    self._recorder.stop()
                if self._bus is not None and isinstance(self._bus_arg, str):
                    self._bus.shutdown()
                self._bus = None

    # ------------------------------------------------------------ cycle
    def exchange(self, motor_torque) -> Measurement:
        """One lock-step cycle: send torques, SYNC, collect the TPDOs of this SYNC.

        Args:
            motor_torque: (4,) N m motor side, order fl, rl, fr, rr; sent as per mille of the rated
                torque (rounded), clipped to ±0x6072.
        Returns:
            The :class:`~qomni.vehicle_interface.Measurement` sampled at this SYNC.
        Raises:
            ValueError: wrong shape or non-finite torque.
            CommunicationError: not connected, or not all TPDOs arrived within ``timeout``.
            DriveFaultError: a drive reports a state other than OPERATION ENABLED.
        """
        if not self._operational:
            raise CommunicationError("not connected: call connect() first")
        if self._rebooted:
            raise CommunicationError(
                f"node(s) {sorted(set(self._rebooted))} sent a boot-up message while operational (power "
                f"loss or reset): their configuration is gone{self._recent_emcy()}")
        tau = np.asarray(motor_torque, dtype=float)
        if tau.shape != (4,):
            raise ValueError(f"motor_torque must have shape (4,), got {tau.shape}")
        # per mille of rated, rounded half to even (as np.rint) and clipped; on Python floats, which is
        # four numpy calls less per cycle and the same numbers
        per_mille = []
        for t, scale, limit in zip(tau.tolist(), self._per_mille_scale, self._per_mille_limit):
            if not math.isfinite(t):
                raise ValueError(f"motor_torque must be finite, got {tau}")
            per_mille.append(int(min(max(round(t * scale), -limit), limit)))
        self._rx.clear()
        self._rx_done.clear()
        send = self._network.send_message
        for cob_id, codec, drive, slots in self._rpdo_plan:
            values = [per_mille[drive] if slot is None else slot for slot in slots]
            send(cob_id, codec.pack(values))
        sync_data = self._sync_data
        send(SYNC_COB_ID, sync_data[self.cycle % len(sync_data)])   # counter 1…0x1019, or no data
        t = self.cycle * self.cycle_time
        self.cycle += 1
        if not self._wait_for_tpdos():
            missing = sorted(set(self._tpdo_plan) - set(self._rx))
            self._consecutive_missed += 1
            if self._consecutive_missed > self.max_missed or not self._last_rx or self._rebooted:
                silent = sorted({c & 0x7F for c in missing})
                raise CommunicationError(
                    f"cycle {self.cycle - 1}: no TPDO with COB-ID {', '.join(f'0x{c:03X}' for c in missing)} "
                    f"(node(s) {', '.join(map(str, silent))}) for {self._consecutive_missed} cycle(s) in a row"
                    f"{self._lost_cause()}")
            for cob_id in missing:                       # hold the last sample, as a real master does
                self.missed[cob_id] = self.missed.get(cob_id, 0) + 1
                self._rx[cob_id] = self._last_rx[cob_id]
            logger.warning("cycle %d: TPDO %s missing, last sample held (%d in a row)", self.cycle - 1,
                           ", ".join(f"0x{c:03X}" for c in missing), self._consecutive_missed)
        else:
            self._consecutive_missed = 0
            self._last_good = time.time()
        self._last_rx.update(self._rx)
        return self._decode(t)

    def _wait_for_tpdos(self) -> bool:
        """Whether every TPDO of this SYNC arrived. Without any, wait ``timeout``; once the first has
        come, the rest of the same SYNC get ``tpdo_grace``: a device sends its TPDOs of a SYNC together,
        within its cycle, so a frame later than that is a lost one."""
        deadline = time.monotonic() + self.timeout
        while not self._rx:
            if self._rx_done.wait(min(0.01, self.timeout)) or time.monotonic() > deadline:
                return self._rx_done.is_set()
        return self._rx_done.wait(self.tpdo_grace)


    def enable(self) -> None:
        """Walk every drive to OPERATION ENABLED by SDO (controlword 0x6040, statusword 0x6041), with a
        fault reset (controlword bit 7 rising edge) if a drive is in FAULT. Works in PRE-OPERATIONAL and
        OPERATIONAL; clears target torque 0x6071 first.

        Raises:
            CommunicationError: SDO failure, or a drive not enabled within ``enable_timeout``.
        """
        for node in self.drives:
            self._write(node, 0x6071, 0)
            deadline = time.monotonic() + self.enable_timeout
            while True:
                statusword = self._read(node, 0x6041)
                state = state_of(statusword)
                if state == "OPERATION ENABLED":
                    break
                if time.monotonic() > deadline:
                    raise CommunicationError(
                        f"drive {node.id} ({WHEELS[node.id - 1]}) stays in {state} "
                        f"(statusword 0x{statusword:04X}) instead of OPERATION ENABLED")
                if state == "FAULT":
                    self._write(node, 0x6040, 0x0000)
                    self._write(node, 0x6040, _CW_FAULT_RESET)
                elif state in ("NOT READY TO SWITCH ON", "FAULT REACTION ACTIVE", "UNKNOWN"):
                    time.sleep(0.005)                     # automatic transition in progress
                else:
                    target = "OPERATION ENABLED"
                    if (state, target) not in State402.TRANSITIONTABLE:
                        target = State402.next_state_indirect(state)
                    self._write(node, 0x6040, State402.TRANSITIONTABLE[(state, target)])

    # ----------------------------------------------------------- set-up


    def _start(self) -> None:
        for cob_id in self._tpdo_plan:
            self._network.subscribe(cob_id, self._on_tpdo)
        self._watch_nodes()
        self._rebooted = []
        for node in self.drives + self.encoders:
            node.nmt.send_command(0x01)                  # NMT start
        self.cycle = 0
        self._unwrap = None
        self._operational = True

    # ------------------------------------------------------- reception
    def _on_tpdo(self, can_id: int, data, timestamp: float) -> None:
        rx = self._rx
        rx[can_id] = data
        if len(rx) >= self._expected:
            self._rx_done.set()

    def _decode(self, t: float) -> Measurement:
        fields = {"status": [None] * 4, "position": [0] * 4, "velocity": [0] * 4, "torque": [0] * 4,
                  "counts": [0] * 2}
        for cob_id, data in list(self._rx.items()):
            plan = self._tpdo_plan.get(cob_id)
            if plan is None:
                continue
            codec, sinks = plan
            if len(data) < codec.size:
                raise CommunicationError(f"cycle {self.cycle - 1}: TPDO 0x{cob_id:03X} has {len(data)} "
                                         f"bytes, mapping needs {codec.size}")
            for sink, value in zip(sinks, codec.unpack(data)):
                if sink is not None:
                    fields[sink[0]][sink[1]] = value
        raw = np.array(fields["position"], dtype=np.int64)
        total = raw if self._unwrap is None else unwrap32(raw, *self._unwrap)
        self._unwrap = (raw, total)
        measurement = device_measurement(t, total, fields["velocity"], fields["torque"], fields["counts"],
                                         encoder_increments=self.encoder_increments,
                                         rated_torque=self.rated_torque,
                                         steering_sensor_bits=self.steering_sensor_bits)
        bad = {DRIVE_NODE_IDS[i]: state_of(sw) for i, sw in enumerate(fields["status"])
               if sw is not None and sw & _SW_STATE_MASK != _SW_OPERATION_ENABLED}
        if bad:
            raise DriveFaultError(
                f"cycle {self.cycle - 1}: drive(s) not OPERATION ENABLED: "
                + ", ".join(f"{n} ({WHEELS[n - 1]}) {s}{self._error_code(n)}" for n, s in bad.items())
                + f"{self._lost_cause()}; call enable() to recover", measurement, bad)
        return measurement

    # ------------------------------------------------------------- SDO
    def _read(self, node, index: int, subindex: int | None = None):
        try:
            obj = node.sdo[index] if subindex is None else node.sdo[index][subindex]
            return obj.raw
        except (SdoAbortedError, SdoCommunicationError) as exc:
            raise CommunicationError(f"node {node.id}: SDO read 0x{index:04X} failed: {exc}") from exc

    def _write(self, node, index: int, value, subindex: int | None = None) -> None:
        try:
            obj = node.sdo[index] if subindex is None else node.sdo[index][subindex]
            obj.raw = value
        except (SdoAbortedError, SdoCommunicationError) as exc:
            raise CommunicationError(f"node {node.id}: SDO write 0x{index:04X} = {value} failed: {exc}") \
                from exc


