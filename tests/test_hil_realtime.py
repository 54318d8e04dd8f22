"""Real-time hardening: CPU pinning and SCHED_FIFO requests (done, or a plain sentence why not), the
garbage collector kept off the cycle, the latency histogram (JSON and PNG) of ``qomni emulate --stats``."""
from __future__ import annotations

import gc
import json
import os
import signal
import subprocess
import sys

import numpy as np
import pytest

from qomni.hil.device.realtime import (QuietCollector, RealtimeError, parse_cpus, pin_cpus,
                                       set_realtime_priority)
from qomni.hil.device.server import TimingStats
from qomni.hil.tools.timing_plot import plot_latency_histogram

QOMNI = [sys.executable, "-c", "from qomni.cli import main; main()"]


def test_cpu_lists_parse_and_bad_ones_are_refused():
    assert parse_cpus("2,3") == {2, 3}
    assert parse_cpus("0-3, 6") == {0, 1, 2, 3, 6}
    for bad in ("", "a", "3-1", "-1", "1,,2"):
        with pytest.raises(RealtimeError):
            parse_cpus(bad)


def test_pinning_to_an_unavailable_cpu_says_so_and_changes_nothing():
    before = os.sched_getaffinity(0)
    note = pin_cpus({max(before) + 64})
    assert "not available" in note and os.sched_getaffinity(0) == before
    assert pin_cpus(before).startswith("pinned") and os.sched_getaffinity(0) == before
    with pytest.raises(RealtimeError):
        pin_cpus(set())


def test_realtime_priority_is_set_or_refused_with_a_reason():
    with pytest.raises(RealtimeError):
        set_realtime_priority(0)
    code = ("import os; from qomni.hil.device.realtime import set_realtime_priority as s; n = s(1); "
            "print(n); print(os.sched_getscheduler(0) == os.SCHED_FIFO)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    note, fifo = out.splitlines()
    if fifo == "True":
        assert note == "SCHED_FIFO priority 1"
    else:
        assert "refused" in note and "normal priority" in note


def test_quiet_collector_freezes_collects_only_after_cycles_and_restores():
    assert gc.isenabled()
    collector = QuietCollector(every=3)
    collector.start()
    try:
        assert not gc.isenabled() and gc.get_freeze_count() > 0
        counts = []
        for _ in range(6):
            collector.after_cycle()
            counts.append(gc.get_stats()[1]["collections"])
        assert counts[0] == counts[1] < counts[2] == counts[3] == counts[4] < counts[5]
    finally:
        collector.stop()
    assert gc.isenabled() and gc.get_freeze_count() == 0


def test_histogram_counts_every_latency_once_and_plots(tmp_path):
    stats = TimingStats(0.002, 0.001)
    rng = np.random.default_rng(3)
    for latency in np.concatenate([rng.uniform(0, 0.0039, 500), [0.0045, 0.01]]):
        stats.record(float(latency))
    summary = stats.summary()
    hist = summary["histogram"]
    assert sum(hist["counts"]) + hist["above"] == 502 and hist["above"] == 2
    assert hist["edges"][0] == 0.0 and hist["edges"][-1] == pytest.approx(0.004)
    png = plot_latency_histogram(json.loads(json.dumps(summary)), tmp_path / "t.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(ValueError):
        plot_latency_histogram(TimingStats(0.002, 0.001).summary(), tmp_path / "none.png")


def test_emulate_refuses_bad_cpu_lists_and_priorities_plainly():
    for args in (["--cpus", "x"], ["--rt-priority", "500"]):
        result = subprocess.run([*QOMNI, "emulate", "--bus", "virtual", "--duration", "0.1", *args],
                                capture_output=True, text=True)
        output = result.stdout + result.stderr
        assert result.returncode == 2 and "error:" in output and "Traceback" not in output


def test_realtime_emulate_writes_statistics_with_histogram_and_plot(tmp_path):
    from qomni.datasheet import DataSheet
    from qomni.hil.master.client import VehicleClient
    from qomni.hil.tools.hub import Hub

    stats = tmp_path / "stats.json"
    cpus = ",".join(map(str, sorted(os.sched_getaffinity(0))))
    with Hub() as hub:
        process = subprocess.Popen([*QOMNI, "emulate", "--bus", hub.bus_spec(), "--realtime", "--stats",
                                    str(stats), "--cpus", cpus, "--sync-timeout", "1.0"],
                                   stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                   preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        try:
            lines = []
            for line in process.stdout:
                lines.append(line)
                if "emulating" in line:
                    break
            assert any(line.startswith("pinned to CPU") for line in lines), lines
            with VehicleClient.from_drive(DataSheet.load().drive, hub.bus_spec(), timeout=1.0) as client:
                for _ in range(200):
                    client.exchange(np.zeros(4))
        finally:
            process.send_signal(signal.SIGINT)
            out, _ = process.communicate(timeout=30)
    assert process.returncode == 0, out
    summary = json.loads(stats.read_text())
    assert summary["cycles"] >= 200 and summary["realtime"] is True
    assert sum(summary["histogram"]["counts"]) + summary["histogram"]["above"] == summary["cycles"]
    assert stats.with_suffix(".png").read_bytes()[:4] == b"\x89PNG"
