"""Whole cycles a logger lost, counted by the decode (README, Decode).

    python benchmarks/lost_cycles.py RUN_DIR [--cycles 200] [--seed 1] [--without-counter] [--real-time]
        [--work DIR]

RUN_DIR is a campaign of the embedded emulator (``qomni campaign --out DIR``), whose ``bus.log`` (candump
-L, lock-step: wall-clock stamps) is the intact log. ``--cycles`` cycles, drawn at random, lose their SYNC
and every TPDO of their cycle; the RPDOs stay, as a logger that lost the nodes' answers and the SYNC would
leave them. Both logs are decoded with the run's data sheet and the script prints the cycles decoded, the
lost cycles counted, and whether every row of the lossy log equals the intact log's row at its time
(positions, steering angles, commanded torques); the cycle before each gap is skipped as incomplete (it
may hold two cycles' frames). ``--without-counter`` strips the SYNC counter first (a master that sends
none): a lock-step log then counts its cycles as logged. ``--real-time`` restamps the log as a real-time
master's: cycle k's frames at k·T_s plus a SYNC jitter of 50 µs (normal, σ, seeded), 10 µs apart. The
logs are written under --work (default: a temporary directory), replaced on every run.
"""
from __future__ import annotations

import argparse
import random
import re
import tempfile
from pathlib import Path

import numpy as np

from qomni.hil.master.decode import DecodeReport, decode_log
from qomni.ident.rundir import datasheet_from_metadata, read_json

TPDOS = {0x181, 0x182, 0x183, 0x184, 0x185, 0x186, 0x281, 0x282, 0x283, 0x284}


def cob_id(line: str) -> int:
    """COB-ID of a candump -L line ``(stamp) channel ID#DATA [T|R]``."""
    return int(line.split()[2].split("#")[0], 16)


def restamped(lines: list[str], period: float, rng: random.Random) -> list[str]:
    """candump -L lines stamped as a real-time master's log: the frames from SYNC k on at k·period plus a
    jitter of 50 µs (σ), 10 µs apart."""
    out, start, within = [], 1.7e9, 0
    for line in lines:
        if cob_id(line) == 0x80:
            start, within = start + period, 0
            t = start + rng.gauss(0.0, 50e-6)
        else:
            within += 1
            t = start + 1e-5 * within
        out.append(f"({t:.6f}) {line.split(' ', 1)[1]}")
    return out


def decoded(path: Path, drive) -> tuple[dict, DecodeReport]:
    """{cycle index: DecodedCycle} of a log, and its report."""
    report = DecodeReport()
    cycles = decode_log(path, encoder_increments=drive.encoder_increments,
                        steering_sensor_bits=drive.steering_sensor_bits, cycle_time=drive.cycle_time,
                        report=report)
    return {round(c.measurement.time / drive.cycle_time): c for c in cycles}, report


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--cycles", type=int, default=200)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--without-counter", action="store_true")
    parser.add_argument("--real-time", action="store_true")
    parser.add_argument("--work", type=Path)
    args = parser.parse_args()
    drive = datasheet_from_metadata(read_json(args.run / "metadata.json"), str(args.run / "metadata.json")).drive
    lines = (args.run / "bus.log").read_text().splitlines()
    if args.without_counter:
        lines = [re.sub(r" 080#[0-9A-F]{2}\b", " 080#", line) for line in lines]
    if args.real_time:
        lines = restamped(lines, drive.cycle_time, random.Random(args.seed + 1))
    syncs = [i for i, line in enumerate(lines) if cob_id(line) == 0x80]
    gone = random.Random(args.seed).sample(range(10, len(syncs) - 1), args.cycles)
    drop = set()
    for k in gone:
        drop.add(syncs[k])
        drop.update(i for i in range(syncs[k] + 1, syncs[k + 1]) if cob_id(lines[i]) in TPDOS)
    work = args.work or Path(tempfile.mkdtemp(prefix="lost_cycles_"))
    work.mkdir(parents=True, exist_ok=True)
    intact_log, lossy_log = work / "intact.log", work / "lossy.log"
    intact_log.write_text("\n".join(lines) + "\n")
    lossy_log.write_text("\n".join(line for i, line in enumerate(lines) if i not in drop) + "\n")
    intact, intact_report = decoded(intact_log, drive)
    lossy, report = decoded(lossy_log, drive)
    same = all(k in intact and np.array_equal(c.measurement.motor_position, intact[k].measurement.motor_position)
               and np.array_equal(c.measurement.alpha, intact[k].measurement.alpha)
               and np.array_equal(c.motor_torque_cmd, intact[k].motor_torque_cmd) for k, c in lossy.items())
    print(f"intact log: {intact_report.cycles} cycles, SYNC counter to {intact_report.sync_counter or 'none'}, "
          f"real-time clock {intact_report.real_time_clock}")
    print(f"lossy log, {args.cycles} whole cycles deleted: {report.cycles} cycles decoded, "
          f"{report.lost_cycles} lost cycles counted, {report.incomplete} incomplete, "
          f"{report.sync_restored} SYNCs restored")
    print(f"every decoded row equal to the intact log's at its time: {same}")


if __name__ == "__main__":
    main()
