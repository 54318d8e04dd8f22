"""Blind check of the sim-to-real gap diagnosis (issue: every effect × seeds × 2 magnitudes, the ideal
emulator, two effects at once), in one command:

    python benchmarks/blind_suite.py                   # full: 5 seeds × 2 magnitudes, full campaigns
    python benchmarks/blind_suite.py --quick           # 1 seed, high magnitude, quick campaigns
    python benchmarks/blind_suite.py --campaigns quick # full size on quick campaigns (~1 h on 2 cores)
    python benchmarks/blind_suite.py --scheduler tcp://HOST:PORT   # the cases as tasks of a Dask cluster
    python benchmarks/blind_suite.py --probe --dask-vs-local 4     # a local Dask cluster on 127.0.0.1
                                                       # against local processes, same tasks, same run

Prints top-1 accuracy, false positives and held-out shrinkage per effect and writes
``<work>/blind_suite.json`` after every finished case; started again, the suite runs only the cases not
in it. A case's campaign already in ``--work`` is re-used (its run directory holds
``identification.json``). ``--probe`` runs a worker check instead of campaigns (each task builds its
case's emulator and steps it). Ray is not offered: its head binds every interface, loopback or not.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rich.console import Console  # noqa: E402
from rich.table import Table  # noqa: E402

from qomni.blind_suite import cases, probe_case, run_suite, write_results  # noqa: E402


def dask_vs_local(todo, work: Path, quick: bool, workers, runner, console) -> int:
    """The same tasks on local processes and on a local Dask cluster bound to 127.0.0.1; wall times."""
    from distributed import Client, LocalCluster

    n = workers or 2
    started = time.perf_counter()
    local = run_suite(todo, work / "local", quick=quick, workers=n, runner=runner)
    t_local = time.perf_counter() - started
    with LocalCluster(host="127.0.0.1", n_workers=n, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        started = time.perf_counter()
        remote = run_suite(todo, work / "dask", quick=quick, executor=client.get_executor(), runner=runner)
        t_dask = time.perf_counter() - started
    errors = [r.error for r in local + remote if r.error]
    console.print(f"{len(todo)} tasks, {n} workers: local processes {t_local:.1f} s, Dask on 127.0.0.1 "
                  f"{t_dask:.1f} s (ratio {t_dask / t_local:.2f})" + (f"; errors: {errors}" if errors else ""))
    return 1 if errors else 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="1 seed, high magnitude, quick campaigns")
    ap.add_argument("--campaigns", choices=("quick", "full"), default=None,
                    help="campaign length (default: quick with --quick, else full)")
    ap.add_argument("--seeds", type=int, default=None, help="seeds per effect and magnitude (default 5)")
    ap.add_argument("--work", type=Path, default=Path("runs/blind_suite"), help="work directory")
    ap.add_argument("--workers", type=int, default=None, help="local worker processes (default: cores)")
    ap.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                    help="run the cases on this Dask distributed scheduler's workers")
    ap.add_argument("--probe", action="store_true", help="worker check: no campaigns, each task steps its "
                    "case's emulator")
    ap.add_argument("--dask-vs-local", type=int, default=None, metavar="N",
                    help="time N tasks on a local Dask cluster bound to 127.0.0.1 against local processes")
    ap.add_argument("--effects", nargs="*", default=None, help="only these suite entries")
    ap.add_argument("--recorded-only", action="store_true",
                    help="diagnose only the cases already recorded in --work (no new campaigns)")
    args = ap.parse_args(argv)
    console = Console()
    seeds = args.seeds or (1 if args.quick else 5)
    todo = cases(seeds=seeds, magnitudes=(1,) if args.quick else (0, 1), entries=args.effects,
                 ideal=max(seeds, 2))
    campaigns = args.campaigns or ("quick" if args.quick else "full")
    if args.recorded_only:
        todo = [c for c in todo if (args.work / c.name / "identification.json").exists()]
    console.print(f"{len(todo)} cases in {args.work} ({campaigns} campaigns)")
    started = time.perf_counter()

    def show(r):
        mark = "[green]✓[/]" if r.top1 and not r.false_positives else "[red]✗[/]"
        console.print(f"{mark} {r.case.name:40s} → {r.verdict or r.error}  ({r.wall_time:.0f} s)")

    runner = probe_case if args.probe else None
    if args.dask_vs_local:
        return dask_vs_local(todo[:args.dask_vs_local], args.work, campaigns == "quick", args.workers, runner,
                             console)
    executor, client = None, None
    if args.scheduler:
        from distributed import Client

        client = Client(args.scheduler)
        executor = client.get_executor()
    try:
        results = run_suite(todo, args.work, quick=campaigns == "quick", workers=args.workers, executor=executor,
                            results_path=None if args.probe else args.work / "blind_suite.json", on_result=show,
                            runner=runner)
    finally:
        if client is not None:
            client.close()
    if args.probe:
        return 0 if not any(r.error for r in results) else 1
    summary = write_results(results, args.work / "blind_suite.json")
    table = Table(title="Blind check per effect")
    for col in ("Effect", "Cases", "Top-1", "False positives", "Median held-out shrink", "Min shrink",
                "Median shrink beyond floor", "Min beyond floor", "Median from base fit", "Min from base fit"):
        table.add_column(col, justify="left" if col == "Effect" else "right")
    for name, e in sorted(summary["per_effect"].items()):
        fmt = (lambda v: "–" if v is None else f"{100 * v:.0f} %")
        table.add_row(name, str(e["cases"]), f"{e['top1']}/{e['cases']}", str(e["false_positives"]),
                      fmt(e["median_holdout_shrink"]), fmt(e["min_holdout_shrink"]),
                      fmt(e["median_excess_shrink"]), fmt(e["min_excess_shrink"]),
                      fmt(e["median_beyond_base_fit_shrink"]), fmt(e["min_beyond_base_fit_shrink"]))
    console.print(table)
    acc = summary["top1_accuracy"]
    console.print(f"top-1 accuracy {100 * acc:.1f} % over {summary['effect_cases']} effect cases; "
                  f"ideal: {summary['ideal_false_positives']} false positives in {summary['ideal_cases']} "
                  f"cases; two effects both named in {summary['pairs_both_named']}/{summary['pair_cases']}; "
                  f"{time.perf_counter() - started:.0f} s wall")
    for err in summary["errors"]:
        console.print(f"[red]error[/] {err}")
    return 0 if not summary["errors"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
