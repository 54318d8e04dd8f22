"""LSS slave (CiA 305, layer setting services) of the emulated nodes.

Requests on COB-ID 0x7E5, responses on 0x7E4 (8 bytes, byte 0 the command specifier). The LSS address is
the identity object 0x1018:1…4 (vendor-ID, product code, revision number, serial number); an EDS serial
number of 0 is replaced by the node-ID the device is built with, so the vehicle's nodes differ.

* Switch state global (0x04) and selective (0x40…0x43 → 0x44): waiting ↔ configuration state.
* In configuration state: configure node-ID (0x11; 1…127, or 255 = not configured), configure bit
  timing (0x13; CiA 301 table index 0…8, only the rates the EDS's ``BaudRate_*`` lists), activate bit
  timing (0x15), store configuration (0x17), inquire vendor-ID/product/revision/serial (0x5A…0x5D)
  and node-ID (0x5E). Error code 1 (out of range) for an inadmissible value.
* In any state: identify remote slave (0x46…0x4B, a range of revisions and serials → 0x4F) and
  identify non-configured remote slave (0x4C → 0x50).
* Fastscan (0x51 → 0x4F), for slaves without a node-ID in waiting state: bit check 0x80 starts a scan;
  a slave answers while the bits of its LSS address above the bit checked match, and enters the
  configuration state when the last part is confirmed.

A configured node-ID takes effect at the next NMT reset communication (or reset node), or at once when
the slave returns to waiting state while it had none (CiA 305 §8.3.2); the node then boots with it
(boot-up 0x700 + id; SDO, EMCY and $NODEID-relative PDO COB-IDs follow). Without a node-ID the node
is silent on the bus except for LSS. The bit timing is recorded (:attr:`LssSlave.bit_rate`); a virtual
bus has none to change.
"""
from __future__ import annotations

import struct

from canopen import objectdictionary as od

LSS_REQUEST, LSS_RESPONSE = 0x7E5, 0x7E4
UNCONFIGURED = 0xFF
WAITING, CONFIGURATION = 0, 1
#: CiA 301 bit timing table: index → kbit/s (index 5, 100 kbit/s, is not recommended; 0x6 50 kbit/s).
BIT_TIMINGS = {0: 1000, 1: 800, 2: 500, 3: 250, 4: 125, 5: 100, 6: 50, 7: 20, 8: 10}


class LssSlave:
    """CiA 305 slave mixed into a :class:`~qomni.hil.device.node301.Node301` subclass (before it in the
    bases). Attributes: ``lss_state`` (WAITING/CONFIGURATION), ``pending_node_id``, ``bit_rate`` [kbit/s]
    active, ``stored`` (node-ID and bit rate of the last store configuration)."""

    def __init__(self, node_id, eds, **kwargs):
        super().__init__(node_id, eds, **kwargs)
        if self.values.get((0x1018, 4)) == 0:          # factory serial number: distinct on the vehicle
            self._defaults[(0x1018, 4)] = self.values[(0x1018, 4)] = node_id
        self.lss_state = WAITING
        self.pending_node_id = node_id
        info = self.object_dictionary.device_information
        self.bit_rates = {k for k, rate in BIT_TIMINGS.items() if (info.allowed_baudrates or set()) and
                          rate * 1000 in info.allowed_baudrates} or set(BIT_TIMINGS)
        self.bit_rate = None
        self._pending_bit_timing = None
        self.stored = (node_id, None)
        self._selective = []
        self._identify = []
        self._fastscan_pos = 0
        self._lss_network = None
        self._id_base = node_id            # the node-ID the $NODEID-relative defaults were computed for

    # ------------------------------------------------------- bus
    def associate_network(self, network) -> None:
        super().associate_network(network)
        if self._lss_network is not network:
            self._lss_network = network
            network.subscribe(LSS_REQUEST, self._on_lss)

    def _respond(self, data: bytes) -> None:
        self._lss_network.send_message(LSS_RESPONSE, bytes(data).ljust(8, b"\0"))

    @property
    def lss_address(self) -> tuple[int, int, int, int]:
        """(vendor-ID, product code, revision number, serial number) from 0x1018."""
        return tuple(self.values.get((0x1018, sub), 0) for sub in (1, 2, 3, 4))

    # ------------------------------------------------------- services
    def _on_lss(self, can_id, data, timestamp) -> None:
        if len(data) != 8 or not self.powered:
            return
        with self.lock:
            cs = data[0]
            value = struct.unpack_from("<I", data, 1)[0]
            if cs == 0x04:
                self._switch(data[1])
            elif 0x40 <= cs <= 0x43:
                self._switch_selective(cs - 0x40, value)
            elif 0x46 <= cs <= 0x4B:
                self._identify_remote(cs - 0x46, value)
            elif cs == 0x4C:
                if self.id == UNCONFIGURED and self.pending_node_id == UNCONFIGURED:
                    self._respond(b"\x50")
            elif cs == 0x51:
                self._fastscan(value, data[5], data[6], data[7])
            elif self.lss_state == CONFIGURATION:
                self._configure(cs, data)

    def _switch(self, mode: int) -> None:
        if mode == CONFIGURATION:
            self.lss_state = CONFIGURATION
        elif mode == WAITING and self.lss_state == CONFIGURATION:
            self.lss_state = WAITING
            if self.id == UNCONFIGURED and self.pending_node_id != UNCONFIGURED:
                self.boot(application=False)

    def _switch_selective(self, part: int, value: int) -> None:
        self._selective = self._selective[:part] if part == len(self._selective) else []
        if part != len(self._selective):
            return
        self._selective.append(value)
        if part == 3 and tuple(self._selective) == self.lss_address:
            self.lss_state = CONFIGURATION
            self._respond(b"\x44")
        if part == 3:
            self._selective = []

    def _identify_remote(self, part: int, value: int) -> None:
        if part == 0:
            self._identify = []
        if part != len(self._identify):
            self._identify = []
            return
        self._identify.append(value)
        if part == 5:
            vendor, product, rev_lo, rev_hi, ser_lo, ser_hi = self._identify
            v, p, r, s = self.lss_address
            if v == vendor and p == product and rev_lo <= r <= rev_hi and ser_lo <= s <= ser_hi:
                self._respond(b"\x4F")
            self._identify = []

    def _fastscan(self, id_number: int, bit_check: int, lss_sub: int, lss_next: int) -> None:
        if self.id != UNCONFIGURED or self.lss_state != WAITING:
            return
        if bit_check == 0x80:
            self._fastscan_pos = 0
            self._respond(b"\x4F")
            return
        if lss_sub != self._fastscan_pos or bit_check > 31 or lss_sub > 3:
            return
        mask = (0xFFFFFFFF << bit_check) & 0xFFFFFFFF
        if (self.lss_address[lss_sub] ^ id_number) & mask:
            return
        self._respond(b"\x4F")
        if bit_check == 0:
            self._fastscan_pos = lss_next
            if lss_next < lss_sub:
                self.lss_state = CONFIGURATION

    def _configure(self, cs: int, data: bytes) -> None:
        if cs == 0x11:
            ok = 1 <= data[1] <= 127 or data[1] == UNCONFIGURED
            if ok:
                self.pending_node_id = data[1]
            self._respond(bytes([0x11, 0 if ok else 1]))
        elif cs == 0x13:
            ok = data[1] == 0 and data[2] in self.bit_rates
            if ok:
                self._pending_bit_timing = data[2]
            self._respond(bytes([0x13, 0 if ok else 1]))
        elif cs == 0x15:
            if self._pending_bit_timing is not None:
                self.bit_rate = BIT_TIMINGS[self._pending_bit_timing]
        elif cs == 0x17:
            self.stored = (self.pending_node_id, self.bit_rate)
            self._respond(b"\x17\x00")
        elif 0x5A <= cs <= 0x5D:
            self._respond(struct.pack("<BI", cs, self.lss_address[cs - 0x5A]))
        elif cs == 0x5E:
            self._respond(bytes([0x5E, self.id]))

    # ------------------------------------------------------- node-ID
    def boot(self, application: bool = True) -> None:
        """NMT reset: a pending node-ID takes effect first; without one the node stays silent."""
        with self.lock:
            if self.pending_node_id != self.id:
                self._change_node_id(self.pending_node_id)
            if self.id == UNCONFIGURED:
                self.nmt.stop_heartbeat()
                self.nmt._state = 0              # INITIALISING: no boot-up, SDO, PDO or heartbeat
                return
            super().boot(application)

    def _change_node_id(self, new_id: int) -> None:
        network, old_id = self._lss_network, self.id
        if network is not None and old_id in network.nodes:
            del network[old_id]
        if new_id != UNCONFIGURED:
            for var in _variables(self.object_dictionary):
                key = (var.index, var.subindex)
                if var.relative and key in self._defaults:
                    self._defaults[key] += new_id - self._id_base
                    self.values[key] = self._defaults[key]
            self._id_base = new_id
        self.nmt.stop_heartbeat()
        self._rebind(new_id)
        if network is not None and new_id != UNCONFIGURED:
            network.add_node(self)

    def _rebind(self, new_id: int) -> None:
        """Re-create the services addressed by node-ID (SDO server, NMT slave, EMCY producer)."""
        from canopen.emcy import EmcyProducer

        self.id = new_id
        self.sdo = type(self.sdo)(0x600 + new_id, 0x580 + new_id, self)
        self.nmt = type(self.nmt)(new_id, self)
        self.emcy = EmcyProducer(0x80 + new_id)


def _variables(dictionary: od.ObjectDictionary):
    for obj in dictionary.values():
        yield from [obj] if isinstance(obj, od.ODVariable) else obj.values()
