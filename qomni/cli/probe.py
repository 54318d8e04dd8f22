"""``qomni probe``: what answers on a CANopen bus (identity, profile, CiA 402 modes, SDO timing) and,
with ``--timing NODE``, one node's dynamic timing as its master."""
from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path
from typing import List, Optional

import typer
from rich.table import Table

from .app import app
from .console import console, fail


@app.command()
def probe(
    bus: str = typer.Option(..., help="Bus to probe: 'virtual:NAME', 'socketcand:127.0.0.1:PORT/can0' "
                            "(a 'qomni hub'), 'socketcan:can0', 'pcan:…'."),
    node: Optional[List[int]] = typer.Option(None, min=1, max=127, help="Node-ID to probe (repeat); "
                                             "default: scan 1…127."),
    timeout: float = typer.Option(0.3, min=0.01, help="s to wait for answers to the scan."),
    samples: int = typer.Option(20, min=1, help="SDO uploads per node timed for the response time."),
    json_out: Optional[Path] = typer.Option(None, "--json", help="Also write the reports as JSON here."),
    timing: Optional[int] = typer.Option(None, min=1, max=127, help="Then take this node over and time it: "
                                         "SYNC→TPDO latency, heartbeat jitter, reaction to a missed SYNC "
                                         "and to NMT reset node (leaves it reset; a bench, not a bus in use)."),
    cycle: float = typer.Option(0.01, min=0.001, help="s, SYNC period of --timing."),
    syncs: int = typer.Option(300, min=1, help="SYNCs sent by --timing."),
):
    """Scan the bus by SDO and print each node's identity (0x1018), profile (0x1000), supported CiA 402
    modes (0x6502), mode display (0x6061), power state (0x6041) and SDO response time p50/p99."""
    from qomni.hil.bus import open_bus
    from qomni.hil.tools.probe import COLUMNS, ProbeError, probe as run_probe, table_rows
    from qomni.hil.tools.timing_probe import measure

    if json_out is not None and not json_out.parent.is_dir():
        fail(f"--json {json_out}: the directory {json_out.parent} does not exist")
    try:
        can_bus = open_bus(bus)
    except Exception as exc:                       # noqa: BLE001 - bad spec or interface: say so plainly
        fail(f"cannot open bus {bus!r}: {exc}")
    try:
        reports = run_probe(can_bus, sorted(set(node)) if node else range(1, 128), timeout=timeout,
                            samples=samples)                      # a node given twice is probed once
        if timing is not None and timing not in [r.node_id for r in reports]:
            fail(f"--timing {timing}: node {timing} did not answer the scan")
        timed = measure(can_bus, timing, cycle=cycle, syncs=syncs) if timing is not None else None
    except ProbeError as exc:
        fail(f"{bus}: {exc}")
    finally:
        can_bus.shutdown()
    table = Table(*COLUMNS, title=f"CANopen nodes on {bus}")
    for row in table_rows(reports):
        table.add_row(*row)
    console.print(table)
    if timed is not None:
        detail = Table("quantity", "value", title=f"node {timing}: timing as its master (SYNC every "
                                                  f"{cycle * 1e3:g} ms)")
        for row in timed.rows():
            detail.add_row(*row)
        console.print(detail)
    if json_out is not None:
        tmp = json_out.with_name(json_out.name + ".tmp")
        out = {"nodes": [r.as_dict() for r in reports],
               "timing": None if timed is None else dataclasses.asdict(timed)}
        tmp.write_text(json.dumps(out, indent=2))
        os.replace(tmp, json_out)
