"""HIL benchmarks, one command: ``python benchmarks/hil.py [--quick]``.

Measured in the same run, each against a baseline measured alongside:
1. lock-step campaign (quick or full) against the embedded emulator over CANopen vs. real time;
2. real-time mode (``qomni emulate --realtime`` in its own process, behind the socketcand hub) driven by
   a real-timed raw master (4 RPDOs + SYNC every T_s by its own clock) for 60 s (``--quick``: 10 s):
   SYNC-to-last-TPDO latency median/p99/max and late cycles (> T_s/2), against the same master and hub
   with an echo responder that answers each SYNC with the same 10 frames and does nothing else (the
   floor of Python + loopback TCP on this machine);
3. bus load of the active mapping (shipped EDS files) at 1 Mbit/s and 500 kbit/s, worst-case bit
   stuffing, against the bus capacity.
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import logging
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import can

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from qomni.hil.tools.busload import bus_load  # noqa: E402
from qomni.hil.tools.hub import Hub, hub_bus_spec  # noqa: E402
from qomni.hil.device.server import TimingStats  # noqa: E402

T_S = 0.002
QOMNI = [sys.executable, "-c", "from qomni.cli import main; main()"]
TPDO_IDS = {0x181, 0x182, 0x183, 0x184, 0x281, 0x282, 0x283, 0x284, 0x185, 0x186}


def lockstep_campaign(quick: bool) -> tuple[float, float]:
    """(emulated s, wall s) of the lock-step campaign (benchmarks/run.py's measurement)."""
    spec = importlib.util.spec_from_file_location("qomni_bench_run", ROOT / "benchmarks" / "run.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    from qomni.emulator.description import VehicleDescription

    return module.campaign(VehicleDescription.load(), quick)


# ------------------------------------------------------------------ real-time master and echo responder
def echo_responder(bus_spec: str, stats_path: str) -> None:
    """Baseline device: answer every SYNC with the emulator's 10 TPDO frames at once; SIGINT ends it."""
    from qomni.hil.bus import open_bus

    bus = open_bus(bus_spec)
    stats = TimingStats(T_S, T_S / 2)
    frames = [can.Message(arbitration_id=i, data=bytes(6 if i < 0x185 or i >= 0x281 else 4),
                          is_extended_id=False) for i in sorted(TPDO_IDS)]
    print("emulating (echo responder)", flush=True)
    try:
        while True:
            msg = bus.recv(0.1)
            if msg is None or msg.arbitration_id != 0x80:
                continue
            for frame in frames:
                bus.send(frame)
            latency = time.time() - msg.timestamp
            stats.record(latency if 0 <= latency < 10 else 0.0)
    except KeyboardInterrupt:
        pass
    finally:
        bus.shutdown()
        Path(stats_path).write_text(json.dumps(stats.summary()))


def run_master(spec: str, duration: float) -> dict:
    """Raw real-timed master: NMT reset communication + start, then 4 RPDOs and SYNC every T_s for
    ``duration`` s, deadline-paced. Returns its own counts: SYNCs sent, SYNC sends late by > T_s/2, and
    cycles whose 10 TPDOs were not all in before the next SYNC."""
    from qomni.hil.bus import open_bus

    bus = open_bus(spec)
    received: dict[int, set] = {}
    cycle = [0]
    stop = threading.Event()

    def receive():
        while not stop.is_set():
            msg = bus.recv(0.05)
            if msg is not None and msg.arbitration_id in TPDO_IDS:
                received.setdefault(cycle[0], set()).add(msg.arbitration_id)

    reader = threading.Thread(target=receive, daemon=True)
    reader.start()
    bus.send(can.Message(arbitration_id=0, data=[0x82, 0], is_extended_id=False))
    time.sleep(0.5)
    bus.send(can.Message(arbitration_id=0, data=[0x01, 0], is_extended_id=False))
    time.sleep(0.1)
    rpdos = [can.Message(arbitration_id=0x200 + i, data=bytes(4), is_extended_id=False) for i in (1, 2, 3, 4)]
    sync = can.Message(arbitration_id=0x80, data=b"", is_extended_id=False)
    n = int(duration / T_S)
    late_send = 0
    start = time.perf_counter()
    for k in range(n):
        due = start + k * T_S
        delay = due - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
        elif -delay > T_S / 2:
            late_send += 1
        for msg in rpdos:
            bus.send(msg)
        cycle[0] = k
        bus.send(sync)
    time.sleep(0.05)
    stop.set()
    reader.join()
    bus.shutdown()
    incomplete = sum(1 for k in range(n) if len(received.get(k, ())) < len(TPDO_IDS))
    return {"syncs": n, "late_sends": late_send, "incomplete_cycles": incomplete}


def realtime_run(device: str, duration: float) -> tuple[dict, dict]:
    """(device stats, master counts) of one real-time run against ``device`` ('emulator' or 'echo')."""
    with Hub() as hub, tempfile.TemporaryDirectory() as tmp:
        spec = hub_bus_spec(hub.port)
        stats_path = Path(tmp) / "stats.json"
        if device == "emulator":
            cmd = [*QOMNI, "emulate", "--realtime", "--bus", spec, "--stats", str(stats_path),
                   "--sync-timeout", "1.0"]
        else:
            cmd = [sys.executable, __file__, "--echo", spec, "--stats", str(stats_path)]
        process = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                   cwd=ROOT)
        try:
            for line in process.stdout:
                if "emulating" in line:
                    break
            else:
                raise RuntimeError(f"{device} did not start")
            master = run_master(spec, duration)
        finally:
            process.send_signal(signal.SIGINT)
            process.communicate(timeout=60)
        return json.loads(stats_path.read_text()), master


def _us(x) -> str:
    return "-" if x is None else f"{x * 1e6:7.0f} µs"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="10 s real-time runs and the quick campaign")
    parser.add_argument("--echo", metavar="SPEC", help=argparse.SUPPRESS)
    parser.add_argument("--stats", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.echo:
        echo_responder(args.echo, args.stats)
        return
    duration = 10.0 if args.quick else 60.0
    for noisy in ("can", "asyncio", "hil", "canopen"):      # closed-connection chatter at the end of runs
        logging.getLogger(noisy).setLevel(logging.CRITICAL)
    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} at start")

    load = {rate: bus_load(rate, T_S) for rate in (1_000_000, 500_000)}
    print("\nbus load of the active mapping (worst-case stuffing; capacity = 1.00)")
    for rate, result in load.items():
        print(f"  {rate / 1e3:6.0f} kbit/s: {result.bits_per_cycle:7.1f} bit per {T_S * 1e3:g} ms cycle "
              f"= {result.load:5.2f} × capacity ({len(result.frames)} message kinds)")

    echo, echo_master = realtime_run("echo", duration)
    emu, emu_master = realtime_run("emulator", duration)
    print(f"\nreal time, {duration:g} s at {1 / T_S:g} Hz, master + hub in one process, device in another")
    print(f"  {'':30s} {'echo (baseline)':>16s} {'emulator':>16s} {'ratio':>8s}")
    for key, label in (("latency_median", "SYNC→last TPDO median"), ("latency_p99", "SYNC→last TPDO p99"),
                       ("latency_max", "SYNC→last TPDO max")):
        ratio = emu[key] / echo[key] if echo[key] else float("nan")
        print(f"  {label:30s} {_us(echo[key]):>16s} {_us(emu[key]):>16s} {ratio:8.2f}")
    for stats, master in ((echo, echo_master), (emu, emu_master)):
        stats["master"] = master
    print(f"  {'late cycles (> T_s/2)':30s} {100 * echo['late_fraction']:15.2f}% {100 * emu['late_fraction']:15.2f}%")
    print(f"  {'cycles answered incompletely':30s} "
          f"{100 * echo_master['incomplete_cycles'] / echo_master['syncs']:15.2f}% "
          f"{100 * emu_master['incomplete_cycles'] / emu_master['syncs']:15.2f}%   (master's view, next SYNC)")
    print(f"  {'master SYNC sends > T_s/2 late':30s} "
          f"{100 * echo_master['late_sends'] / echo_master['syncs']:15.2f}% "
          f"{100 * emu_master['late_sends'] / emu_master['syncs']:15.2f}%")
    if emu.get("physics_ticks"):
        print(f"  {'physics ticks > 1 cycle late':30s} {'':>16s} "
              f"{100 * emu['physics_late'] / emu['physics_ticks']:15.2f}%")

    emulated, wall = lockstep_campaign(args.quick)
    print(f"\nlock-step campaign ({'quick' if args.quick else 'full'}): {emulated:.1f} s emulated in {wall:.1f} s "
          f"wall = {emulated / wall:.2f} × real time (baseline 1.00)")
    print(f"load average at the end {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
