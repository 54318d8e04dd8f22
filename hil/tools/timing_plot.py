"""The latency histogram of a real-time run as a picture: ``qomni emulate --stats FILE.json`` writes
``FILE.png`` beside the JSON (matplotlib, Agg backend, no display needed)."""
from __future__ import annotations

import os
from pathlib import Path


def plot_latency_histogram(summary: dict, path: str | Path, title: str = "") -> Path:
    """Bar chart of ``summary['histogram']`` (:meth:`qomni.hil.device.server.TimingStats.summary`) in µs,
    the deadline and p99 marked, late cycles in the legend; written atomically.

    Raises:
        ValueError: the summary has no histogram or no cycles.
    """
    hist = summary.get("histogram")
    if not hist or not summary.get("cycles"):
        raise ValueError("no SYNC was answered: nothing to plot")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    edges = [e * 1e6 for e in hist["edges"]]
    widths = [b - a for a, b in zip(edges, edges[1:])]
    fig, ax = plt.subplots(figsize=(7, 3.6))
    ax.bar(edges[:-1], hist["counts"], width=widths, align="edge", color="#4878a8")
    ax.axvline(summary["deadline"] * 1e6, color="#c03030", label=f"deadline {summary['deadline'] * 1e6:.0f} µs: "
               f"{summary['late']} late ({100 * summary['late_fraction']:.2f} %)")
    ax.axvline(summary["latency_p99"] * 1e6, color="#303030", ls="--",
               label=f"p99 {summary['latency_p99'] * 1e6:.0f} µs, max {summary['latency_max'] * 1e6:.0f} µs")
    ax.set_yscale("log")
    ax.set_xlabel("SYNC → last TPDO [µs]")
    ax.set_ylabel("SYNCs")
    ax.set_title(title or f"{summary['cycles']} SYNCs; {hist['above']} beyond {edges[-1]:.0f} µs")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    path = Path(path)
    partial = path.with_name(f".{path.name}.partial")
    fig.savefig(partial, format="png", dpi=110)
    plt.close(fig)
    os.replace(partial, path)
    return path
