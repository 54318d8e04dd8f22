"""Fuzz the emulated vehicle through the loopback hub: random frames (any 11/29-bit identifier, data or
remote, any length) from a socketcand client, then every node must still answer an SDO request.

    python benchmarks/fuzz.py [--frames 1000000] [--seed 0]

Prints the fuzz throughput against a baseline measured in the same run (the same number of one valid,
unused frame through the same path), the hub's counters and each node's answer.
"""
from __future__ import annotations

import argparse
import random
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import can  # noqa: E402
import canopen  # noqa: E402

from qomni.emulator.vehicle import Emulator  # noqa: E402
from qomni.hil.device.server import VehicleServer  # noqa: E402
from qomni.hil.layout import DRIVE_EDS, DRIVE_NODE_IDS, ENCODER_EDS, ENCODER_NODE_IDS  # noqa: E402
from qomni.hil.tools.hub import Hub, hub_bus_spec, open_hub_bus  # noqa: E402


def random_frame(rng: random.Random) -> can.Message:
    extended = rng.random() < 0.2
    remote = rng.random() < 0.05
    cob = rng.randrange(1 << 29) if extended else rng.randrange(1 << 11)
    if rng.random() < 0.3:                                  # CANopen's own identifiers, often
        cob = rng.choice([0x000, 0x080, 0x081, 0x201, 0x301, 0x601, 0x602, 0x605, 0x701, 0x7E5])
    length = rng.randrange(9)
    data = b"" if remote else bytes(rng.randrange(256) for _ in range(length))
    return can.Message(arbitration_id=cob, is_extended_id=extended, is_remote_frame=remote, data=data,
                       dlc=length)


def blast(port: int, frames: list[can.Message]) -> float:
    """Send ``frames`` through the hub; seconds taken."""
    with open_hub_bus(port) as bus:
        start = time.perf_counter()
        for msg in frames:
            bus.send(msg)
        return time.perf_counter() - start


def nodes_answer(port: int) -> dict[int, str]:
    network = canopen.Network()
    network.connect(interface="socketcand", host="127.0.0.1", port=port, channel="can0")
    out = {}
    try:
        for node_id in (*DRIVE_NODE_IDS, *ENCODER_NODE_IDS):
            node = network.add_node(node_id, str(DRIVE_EDS if node_id in DRIVE_NODE_IDS else ENCODER_EDS))
            try:
                out[node_id] = f"0x1000 = 0x{node.sdo[0x1000].raw:08X}"
            except Exception as exc:                         # noqa: BLE001 - report, not crash
                out[node_id] = f"NO ANSWER ({type(exc).__name__}: {exc})"
    finally:
        network.disconnect()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=1_000_000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = random.Random(args.seed)
    fuzz = [random_frame(rng) for _ in range(args.frames)]
    valid = [can.Message(arbitration_id=0x77F, data=b"\x05")] * args.frames   # heartbeat of no node
    with Hub(port=0, max_clients=8) as hub, Emulator() as emulator, \
            VehicleServer(emulator, hub_bus_spec(hub.port), sync_timeout=None) as server:
        baseline = blast(hub.port, valid)
        fuzzed = blast(hub.port, fuzz)
        time.sleep(1.0)                                      # let the devices drain the hub's queue
        answers = nodes_answer(hub.port)
        kinds = {"29-bit": sum(m.is_extended_id for m in fuzz), "remote": sum(m.is_remote_frame for m in fuzz)}
        print(f"frames sent: {args.frames} fuzz ({kinds['29-bit']} 29-bit, {kinds['remote']} remote) and "
              f"{args.frames} baseline")
        print(f"baseline (one valid frame): {args.frames / baseline:,.0f} frames/s")
        print(f"fuzz:                       {args.frames / fuzzed:,.0f} frames/s  "
              f"(time {fuzzed / baseline:.2f}× the baseline's)")
        print(f"hub: {hub.frames} frames forwarded, {hub.dropped} dropped for full queues, "
              f"{hub.remote_dropped} remote requests not forwarded")
        print(f"server error: {server.error!r}; frames that raised inside a node: "
              f"{server.listener.internal_errors}; physics steps from fuzzed SYNCs: {server.cycles}")
        for node_id, answer in answers.items():
            print(f"node {node_id}: {answer}")
        if server.error is not None or server.listener.internal_errors \
                or any(a.startswith("NO ANSWER") for a in answers.values()):
            raise SystemExit("a node stopped answering")


if __name__ == "__main__":
    main()
