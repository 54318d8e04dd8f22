"""Test doubles and shared helpers of the suite: a fake plant for the CANopen server, an independent
canopen master on a virtual bus, frame builders, an example identification result and random desired
states of each motion mode. Fixtures built on them are in conftest.py."""
from __future__ import annotations

import struct
import time
from types import SimpleNamespace

import can
import canopen
import numpy as np

from qomni.conventions import P1_NAMES
from qomni.fmu import codegen
from qomni.hil.layout import DRIVE_EDS, ENCODER_EDS
from qomni.ident import kinematics
from qomni.ident.result import IdentificationResult

T_S = 0.002
INCREMENTS = 65536
BITS = 14


class FakePlant:
    """Per wheel a rigid motor-side inertia (exact double integrator); constant steering angles.

    Implements the duck-typed plant interface of ``qomni.hil.device.server`` and logs every torque it is given.
    """

    def __init__(self, inertia=0.01, theta0=(0.0,) * 4, omega0=(0.0,) * 4, alpha=(0.3, -3.0)):
        self.description = SimpleNamespace(drive=SimpleNamespace(
            i_G=25.0, rated_torque=2.0, max_torque=6.0, encoder_increments=INCREMENTS,
            steering_sensor_bits=BITS, cycle_time=T_S))
        self.inertia = inertia
        self.time = 0.0
        self.theta = np.array(theta0, dtype=float)
        self.omega = np.array(omega0, dtype=float)
        self.tau = np.zeros(4)
        self.alpha = np.array(alpha, dtype=float)
        self.steps = 0
        self.torque_log: list[np.ndarray] = []

    def set_motor_torques(self, motor_torque):
        self.tau = np.array(motor_torque, dtype=float)
        self.torque_log.append(self.tau.copy())

    def step(self, duration):
        acc = self.tau / self.inertia
        self.theta = self.theta + self.omega * duration + 0.5 * acc * duration**2
        self.omega = self.omega + acc * duration
        self.time += duration
        self.steps += 1

    def read_sensors(self):
        k = INCREMENTS / (2 * np.pi)
        return SimpleNamespace(
            time=self.time,
            motor_position=np.rint(self.theta * k).astype(np.int64),
            motor_velocity=np.rint(self.omega * k).astype(np.int64),
            motor_torque=self.tau.copy(),
            steering_position=np.rint(self.alpha / (2 * np.pi) * 2**BITS).astype(np.int64) % 2**BITS)


def wait_for(predicate, timeout=2.0):
    end = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > end:
            raise AssertionError("condition not reached in time")
        time.sleep(0.001)


class Master:
    """Independent master on its own virtual bus: canopen network + a log of every received frame."""

    def __init__(self, channel):
        self.frames: list[can.Message] = []
        self.net = canopen.Network()
        self.net.NOTIFIER_CYCLE = 0.05
        self.net.listeners.append(self.frames.append)
        self.net.connect(interface="virtual", channel=channel)
        self.drive = {i: canopen.RemoteNode(i, str(DRIVE_EDS)) for i in (1, 2, 3, 4)}
        self.encoder = {i: canopen.RemoteNode(i, str(ENCODER_EDS)) for i in (5, 6)}
        for node in [*self.drive.values(), *self.encoder.values()]:
            self.net.add_node(node)

    def send(self, cob_id, data=b""):
        self.net.send_message(cob_id, bytes(data))

    def nmt(self, command, node_id=0):
        self.send(0, bytes([command, node_id]))

    def barrier(self, node_id=5):
        """Return when the server has processed everything sent before (SDO round trip, in order)."""
        self.encoder[node_id].sdo[0x1000].raw if node_id in self.encoder else self.drive[node_id].sdo[0x1000].raw

    def cycle(self, rpdos=()):
        """Send RPDOs then SYNC, return the TPDO frames of this SYNC (after an SDO barrier)."""
        start = len(self.frames)
        for cob_id, data in rpdos:
            self.send(cob_id, data)
        self.send(0x80)
        self.barrier()
        return {m.arbitration_id: bytes(m.data) for m in self.frames[start:]
                if 0x180 <= m.arbitration_id < 0x500}

    def ids(self, start=0):
        return [m.arbitration_id for m in self.frames[start:]]

    def close(self):
        self.net.disconnect()


def rpdo1(node_id, controlword, torque):
    return 0x200 + node_id, struct.pack("<Hh", controlword, torque)


def enable_by_sdo(master, node_id):
    node = master.drive[node_id]
    node.sdo[0x6060].raw = 10
    for cw in (0x06, 0x07, 0x0F):
        node.sdo[0x6040].raw = cw
    assert node.sdo[0x6041].raw & 0x6F == 0x27


#: The prototype's p (18) (paper Table 2 and B_w), in the order of PARAMETER_NAMES.
P_VALUES = np.array([0.3342, 4.4649, 12.9458, 0.4501, 2.4820, 17.1071, 842.0684, 286.5955, 0.7316, 3.9656, 0.121])


def identification() -> IdentificationResult:
    values = dict(zip(P1_NAMES, P_VALUES[:10]))
    return IdentificationResult(values=values, std={n: 0.01 * v for n, v in values.items()}, B_w=P_VALUES[10],
                                condition_number=12.0, rows_used={}, rows_total={}, residual_rms={})


def random_states(k, n, geometry, rng):
    """Random desired states of mode k: alpha (n, 2), alpha_v (n,), sd, sdd (n, n_k)."""
    nk = codegen.N_GENERALIZED[k]
    alpha_v = np.zeros(n)
    if k == 1:
        alpha = rng.uniform(-1.5, 1.5, (n, 2))
    elif k == 2:
        alpha_v = rng.uniform(-0.95, 0.95, n) * kinematics.alpha_v_max(geometry)
        alpha = kinematics.f_icr(alpha_v, geometry)
    else:
        alpha = np.tile(kinematics.mode_alpha(k, geometry), (n, 1))
        alpha[: n // 2] += rng.normal(0, 0.01, (n // 2, 2))  # off the ideal configuration too
    sd = rng.normal(0, 1.0, (n, nk))
    sd[: n // 4] *= 0.01  # inside the tanh region (|v| ~ eps)
    sdd = rng.normal(0, 3.0, (n, nk))
    return alpha, alpha_v, sd, sdd
