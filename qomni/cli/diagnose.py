"""``qomni diagnose``: the sim-to-real gap report of a run against an identified model."""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.table import Table
from rich.text import Text

from .app import app
from .console import console, guarded


@app.command()
def diagnose(
    model: Path = typer.Option(..., "--model", help="identification.json (or its run directory)."),
    data: Path = typer.Option(..., "--data", help="Run directory whose data are diagnosed."),
    holdout: Optional[Path] = typer.Option(None, "--holdout", help="Second run used only as held-out "
                                           "data (default: alternate 1 s windows of --data)."),
    out: Path = typer.Option(..., "--out", help="Directory for gap.json and report.html."),
    simulate: bool = typer.Option(True, help="Also compare 1 s forward simulations."),
):
    """Diagnose the sim-to-real gap: where model and data differ, which unmodelled effect explains it,
    how far the held-out residual shrinks once it is added (gap.json, report.html)."""
    from qomni.diagnosis.diagnose import diagnose_paths
    from qomni.diagnosis.report import write_report

    d = guarded(lambda: diagnose_paths(model, data, holdout, simulate=simulate))
    table = Table(title="Unmodelled-effect hypotheses (ranked by held-out residual removed)")
    for col in ("#", "Effect", "Magnitude", "95 % CI", "p", "Held-out shrink", "beyond base fit", "Channel",
                "Significant"):
        table.add_column(col, justify="left" if col in ("Effect", "Channel") else "right")
    for i, c in enumerate(d.candidates[:8]):
        m = c.magnitude
        table.add_row(str(i + 1), c.hypothesis.label, f"{m.value:.4g} {m.unit}",
                      f"[{m.ci[0]:.3g}, {m.ci[1]:.3g}]", f"{c.p_value:.1e}",
                      f"{100 * c.from_model.shrink_affected:.1f} %", f"{100 * c.shrink.shrink_affected:.1f} %",
                      c.shrink.affected,
                      "yes" if c.significant else "no")
    console.print(table)
    console.print(Text.assemble(("verdict:", "bold"), f" {d.verdict}"))
    json_path, html_path = write_report(d, out)
    console.print(f"written {json_path} and {html_path}")

