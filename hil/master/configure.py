"""Bringing the vehicle's network up for the client: open the bus, await the boot-up messages, configure
every node by SDO (a concise DCF where given, 0x1006, the PDO mapping from the EDS or read from the devices, the drives' mode) and
plan the cycle's codecs (CiA 301 §7.2.2 PDOs; CiA 402 0x6060/0x6061, 0x6502)."""
from __future__ import annotations

import logging
import threading

import can
import canopen
import numpy as np
from canopen.profiles.p402 import BaseNode402
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from ..bus import open_bus
from ..virtual_bus import attach_inline, data_frame
from ..cia import (COMMUNICATION_CYCLE_PERIOD, CW_ENABLE_OPERATION as _CW_ENABLE_OPERATION, MAX_SYNC_COUNTER,
                   MEASURED_DRIVE_OBJECTS as _DRIVE_INPUTS, MEASURED_ENCODER_OBJECTS as _ENCODER_INPUTS,
                   MODE_CST as _MODE_CST, SYNC_COUNTER_OVERFLOW, supported_mode_bit, valid_sync_counter)
from ..layout import DRIVE_NODE_IDS, ENCODER_NODE_IDS
from ..pdo_codec import PdoCodec, build_codec, encode_entry
from ..tools.dbc import reset_value
from ..tools.recorder import BusRecorder
from . import dcf
from .errors import CommunicationError

logger = logging.getLogger(__name__)

_CST_SUPPORTED = supported_mode_bit(_MODE_CST)
#: Times an SDO request is repeated when no response comes (a frame lost on the bus), as masters do.
SDO_RETRIES = 3


class RecordingNetwork(canopen.Network):
    """canopen Network that hands every frame it sends to a :class:`BusRecorder`."""

    recorder: BusRecorder | None = None

    def send_message(self, can_id: int, data, remote: bool = False) -> None:
        if not self.bus:
            raise RuntimeError("Not connected to CAN bus")
        send_frame = getattr(self.bus, "send_frame", None)      # the in-process bus's frame lane
        if send_frame is not None and can_id <= 0x7FF and not remote and len(data) <= 8:
            data = bytes(data)
            if self.recorder is not None:
                self.recorder.on_transmit_frame(can_id, data)
            with self.send_lock:
                send_frame(can_id, data)
            self.check()
            return
        msg = data_frame(can_id, data) if can_id <= 0x7FF and not remote and len(data) <= 8 else \
            can.Message(arbitration_id=can_id, data=data, is_extended_id=can_id > 0x7FF, is_remote_frame=remote)
        if self.recorder is not None:          # before sending: an in-process bus may deliver the
            self.recorder.on_transmit(msg)      # answers inline, and they must follow the request in the log
        with self.send_lock:
            self.bus.send(msg)
        self.check()



class ClientConfiguration:
    """Connect-time configuration of :class:`~.client.VehicleClient` (mixed in)."""

    def _open(self) -> None:
        self._bus = open_bus(self._bus_arg) if isinstance(self._bus_arg, str) else self._bus_arg
        network = RecordingNetwork(self._bus)
        network.NOTIFIER_CYCLE = 0.05
        if self.record is not None:
            self._recorder = BusRecorder(self.record)
            network.recorder = self._recorder
            network.listeners.append(self._recorder)
        self.drives = [BaseNode402(i, self._drive_eds) for i in DRIVE_NODE_IDS]
        self.encoders = [canopen.RemoteNode(i, self._encoder_eds) for i in ENCODER_NODE_IDS]
        for node in self.drives + self.encoders:
            node.sdo.MAX_RETRIES = SDO_RETRIES          # a lost request or response is sent again
        for node in self.drives + self.encoders:
            network.add_node(node)
        self._network = network
        network.connect()
        attach_inline(network)

    def _boot(self) -> None:
        booted: set[int] = set()
        condition = threading.Condition()

        def watcher(node_id):
            def on_heartbeat(state):
                if state == 0:
                    with condition:
                        booted.add(node_id)
                        condition.notify_all()
            return on_heartbeat

        nodes = self.drives + self.encoders
        for node in nodes:
            node.nmt.add_heartbeat_callback(watcher(node.id))
        for node in nodes:
            node.nmt.send_command(0x82)                  # reset communication
        with condition:
            condition.wait_for(lambda: len(booted) == len(nodes), self.boot_timeout)
        missing = sorted({n.id for n in nodes} - booted)
        if missing:
            raise CommunicationError(f"no boot-up from node(s) {missing} within {self.boot_timeout} s "
                                     f"after NMT reset communication")
        self._booted = True

    def _configure(self) -> None:
        period_us = int(round(self.cycle_time * 1e6))
        for node in self.drives + self.encoders:
            if node.id in self._concise_dcf:
                dcf.apply(node, self._concise_dcf[node.id])       # CiA 302: the manager's 0x1F22 first
        self._configure_sync_counter()
        for node in self.drives + self.encoders:
            if 0x1006 in node.object_dictionary:
                self._write(node, 0x1006, period_us)
            try:
                if self._configure_pdos:
                    node.pdo.read(from_od=True)
                    node.pdo.save()
                else:
                    node.pdo.read()
            except (SdoAbortedError, SdoCommunicationError) as exc:
                raise CommunicationError(f"node {node.id}: PDO configuration failed: {exc}") from exc
            for pdo in list(node.tpdo.map.values()) + list(node.rpdo.map.values()):
                # The cycle decodes TPDOs itself; canopen's per-frame handlers would only cost time.
                if pdo.cob_id in self._network.subscribers and \
                        pdo.on_message in self._network.subscribers[pdo.cob_id]:
                    self._network.unsubscribe(pdo.cob_id, pdo.on_message)
        for i, node in enumerate(self.drives):
            rated = self._read(node, 0x6076)
            if rated <= 0:
                raise CommunicationError(f"drive {node.id}: motor rated torque 0x6076 = {rated}")
            self.rated_torque[i] = rated * 1e-3
            self.max_torque[i] = self._read(node, 0x6072) * rated * 1e-6
            if not self._read(node, 0x6502) & _CST_SUPPORTED:
                raise CommunicationError(f"drive {node.id}: cyclic synchronous torque not in 0x6502")
            self._write(node, 0x6071, 0)
            self._write(node, 0x6060, _MODE_CST)
            mode = self._read(node, 0x6061)
            if mode != _MODE_CST:
                raise CommunicationError(f"drive {node.id}: mode display 0x6061 = {mode} after setting "
                                         f"0x6060 = {_MODE_CST}")
        for node in self.encoders:
            if 0x6001 in node.object_dictionary:
                units = self._read(node, 0x6001)
                if units != 1 << self.steering_sensor_bits:
                    logger.warning("encoder %d: 0x6001 = %d measuring units per revolution, data sheet "
                                   "says %d bits", node.id, units, self.steering_sensor_bits)
        self._per_mille_per_nm = 1000.0 / self.rated_torque
        self._max_per_mille = np.minimum(np.rint(self.max_torque * self._per_mille_per_nm), 32767)
        self._per_mille_scale = self._per_mille_per_nm.tolist()
        self._per_mille_limit = self._max_per_mille.tolist()
        self._plan_cycle()

    def _configure_sync_counter(self) -> None:
        """The SYNC's counter (CiA 301 §7.2.5, object 0x1019): a SYNC consumer expects a 1-byte counter
        where its 0x1019 is 2…240 and no data where it is 0, so every node gets one value. It is the
        EDS/DCF's (``configure_pdos``) or the devices' own; a node without 0x1019 makes it 0 for all.
        The counter lets a log's reader count lost SYNCs exactly (:mod:`qomni.hil.master.decode`). 0x1019
        may change only while 0x1006 is 0 (CiA 301), so 0x1006 is cleared first where it must change;
        :meth:`_configure` writes it afterwards.

        Raises: CommunicationError: the nodes hold different counters (read from the devices), the files
            give one outside 0, 2…240, or an SDO fails."""
        nodes = self.drives + self.encoders
        if any(SYNC_COUNTER_OVERFLOW not in node.object_dictionary for node in nodes):
            wanted = {0}
        elif self._configure_pdos:
            wanted = {reset_value(node.object_dictionary[SYNC_COUNTER_OVERFLOW]) for node in nodes}
        else:
            wanted = {self._read(node, SYNC_COUNTER_OVERFLOW) for node in nodes}
        if len(wanted) != 1 or not valid_sync_counter(next(iter(wanted))):
            raise CommunicationError(f"synchronous counter overflow value 0x1019: the nodes' files or the "
                                     f"devices give {sorted(wanted)}; the SYNC takes one counter for every "
                                     f"node, 0 (none) or 2…{MAX_SYNC_COUNTER}")
        overflow = wanted.pop()
        for node in nodes:
            if SYNC_COUNTER_OVERFLOW in node.object_dictionary and \
                    self._read(node, SYNC_COUNTER_OVERFLOW) != overflow:
                if COMMUNICATION_CYCLE_PERIOD in node.object_dictionary:
                    self._write(node, COMMUNICATION_CYCLE_PERIOD, 0)
                self._write(node, SYNC_COUNTER_OVERFLOW, overflow)
        self.sync_counter_overflow = overflow
        self._sync_data = [bytes((k,)) for k in range(1, overflow + 1)] if overflow else [b""]

    def _plan_cycle(self) -> None:
        """Compile the RPDOs to send and the TPDOs to await from the configured PDO maps."""
        self._rpdo_plan: list[tuple[int, PdoCodec, int, list]] = []
        for i, node in enumerate(self.drives):
            has_torque = False
            for pdo in node.rpdo.map.values():
                if not pdo.enabled or not pdo.map:
                    continue
                codec = _codec(node, pdo, receive=True)
                slots = []
                for key in codec.keys:
                    if key == (0x6071, 0):
                        slots.append(None)
                        has_torque = True
                    elif key == (0x6040, 0):
                        slots.append(_CW_ENABLE_OPERATION)
                    elif key == (0x6060, 0):
                        slots.append(_MODE_CST)
                    else:
                        raise CommunicationError(f"drive {node.id}: RPDO {pdo.cob_id:#x} maps "
                                                 f"0x{key[0]:04X}:{key[1]:02X}, the master has no value for it")
                self._rpdo_plan.append((pdo.cob_id, codec, i, slots))
            if not has_torque:
                raise CommunicationError(f"drive {node.id}: target torque 0x6071 is in no enabled RPDO")
        self._tpdo_plan: dict[int, tuple[PdoCodec, list]] = {}
        for nodes, inputs in ((self.drives, _DRIVE_INPUTS), (self.encoders, _ENCODER_INPUTS)):
            for i, node in enumerate(nodes):
                found = set()
                for pdo in node.tpdo.map.values():
                    if not pdo.enabled or not pdo.map:
                        continue
                    if pdo.trans_type != 1:
                        logger.warning("node %d: TPDO %#x has transmission type %s, not awaited each "
                                       "SYNC; its data are not used", node.id, pdo.cob_id, pdo.trans_type)
                        continue
                    codec = _codec(node, pdo, receive=False)
                    sinks = [(inputs[k], i) if k in inputs else None for k in codec.keys]
                    found.update(k for k in codec.keys if k in inputs)
                    self._tpdo_plan[pdo.cob_id] = (codec, sinks)
                needed = set(inputs) - {(0x6041, 0)} - found
                if needed:
                    raise CommunicationError(
                        f"node {node.id}: {', '.join(f'0x{k[0]:04X}' for k in sorted(needed))} not in a "
                        f"synchronous TPDO (transmission type 1)")
        self._expected = len(self._tpdo_plan)


def _codec(node, pdo, receive: bool) -> PdoCodec:
    entries = [encode_entry(var.index, var.subindex, var.length) for var in pdo.map]
    try:
        return build_codec(node.object_dictionary, entries, receive)
    except ValueError as exc:
        raise CommunicationError(f"node {node.id}: PDO {pdo.cob_id:#x}: {exc}") from exc
