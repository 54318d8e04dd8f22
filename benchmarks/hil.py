"""HIL benchmarks, one command: ``python benchmarks/hil.py [--quick]``.

Measured in the same run, each against a baseline measured alongside:
1. real-time mode: ``qomni emulate --realtime``, the socketcand hub (``python -m qomni.hil.tools.hub``)
   and a real-timed lean master (one thread, raw socketcand over TCP: 4 RPDOs + SYNC every T_s at
   absolute monotonic deadlines), each a process of its own, for 60 s (``--quick``: 10 s):
   SYNC-to-last-TPDO latency median/p99/max and late cycles (> T_s/2), seen by the device (SYNC's hub
   time stamp → last TPDO handed to its socket) and by the master (SYNC written → 10th TPDO read),
   against the same master and hub with an echo responder (python-can's socketcand client, like the
   emulator) that answers each SYNC with the same 10 frames and does nothing else: the floor of Python
   + loopback TCP on this machine. ``--pin 0:1`` pins hub + master and the device to CPU lists;
   ``--busy-poll S`` makes hub, device and master poll their sockets for up to S s before blocking
   (:mod:`qomni.hil.busy_poll`). The emulator runs twice: physics in the bus' process, and in a process
   of its own (``--plant-process``). ``--realtime-only`` stops after these runs;
2. the lock-step CANopen cycle against the bare PyBullet physics of a cycle, and the lock-step campaign
   (quick or full) against real time, each with the emulator in the bus' process and in its own;
3. bus load of the active mapping (shipped EDS files) at 1 Mbit/s and 500 kbit/s, worst-case bit
   stuffing, against the bus capacity;
4. a frame's one-way time through the hub process (ping-pong of two raw socketcand clients) against a
   bare relay process that copies bytes between two sockets (:func:`bare_relay`).
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import logging
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import can

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from qomni.hil.busy_poll import poll_select  # noqa: E402
from qomni.hil.tools.busload import bus_load  # noqa: E402
from qomni.hil.tools.hub import LOOPBACK, hub_bus_spec  # noqa: E402
from qomni.hil.device.server import TimingStats  # noqa: E402

T_S = 0.002
QOMNI = [sys.executable, "-c", "from qomni.cli import main; main()"]
TPDO_IDS = {0x181, 0x182, 0x183, 0x184, 0x281, 0x282, 0x283, 0x284, 0x185, 0x186}


def _bench_run_module():
    """benchmarks/run.py as a module (its measurements are reused here)."""
    spec = importlib.util.spec_from_file_location("qomni_bench_run", ROOT / "benchmarks" / "run.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def lockstep_campaign(quick: bool, plant_process: bool = False) -> tuple[float, float]:
    """(emulated s, wall s) of the lock-step campaign (benchmarks/run.py's measurement)."""
    from qomni.emulator.description import VehicleDescription

    return _bench_run_module().campaign(VehicleDescription.load(), quick, plant_process)[:2]


# ------------------------------------------------------------------ real-time master and echo responder
def echo_responder(bus_spec: str, stats_path: str, busy: float = 0.0) -> None:
    """Baseline device: answer every SYNC with the emulator's 10 TPDO frames at once; SIGINT ends it."""
    from qomni.hil.bus import open_bus

    bus = open_bus(bus_spec, busy_poll=busy)
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


def raw_master(port: int, duration: float, out: str, busy: float = 0.0) -> None:
    """The real-timed master as its own lean process: one thread, one TCP connection to the hub speaking
    socketcand directly (no python-can client, no receive thread). NMT reset communication + start, then
    every T_s at absolute monotonic deadlines one write of 4 RPDOs + SYNC; between deadlines it reads the
    TPDOs. Writes to ``out`` its counts and its own view of the latency: SYNC written → 10th TPDO read."""
    sock = socket.create_connection((LOOPBACK, port))
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    buffer = bytearray()

    def element() -> bytes:
        while (end := buffer.find(b">")) < 0:
            buffer.extend(sock.recv(4096))
        item = bytes(buffer[:end + 1])
        del buffer[:end + 1]
        return item

    assert element() == b"< hi >"
    for command in (b"< open can0 >", b"< rawmode >"):
        sock.sendall(command)
        assert element() == b"< ok >", command
    sock.sendall(b"< send 000 2 82 00 >")                   # NMT reset communication, all nodes
    time.sleep(0.5)
    sock.sendall(b"< send 000 2 01 00 >")                   # NMT start
    time.sleep(0.1)
    sock.setblocking(False)
    try:
        while sock.recv(65536):
            pass
    except BlockingIOError:
        pass
    buffer.clear()
    cycle_frames = b"".join(f"< send {0x200 + i:03X} 4 00 00 00 00 >".encode() for i in (1, 2, 3, 4)) \
        + b"< send 080 0 >"
    tpdo_tokens = {f"{i:03X}".encode() for i in TPDO_IDS}
    stats = TimingStats(T_S, T_S / 2)
    n = int(duration / T_S)
    late_send = incomplete = 0
    got, sync_sent = set(), None
    start = time.monotonic() + T_S
    for k in range(n + 1):
        due = start + k * T_S
        while True:                                           # read TPDOs until the next deadline
            wait = due - time.monotonic()
            if wait <= 0:
                break
            if poll_select([sock], wait, busy):
                try:
                    buffer.extend(sock.recv(65536))
                except BlockingIOError:
                    continue
                now = time.monotonic()
                while (end := buffer.find(b">")) >= 0:
                    words = bytes(buffer[:end]).split()
                    del buffer[:end + 1]
                    if len(words) > 2 and words[1] == b"frame" and words[2] in tpdo_tokens:
                        got.add(words[2])
                if sync_sent is not None and len(got) == len(TPDO_IDS):
                    stats.record(now - sync_sent)
                    sync_sent = None
        if k == n:
            break
        if sync_sent is not None:                             # previous SYNC not answered in full
            incomplete += 1
            stats.record(T_S)
        if time.monotonic() - due > T_S / 2:
            late_send += 1
        got = set()
        sock.sendall(cycle_frames)
        sync_sent = time.monotonic()
    sock.close()
    summary = stats.summary()
    summary.update(syncs=n, late_sends=late_send, incomplete_cycles=incomplete)
    Path(out).write_text(json.dumps(summary))


def _raw_client(port: int) -> socket.socket:
    """A raw socketcand connection to the hub on 127.0.0.1:``port``, channel can0, raw mode."""
    sock = socket.create_connection((LOOPBACK, port))
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    sock.sendall(b"< open can0 >< rawmode >")
    seen = b""
    while seen.count(b">") < 3:                              # < hi > < ok > < ok >
        seen += sock.recv(4096)
    return sock


def _ping_pong(a: socket.socket, b: socket.socket, send: bytes, rounds: int) -> float:
    """Median one-way time [s] of ``send`` from a to b and back, ``rounds`` round trips."""
    times = []
    for _ in range(rounds):
        t = time.perf_counter()
        a.sendall(send)
        while b">" not in b.recv(4096):
            pass
        b.sendall(send)
        while b">" not in a.recv(4096):
            pass
        times.append((time.perf_counter() - t) / 2)
    times.sort()
    return times[len(times) // 2]


def bare_relay() -> None:
    """Baseline for the hub: a process that accepts two loopback TCP connections and copies whatever one
    sends to the other, verbatim (one blocking ``select`` loop, no parsing): the cost of a process in
    the path (two wake-ups, two socket reads and writes), which any hub pays. Announces its port on
    stdout as the hub does."""
    import select

    server = socket.create_server((LOOPBACK, 0))
    print(f"relay listening on {LOOPBACK}:{server.getsockname()[1]};", flush=True)
    a, _ = server.accept()
    b, _ = server.accept()
    other = {a: b, b: a}
    for sock in other:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    while True:
        for sock in select.select([a, b], [], [])[0]:
            data = sock.recv(65536)
            if not data:
                return
            other[sock].sendall(data)


def _listening_port(line: str) -> int:
    """The port in a ``… listening on 127.0.0.1:PORT; …`` line of the hub or the relay."""
    return int(line.split(f"{LOOPBACK}:")[1].split(";")[0])


def _relay_forward(rounds: int) -> float:
    """One-way time [s] of a frame through :func:`bare_relay` in a process of its own."""
    relay, line = _start([sys.executable, __file__, "--relay"], "relay listening")
    try:
        a = socket.create_connection((LOOPBACK, _listening_port(line)))
        b = socket.create_connection((LOOPBACK, _listening_port(line)))
        for sock in (a, b):
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        one_way = _ping_pong(a, b, b"< frame 181 1.000000 010203040506 >", rounds)
        a.close()
        b.close()
    finally:
        _stop(relay)
    return one_way


def hub_forward(rounds: int = 2000) -> tuple[float, float, float]:
    """(one-way frame time through the hub process, through a bare relay process (:func:`bare_relay`),
    over a direct loopback TCP connection in this process) [s], medians of ping-pong round trips."""
    hub, line = _start([sys.executable, "-m", "qomni.hil.tools.hub", "--port", "0"], "hub listening")
    try:
        port = _listening_port(line)
        a, b = _raw_client(port), _raw_client(port)
        time.sleep(0.1)                                       # the hub's raw-mode grace period
        through_hub = _ping_pong(a, b, b"< send 181 6 01 02 03 04 05 06 >", rounds)
        a.close()
        b.close()
    finally:
        _stop(hub)
    server = socket.create_server((LOOPBACK, 0))
    a = socket.create_connection(server.getsockname())
    b, _ = server.accept()
    for sock in (a, b):
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    direct = _ping_pong(a, b, b"< frame 181 1.000000 010203040506 >", rounds)
    for sock in (a, b, server):
        sock.close()
    return through_hub, _relay_forward(rounds), direct


#: SCHED_FIFO priority of hub, master and device (``--rt-priority``), None: normal scheduling.
RT_PRIORITY: int | None = None


def _interruptible() -> None:
    """In the child before exec: SIGINT as default (a benchmark started in the background inherits it
    ignored, and then SIGINT could not stop hub and device, which write their statistics on it), and
    SCHED_FIFO at :data:`RT_PRIORITY` if asked (refused silently: the run's header says whether it held)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    if RT_PRIORITY is not None:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(RT_PRIORITY))
        except OSError:
            pass


def _start(cmd: list[str], ready: str, cpus: str | None = None) -> tuple[subprocess.Popen, str]:
    """Start a process, return it with its first output line containing ``ready``."""
    if cpus:
        cmd = ["taskset", "-c", cpus, *cmd]
    process = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=ROOT,
                               preexec_fn=_interruptible)
    lines = []
    for line in process.stdout:
        lines.append(line)
        if ready in line:
            return process, line
    process.kill()
    raise RuntimeError(f"{cmd[:4]}… did not start:\n{''.join(lines)}")


def _stop(process: subprocess.Popen) -> None:
    process.send_signal(signal.SIGINT)
    try:
        process.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        process.kill()
        process.communicate()


def realtime_run(device: str, duration: float, pin: tuple[str, str] | None,
                 busy: float = 0.0) -> tuple[dict, dict]:
    """(device stats, master's view) of one real-time run against ``device`` ('emulator',
    'emulator-process' (its physics in a process of its own) or 'echo'): the
    hub, the device and the master each a process of its own (``pin``: CPU lists of hub + master and
    of the device)."""
    master_cpus, device_cpus = pin or (None, None)
    hub, line = _start([sys.executable, "-m", "qomni.hil.tools.hub", "--port", "0", "--busy-poll", str(busy)],
                       "hub listening", master_cpus)
    port = _listening_port(line)
    spec = hub_bus_spec(port)
    poll = ["--busy-poll", str(busy)] if busy else []
    with tempfile.TemporaryDirectory() as tmp:
        stats_path, master_path = Path(tmp) / "stats.json", Path(tmp) / "master.json"
        if device.startswith("emulator"):
            cmd = [*QOMNI, "emulate", "--realtime", "--bus", spec, "--stats", str(stats_path),
                   "--sync-timeout", "1.0"] + (["--cpus", device_cpus] if device_cpus else []) \
                + (["--plant-process"] if device == "emulator-process" else []) + poll
        else:
            cmd = [sys.executable, __file__, "--echo", spec, "--stats", str(stats_path)] + poll
        try:
            process, _ = _start(cmd, "emulating", None if device.startswith("emulator") else device_cpus)
            try:
                master = [sys.executable, __file__, "--master", str(port), "--duration", str(duration),
                          "--stats", str(master_path)] + poll
                subprocess.run(["taskset", "-c", master_cpus, *master] if master_cpus else master,
                               check=True, cwd=ROOT, preexec_fn=_interruptible)
            finally:
                _stop(process)
        finally:
            _stop(hub)
        return json.loads(stats_path.read_text()), json.loads(master_path.read_text())


def _us(x) -> str:
    return "-" if x is None else f"{x * 1e6:7.0f} µs"


def _pct(x: float) -> str:
    return f"{100 * x:14.2f} %"


def _ratio(a, b) -> str:
    return f"{a / b:8.2f}" if a is not None and b else "       -"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="10 s real-time runs and the quick campaign")
    parser.add_argument("--pin", metavar="MASTER_CPUS:DEVICE_CPUS",
                        help="pin hub + master and the device to CPU lists, e.g. 0:1 or 2,3:4,5")
    parser.add_argument("--rt-priority", type=int, metavar="N",
                        help="run hub, master and device under SCHED_FIFO at priority N (root or CAP_SYS_NICE)")
    parser.add_argument("--realtime-only", action="store_true",
                        help="only the real-time runs (no bus load, hub ping, lock-step or campaign)")
    parser.add_argument("--busy-poll", type=float, default=0.0, metavar="S",
                        help="hub, device and master poll their sockets for up to S s before blocking")
    parser.add_argument("--echo", metavar="SPEC", help=argparse.SUPPRESS)
    parser.add_argument("--relay", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--master", metavar="PORT", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--duration", type=float, help=argparse.SUPPRESS)
    parser.add_argument("--stats", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.echo:
        echo_responder(args.echo, args.stats, args.busy_poll)
        return
    if args.master:
        raw_master(args.master, args.duration, args.stats, args.busy_poll)
        return
    if args.relay:
        bare_relay()
        return
    pin = tuple(args.pin.split(":")) if args.pin else None
    global RT_PRIORITY
    RT_PRIORITY = args.rt_priority
    if RT_PRIORITY is not None:
        from qomni.hil.device.realtime import set_realtime_priority

        print(f"hub, master, device: {set_realtime_priority(RT_PRIORITY)} (checked in this process)")
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))        # the benchmark itself: normal
    duration = 10.0 if args.quick else 60.0
    for noisy in ("can", "asyncio", "hil", "canopen"):      # closed-connection chatter at the end of runs
        logging.getLogger(noisy).setLevel(logging.CRITICAL)
    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} at start")

    load = {rate: bus_load(rate, T_S) for rate in (1_000_000, 500_000)}
    print("\nbus load of the active mapping (worst-case stuffing; capacity = 1.00)")
    for rate, result in load.items():
        print(f"  {rate / 1e3:6.0f} kbit/s: {result.bits_per_cycle:7.1f} bit per {T_S * 1e3:g} ms cycle "
              f"= {result.load:5.2f} × capacity ({len(result.frames)} message kinds)")

    hub_time, relay, direct = hub_forward()
    print(f"\nhub: a frame from one client to another {hub_time * 1e6:.0f} µs one way; through a bare relay "
          f"process (baseline) {relay * 1e6:.0f} µs, the hub adds {(hub_time - relay) * 1e6:.0f} µs "
          f"= {hub_time / relay:.2f} ×; direct loopback TCP in one process {direct * 1e6:.0f} µs")

    busy = args.busy_poll
    echo, echo_master = realtime_run("echo", duration, pin, busy)
    emu, emu_master = realtime_run("emulator", duration, pin, busy)
    emp, emp_master = realtime_run("emulator-process", duration, pin, busy)
    print(f"\nreal time, {duration:g} s at {1 / T_S:g} Hz; hub, master and device each a process"
          + (f" (hub + master on CPU {pin[0]}, device on CPU {pin[1]})" if pin else "")
          + (f"; sockets polled for up to {busy * 1e3:g} ms before blocking" if busy else "")
          + "; ratios against the echo floor")
    print(f"  {'':36s} {'echo (baseline)':>16s} {'emulator':>16s} {'ratio':>8s} {'plant process':>16s} "
          f"{'ratio':>8s}")
    for view, e, m, p in (("device", echo, emu, emp), ("master", echo_master, emu_master, emp_master)):
        for key, label in (("latency_median", "median"), ("latency_p99", "p99"), ("latency_max", "max")):
            print(f"  {f'SYNC→last TPDO {label} ({view})':36s} {_us(e[key]):>16s} {_us(m[key]):>16s} "
                  f"{_ratio(m[key], e[key])} {_us(p[key]):>16s} {_ratio(p[key], e[key])}")
        print(f"  {f'late cycles > T_s/2 ({view})':36s} {_pct(e['late_fraction']):>16s} "
              f"{_pct(m['late_fraction']):>16s} {_ratio(m['late_fraction'], e['late_fraction'])} "
              f"{_pct(p['late_fraction']):>16s} {_ratio(p['late_fraction'], e['late_fraction'])}")
    for label, key, note in (("cycles answered incompletely", "incomplete_cycles", "   (master's view, by next SYNC)"),
                             ("master SYNC sends > T_s/2 late", "late_sends", "")):
        print(f"  {label:36s} {_pct(echo_master[key] / echo_master['syncs']):>16s} "
              f"{_pct(emu_master[key] / emu_master['syncs']):>16s} {'':8s} "
              f"{_pct(emp_master[key] / emp_master['syncs']):>16s}{note}")
    if emu.get("physics_ticks"):
        print(f"  {'physics ticks > 1 cycle late':36s} {'':>16s} "
              f"{_pct(emu['physics_late'] / emu['physics_ticks']):>16s} {'':8s} "
              f"{_pct(emp['physics_late'] / max(1, emp['physics_ticks'])):>16s}")

    if args.realtime_only:
        return
    bench = _bench_run_module()
    from qomni.emulator.description import VehicleDescription

    description = VehicleDescription.load()
    bare = bench.bare_pybullet_step(description, 2000)
    physics = bare * round(T_S / 0.001)
    cycle, _ = bench.lockstep_cycle(description, 500)
    cycle_pp, _ = bench.lockstep_cycle(description, 500, plant_process=True)
    print(f"\nbare PyBullet step {bare * 1e6:.1f} µs (baseline; physics of a cycle {physics * 1e6:.0f} µs)")
    print(f"  lock-step CANopen cycle {cycle * 1e6:.0f} µs = {cycle / physics:.2f} × bare physics of a cycle")
    print(f"  the same, emulator in a process of its own {cycle_pp * 1e6:.0f} µs = {cycle_pp / physics:.2f} × "
          f"bare physics of a cycle")
    print(f"  real time, emulator median / p99 SYNC→last TPDO (device) = {emu['latency_median'] / physics:.2f} / "
          f"{emu['latency_p99'] / physics:.2f} × bare physics of a cycle")
    emulated, wall = lockstep_campaign(args.quick)
    print(f"\nlock-step campaign ({'quick' if args.quick else 'full'}): {emulated:.1f} s emulated in {wall:.1f} s "
          f"wall = {emulated / wall:.2f} × real time (baseline 1.00)")
    emulated, wall = lockstep_campaign(args.quick, plant_process=True)
    print(f"  the same, emulator in a process of its own: {wall:.1f} s wall = {emulated / wall:.2f} × real time")
    print(f"load average at the end {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
