"""``qomni probe``: what answers on a CANopen bus (identity, profile, CiA 402 modes, SDO timing)."""
from __future__ import annotations

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
):
    """Scan the bus by SDO and print each node's identity (0x1018), profile (0x1000), supported CiA 402
    modes (0x6502), mode display (0x6061), power state (0x6041) and SDO response time p50/p99."""
    from qomni.hil.bus import open_bus
    from qomni.hil.tools.probe import COLUMNS, ProbeError, probe as run_probe, table_rows

    if json_out is not None and not json_out.parent.is_dir():
        fail(f"--json {json_out}: the directory {json_out.parent} does not exist")
    try:
        can_bus = open_bus(bus)
    except Exception as exc:                       # noqa: BLE001 - bad spec or interface: say so plainly
        fail(f"cannot open bus {bus!r}: {exc}")
    try:
        reports = run_probe(can_bus, node or range(1, 128), timeout=timeout, samples=samples)
    except ProbeError as exc:
        fail(f"{bus}: {exc}")
    finally:
        can_bus.shutdown()
    table = Table(*COLUMNS, title=f"CANopen nodes on {bus}")
    for row in table_rows(reports):
        table.add_row(*row)
    console.print(table)
    if json_out is not None:
        tmp = json_out.with_name(json_out.name + ".tmp")
        tmp.write_text(json.dumps([r.as_dict() for r in reports], indent=2))
        os.replace(tmp, json_out)
