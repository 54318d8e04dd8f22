"""``qomni emulate``, ``hub``, ``decode`` and ``replay``: the emulator for external masters, and bus logs.

The work is done in ``qomni.hil``; these commands wire it to the emulator (composition root).
"""
from __future__ import annotations

import functools
import math
import os
import time
from pathlib import Path
from typing import List, Optional

import typer
from rich.text import Text

from .app import app
from .console import console, fail
from .loaders import check_effects, load_description, load_effects, load_faults, prepare_out


BUSY_POLL_HELP = ("s each socket wait polls before it blocks (0: block at once). Against the wake-up "
                  "latency of a virtual machine's idle CPUs; costs a busy core (docs/hil.md).")


def _check_busy_poll(busy_poll: float) -> None:
    from qomni.hil.busy_poll import check_busy

    try:
        check_busy(busy_poll)
    except ValueError as exc:
        fail(f"--busy-poll: {exc}")


@app.command()
def emulate(
    bus: str = typer.Option(..., help="Bus to serve the vehicle on: 'socketcan:vcan0', "
                            "'socketcand:127.0.0.1:PORT/can0' (a 'qomni hub'), 'pcan:…'."),
    vehicle: Optional[Path] = typer.Option(None, help="Vehicle description TOML; default: the prototype."),
    realtime: bool = typer.Option(False, help="Physics paced by the wall clock (the master's SYNC only "
                                  "samples). Default: lock-step, one physics cycle per SYNC."),
    effects: Optional[Path] = typer.Option(None, help="Effects file (TOML) on top of the ideal vehicle; "
                                           "default: the prototype as described."),
    seed: int = typer.Option(0, min=0, help="Seed of the emulator's sensor noise."),
    faults: Optional[Path] = typer.Option(None, help="Fault plan (TOML, see hil/device/faults.py): frame loss, "
                                          "latency, power cycles, bus-off, SYNC loss."),
    duration: Optional[float] = typer.Option(None, help="Stop after this many seconds of wall time "
                                             "(default: until Ctrl-C)."),
    deadline: Optional[float] = typer.Option(None, help="s; a SYNC answered later counts as a late "
                                             "cycle (default T_s/2)."),
    sync_timeout: float = typer.Option(0.1, help="s without SYNC after which enabled drives fault (0x6007)."),
    lifted: bool = typer.Option(False, help="Chassis jacked up, wheels free."),
    stats: Optional[Path] = typer.Option(None, help="Also write the timing statistics as JSON here "
                                         "(latencies in s, with a latency histogram) and the histogram "
                                         "as a PNG beside it (same name, .png)."),
    cpus: Optional[str] = typer.Option(None, help="Pin the emulator to these CPUs, e.g. '2,3' or '2-3' "
                                       "(keep the master on others)."),
    rt_priority: Optional[int] = typer.Option(None, help="Run under SCHED_FIFO at this priority (1-99; "
                                              "needs root or CAP_SYS_NICE, else a note and normal priority)."),
    plant_process: bool = typer.Option(False, help="Run the physics in a process of its own (it inherits "
                                       "--cpus and --rt-priority): the bus side is never held up by a "
                                       "physics tick (docs/hil.md)."),
    busy_poll: float = typer.Option(0.0, help=BUSY_POLL_HELP + " socketcand buses only."),
):
    """Serve the emulated vehicle (4 CiA 402 drives, 2 CiA 406 encoders) to an external CANopen master."""
    from qomni.emulator.vehicle import Emulator
    from qomni.hil.bus import open_bus, parse_bus_spec
    from qomni.hil.device.server import VehicleServer

    try:
        parse_bus_spec(bus)
    except ValueError as exc:
        fail(str(exc))
    for name, value in (("--duration", duration), ("--deadline", deadline), ("--sync-timeout", sync_timeout)):
        if value is not None and not (value > 0 and math.isfinite(value)):
            fail(f"{name} must be a positive number of seconds, got {value}")
    _check_busy_poll(busy_poll)
    if stats is not None and not stats.parent.is_dir():
        fail(f"--stats {stats}: the directory {stats.parent} does not exist")
    if stats is not None and (stats.is_dir() or stats.suffix != ".json"):
        fail(f"--stats {stats}: give a .json file to write (the histogram goes beside it as .png)")
    from qomni.hil.device.realtime import RealtimeError, parse_cpus, pin_cpus, set_realtime_priority

    try:
        notes = ([] if cpus is None else [pin_cpus(parse_cpus(cpus))]) + \
            ([] if rt_priority is None else [set_realtime_priority(rt_priority)])
    except RealtimeError as exc:
        fail(str(exc))
    for note in notes:
        console.print(note)
    plan = load_faults(faults)
    description = load_description(vehicle)
    kwargs = {} if effects is None else {"effects": load_effects(effects)}
    check_effects(description, kwargs.get("effects"))
    try:
        bus_arg = open_bus(bus, busy_poll=busy_poll) if busy_poll else bus   # else the server opens it
    except Exception as exc:                                        # noqa: BLE001 - say what and where
        fail(f"cannot open bus {bus!r}: {exc}")
    factory = functools.partial(Emulator, description, seed=seed, lifted=lifted, **kwargs)
    try:
        if plant_process:
            from qomni.hil.device.plant_process import PlantProcess

            emulator = PlantProcess(factory)
        else:
            emulator = factory()
    except BaseException:
        if bus_arg is not bus:
            bus_arg.shutdown()
        raise
    server = VehicleServer(emulator, bus_arg, sync_timeout=sync_timeout, realtime=realtime, deadline=deadline,
                           faults=plan)
    try:
        try:
            server.start()
        except Exception as exc:                                    # noqa: BLE001 - say what and where
            fail(f"cannot open bus {bus!r}: {exc}")
        console.print(f"emulating '{description.name}' on {bus} ({'real time' if realtime else 'lock-step'}, "
                      f"T_s = {server.cycle_time * 1e3:g} ms): drives 1-4 (fl, rl, fr, rr), encoders 5, 6; "
                      + ("Ctrl-C stops" if duration is None else f"for {duration:g} s"))
        end = None if duration is None else time.monotonic() + duration
        try:
            while end is None or time.monotonic() < end:
                time.sleep(0.05 if end is None else max(0.0, min(0.05, end - time.monotonic())))
                if server.error is not None:
                    break
        except KeyboardInterrupt:
            pass
    finally:
        server.stop()
        emulator.close()
        if bus_arg is not bus:
            bus_arg.shutdown()
    console.print(server.stats.report())
    if stats is not None:
        from qomni.ident.rundir import write_json

        summary = dict(server.stats.summary(), realtime=realtime, bus=bus)
        if server.injector is not None:
            from dataclasses import asdict

            summary["faults"] = asdict(server.injector.counters)
        write_json(stats, summary)
        if summary["cycles"]:
            from qomni.hil.tools.timing_plot import plot_latency_histogram

            plot_latency_histogram(summary, stats.with_suffix(".png"),
                                   f"{description.name}: {summary['cycles']} SYNCs "
                                   f"({'real time' if realtime else 'lock-step'})")
    if server.injector is not None:
        c = server.injector.counters
        console.print(f"faults: frames lost rx {c.lost_rx} / tx {c.lost_tx}, SYNC dropped {c.sync_dropped}, "
                      f"dropped in bus-off {c.bus_off_dropped}, delayed {c.delayed}, power cycles "
                      f"{c.power_cycles}, bus-offs {c.bus_offs}, SYNC losses {c.sync_losses}")
    if server.error is not None:
        fail(f"the emulator stopped: {server.error}")


@app.command()
def hub(port: int = typer.Option(29536, help="TCP port on 127.0.0.1 (0 picks a free one)."),
        max_clients: int = typer.Option(16, help="Most clients connected at once."),
        busy_poll: float = typer.Option(0.0, help=BUSY_POLL_HELP)):
    """Share one CAN bus between processes where vcan does not exist: a socketcand hub on 127.0.0.1.

    Connect with --bus socketcand:127.0.0.1:PORT/can0 (python-can's socketcand interface).
    """
    from qomni.hil.tools.hub import Hub, hub_bus_spec

    if not 0 <= port <= 65535 or max_clients < 1:
        fail(f"--port must be 0…65535 and --max-clients at least 1, got {port} and {max_clients}")
    _check_busy_poll(busy_poll)
    running = Hub(port=port, max_clients=max_clients, busy_poll=busy_poll)
    try:
        running.start()
    except OSError as exc:
        fail(f"cannot listen on 127.0.0.1:{port}: {exc.strerror or exc} (another hub running? try --port 0)")
    try:
        console.print(f"hub listening on 127.0.0.1:{running.port}; bus spec "
                      f"{hub_bus_spec(running.port)}; Ctrl-C stops it")
        try:
            while True:
                time.sleep(1.0)
        except KeyboardInterrupt:
            console.print(f"hub stopped after {running.frames} frames ({running.dropped} dropped)")
    finally:
        running.stop()


@app.command()
def decode(
    log: Path = typer.Argument(..., help="Bus log: .blf, .asc, .log (candump -L), .csv, .trc, .mf4."),
    out: Path = typer.Option(..., "--out", help="Run directory to create (signals.csv, metadata.json)."),
    metadata: Optional[Path] = typer.Option(None, help="metadata.json of the recorded run: data sheet and "
                                            "campaign segments (step names), so 'qomni identify' can use it."),
    datasheet: Optional[Path] = typer.Option(None, help="Data-sheet TOML (without --metadata; default: "
                                             "the prototype's)."),
    eds_dir: Optional[Path] = typer.Option(None, help="Directory with drive402.eds / encoder406.eds and/or "
                                           "per-node *.dcf ([DeviceComissioning] NodeID)."),
    drive_eds: Optional[Path] = typer.Option(None, help="EDS/DCF of all four drives (default: hil's)."),
    encoder_eds: Optional[Path] = typer.Option(None, help="EDS/DCF of both encoders (default: hil's)."),
    dcf: Optional[List[Path]] = typer.Option(None, help="DCF of one node (repeatable)."),
    force: bool = typer.Option(False, help="Replace a decoded run already in --out."),
):
    """Decode a recorded bus log (ours or another tool's) with the EDS/DCF PDO mapping into a run directory."""

    from qomni.hil.master.decode import DecodeError, DecodeReport, decode_log, node_files
    from qomni.hil.layout import DRIVE_EDS, ENCODER_EDS
    from qomni.datasheet import DataSheet, DataSheetError
    from qomni.ident.rundir import (METADATA, RUN_FORMAT, SIGNALS, RunDirectoryError, completed_steps,
                                    datasheet_from_metadata, read_json, write_json)
    from qomni.ident.recording import SignalWriter

    if not log.is_file():
        fail(f"log file {log} does not exist")
    meta: dict = {}
    try:
        if metadata is not None:
            meta = read_json(metadata)
            sheet = datasheet_from_metadata(meta, str(metadata))
            completed_steps(meta, str(metadata))
        else:
            sheet = DataSheet.load(datasheet)
    except (OSError, ValueError, DataSheetError, RunDirectoryError) as exc:
        fail(f"{metadata or datasheet}: {exc}")
    segments = [s for s in meta.get("segments", []) if {"name", "k", "t_start", "t_end"} <= set(s)]
    prepare_out(out, (SIGNALS, METADATA), force)
    partial = out / f".{SIGNALS}.partial"
    drive = sheet.drive
    report = DecodeReport()
    try:
        files = node_files(drive_eds or DRIVE_EDS, encoder_eds or ENCODER_EDS, dcf or (), eds_dir)
        cycles = decode_log(log, encoder_increments=drive.encoder_increments,
                            steering_sensor_bits=drive.steering_sensor_bits, cycle_time=drive.cycle_time,
                            rated_torque=drive.rated_torque, files=files, report=report)
        rows, outside, eps, last = 0, 0, 1e-9, -float("inf")
        partial.unlink(missing_ok=True)
        with SignalWriter(partial) as writer:
            for cycle in cycles:
                t = cycle.measurement.time
                if t <= last:
                    raise DecodeError(f"{log}: the SYNC count restarts at {t:.3f} s after {last:.3f} s: the log "
                                      f"holds {report.sessions or 'several'} sessions (NMT start); cut it into "
                                      "one log per session, each its own run")
                last = t
                if segments:
                    seg = next((s for s in segments if s["t_start"] + eps < t <= s["t_end"] + eps), None)
                    if seg is None:
                        outside += 1
                        continue
                    name, k = seg["name"], seg["k"]
                else:
                    name, k = "recorded", 0
                writer.write(name, k, cycle.measurement, cycle.motor_torque_cmd)
                rows += 1
    except (DecodeError, FileNotFoundError) as exc:
        partial.unlink(missing_ok=True)
        fail(str(exc))
    if rows == 0:
        partial.unlink(missing_ok=True)
        fail(f"{log}: no complete SYNC cycle decoded ({report.frames} frames, {report.incomplete} "
              "incomplete cycles); wrong EDS/DCF mapping or not a log of this vehicle?")
    os.replace(partial, out / SIGNALS)
    for warning in report.warnings:
        console.print(Text.assemble(("warning:", "bold yellow"), f" {warning}"))
    if not meta:
        from dataclasses import asdict

        meta = {"format": RUN_FORMAT, "vehicle": sheet.name,
                "datasheet": {"geometry": asdict(sheet.geometry), "drive": asdict(drive),
                              "nominal": asdict(sheet.nominal)}, "segments": []}
    meta = dict(meta, source=f"decoded from {log}", decoded={
        "log": str(log), "frames": report.frames, "cycles": report.cycles, "rows": rows,
        "incomplete_cycles": report.incomplete, "sync_restored": report.sync_restored,
        "lost_cycles": report.lost_cycles, "real_time_clock": report.real_time_clock,
        "sync_counter_overflow": report.sync_counter,
        "cycles_outside_segments": outside,
        "duplicate_frames": report.duplicates, "sessions": report.sessions, "warnings": report.warnings,
        "rated_torque": {"value": report.rated_torque, "unit": "N m", "source": report.rated_torque_source},
        "mapping": {str(k): str(v) for k, v in files.items()}})
    write_json(out / METADATA, meta)
    console.print(f"decoded {report.cycles} cycles ({report.incomplete} incomplete skipped) from "
                  f"{report.frames} frames into {out / SIGNALS}: {rows} rows"
                  + (f"; {report.sync_restored} SYNC missing from the log restored where a synchronous TPDO "
                     "came again" if report.sync_restored else "")
                  + (f"; {report.lost_cycles} whole cycle(s) missing from the log (SYNC and TPDOs) where its SYNC "
                     f"{'counter' if report.sync_counter else 'clock'} skips them: the later rows keep their time"
                     if report.lost_cycles else "")
                  + (f"; {report.duplicates} frame(s) logged twice dropped" if report.duplicates else "")
                  + (f"; {outside} cycle(s) outside the segments of {metadata} left out (the log's session "
                     "before or after the campaign; a log of another campaign than the metadata's is refused "
                     "by every reader of the run where a step's steering is off its mode)" if outside else "")
                  + ("" if segments else "; no --metadata segments, so every row is step 'recorded' "
                     "(qomni identify needs the campaign's step names)")
                  + ("; the rows of the skipped cycles are missing, and every reader of the run refuses it, "
                     "naming the line" if report.incomplete or report.lost_cycles else ""))


@app.command()
def replay(
    log: Path = typer.Argument(..., help="Bus log: .blf, .asc, .log (candump -L), .csv, .trc, .mf4."),
    bus: str = typer.Option(..., help="Bus to replay onto, e.g. 'socketcan:vcan0' or "
                            "'socketcand:127.0.0.1:PORT/can0'."),
    fast: bool = typer.Option(False, help="As fast as the bus takes the frames (default: recorded timing)."),
    master_only: bool = typer.Option(False, help="Replay only the master's frames (NMT, SYNC, RPDO, SDO "
                                     "requests), e.g. to drive an emulator or a real vehicle again."),
):
    """Replay a recorded log onto a bus (python-can LogReader + MessageSync)."""
    from qomni.hil.bus import open_bus
    from qomni.hil.tools.recorder import replay as replay_log, sent_by_master

    try:
        target = open_bus(bus)
    except (ValueError, OSError) as exc:
        fail(f"cannot open bus {bus!r}: {exc}")
    except Exception as exc:                                         # noqa: BLE001 - can.CanError & co
        fail(f"cannot open bus {bus!r}: {exc}")
    started = time.perf_counter()
    try:
        sent = replay_log(log, target, realtime=not fast, only=sent_by_master if master_only else None)
    except (FileNotFoundError, ValueError) as exc:
        fail(str(exc))
    except KeyboardInterrupt:
        sent = None
    finally:
        target.shutdown()
    if sent is not None:
        console.print(f"replayed {sent} frames from {log} onto {bus} in {time.perf_counter() - started:.1f} s")


